"""Mitsuba's `direct` integrator: emission seen by the camera plus direct light at the first surface, from
emitter samples and BSDF samples combined by the power heuristic over their counts. mitsuba_scenes/direct.xml
(a glossy floor, a mirror sphere only BSDF samples light, a point light only emitter samples reach) against
Mitsuba with each strategy alone and both in unequal counts: Welch's t-test per 4x4 block and channel,
Bonferroni-corrected, family-wise false-positive rate ALPHA per comparison; the same test failing when the
counts are ignored (the path tracer's depth-2 image)."""
import numpy as np
import pytest

import tracer
from tracer.rendering import render
from tracer.scene import SceneError
from validation.verdict.mitsuba_render import render_passes
from validation.verdict.protocol import ALPHA  # per comparison; 3 agreement tests: < 3 ALPHA in all
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP, mitsuba_passes
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

SCENE = "direct.xml"


def tracer_passes(counts: tuple[int, int], seed: int, edit=None) -> np.ndarray:
    scene = tracer.load_scene(SCENES / SCENE, width=SIZE, height=SIZE, emitter_samples=counts[0],
                              bsdf_samples=counts[1])
    if edit is not None:
        edit(scene)
    return np.stack([render(scene, "path", spp=SPP, seed=seed + k).image for k in range(PASSES)])


def reference(counts: tuple[int, int]) -> np.ndarray:
    return mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, emitter_samples=counts[0],
                          bsdf_samples=counts[1])


@pytest.mark.parametrize("counts", [(1, 0), (0, 1)])
def test_direct_agrees_with_mitsuba(counts):
    result = compare_passes(tracer_passes(counts, 7100), reference(counts), ALPHA)
    assert result.verdict == "agree", result.summary()


def test_unequal_counts_agree_with_mitsuba(tmp_path):
    """3 emitter samples to 1 BSDF sample, in the scene without its point light (refused with it: below)."""
    text = (SCENES / SCENE).read_text()
    start, end = text.index('<emitter type="point">'), text.index("</emitter>", text.index('<emitter type="point">'))
    path = tmp_path / SCENE
    path.write_text(text[:start] + text[end + len("</emitter>"):])
    params = dict(width=SIZE, height=SIZE, emitter_samples=3, bsdf_samples=1)
    scene = tracer.load_scene(path, **params)
    ours = np.stack([render(scene, "path", spp=SPP, seed=7300 + k).image for k in range(PASSES)])
    result = compare_passes(ours, render_passes(path, PASSES, SPP, seed=12345, **params), ALPHA)
    assert result.verdict == "agree", result.summary()


def test_several_samples_of_a_delta_light_are_refused():
    """Mitsuba weights each emitter sample of a delta light 1 rather than 1/emitter_samples."""
    (error,) = scene_errors(SCENES / SCENE, emitter_samples=3)
    assert "3x too bright" in error and "direct.xml:" in error


def test_fails_when_the_counts_are_ignored():
    """With emitter samples only, Mitsuba's mirror sphere shows no light; the path tracer's does."""
    def both(scene):
        scene.shading_samples = (1, 1)

    result = compare_passes(tracer_passes((1, 0), 7200, both), reference((1, 0)), ALPHA)
    assert result.verdict == "disagree", result.summary()


def test_info_says_how_direct_is_rendered(tmp_path):
    scene = tracer.load_scene(SCENES / SCENE, bsdf_samples=0)
    assert (scene.max_depth, scene.shading_samples) == (2, (1, 0))
    assert any("weighted as Mitsuba weights 1 emitter and 0 BSDF samples" in n for n in scene.notes())
    with pytest.raises(SceneError, match="report estimator samples both"):
        render(scene, "report", spp=1)


@pytest.mark.parametrize("body, words", [
    ('<integrator type="direct"><integer name="shading_samples" value="2"/>'
     '<integer name="bsdf_samples" value="1"/></integrator>', "not both"),
    ('<integrator type="direct"><integer name="shading_samples" value="0"/></integrator>', "at least one"),
    ('<integrator type="direct"><integer name="max_depth" value="3"/></integrator>', "unreferenced"),
])
def test_bad_direct_is_refused(tmp_path, body, words):
    (error,) = scene_errors(write_scene(tmp_path, body))
    assert words in error
