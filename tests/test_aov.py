"""Mitsuba's `aov` integrator: its image is its first nested integrator's (the AOV channels beside it are not
written by the tracer, and `tracer info` says so). A Cornell box whose path integrator is wrapped in `aov`
against Mitsuba rendering that same file (its first three channels): Welch's t-test per 4x4 block and
channel, Bonferroni-corrected, family-wise false-positive rate ALPHA; the same test failing on the image of
the second nested integrator (direct light)."""
import numpy as np
import pytest

import tracer
from tracer.rendering import render
from validation.verdict.mitsuba_render import render_passes
from validation.verdict.protocol import ALPHA
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

WRAPPED = ('<integrator type="aov"><string name="aovs" value="dd.y:depth, nn:sh_normal"/>'
           '<integrator type="path" name="image"><integer name="max_depth" value="$max_depth"/></integrator>'
           '<integrator type="direct" name="second"/></integrator>')


def aov_scene(folder):
    text = (SCENES / "cornell_box.xml").read_text()
    start = text.index("<integrator")
    end = text.index("</integrator>", start) + len("</integrator>")
    text = text[:start] + WRAPPED + text[end:]
    text = text.replace('<scene version="3.0.0">', f'<scene version="3.0.0"><path value="{SCENES}"/>', 1)
    path = folder / "aov.xml"
    path.write_text(text)
    return path


def test_aov_renders_its_first_integrators_image(tmp_path):
    path = aov_scene(tmp_path)
    scene = tracer.load_scene(path, width=SIZE, height=SIZE, max_depth=3)
    assert (scene.integrator, scene.max_depth) == ("aov around path", 3)
    assert any("AOV channels" in note for note in scene.notes())
    ours = np.stack([render(scene, "path", spp=SPP, seed=9900 + k).image for k in range(PASSES)])
    ref = render_passes(path, PASSES, SPP, seed=12345, width=SIZE, height=SIZE, max_depth=3)
    result = compare_passes(ours, ref, ALPHA)
    assert result.verdict == "agree", result.summary()
    second = np.stack([render(scene, "path", spp=SPP, seed=9950 + k, max_depth=2).image for k in range(PASSES)])
    result = compare_passes(second, ref, ALPHA)
    assert result.verdict == "disagree", result.summary()


@pytest.mark.parametrize("body, words", [
    ('<integrator type="aov"><string name="aovs" value="dd:depthh"/><integrator type="path"/></integrator>',
     "invalid AOV 'dd:depthh'"),
    ('<integrator type="aov"><string name="aovs" value="dd:depth"/></integrator>', "without a nested integrator"),
])
def test_bad_aov_is_refused(tmp_path, body, words):
    (error,) = scene_errors(write_scene(tmp_path, body))
    assert words in error
