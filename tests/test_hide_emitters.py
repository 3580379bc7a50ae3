"""The integrator's hide_emitters with Mitsuba 3.9.1's meaning, per integrator: `path` and `direct` let camera
rays pass through emitting shapes and show them no environment (path.cpp, direct.cpp: skip_area_emitters);
`ptracer` leaves out only what emitters send straight to the camera. mitsuba_scenes/hide_emitters.xml (a
sphere light in front of a wall, a panel light, a constant environment) against Mitsuba with each: Welch's
t-test per 4 x 4 block and channel, Bonferroni-corrected, family-wise false-positive rate ALPHA per
comparison (3 agreements); the same test disagrees when path's emitters are only darkened (ptracer's
meaning) and when ptracer's camera rays pass through them (path's)."""
import numpy as np
import pytest

import tracer
from tracer.rendering import render
from tracer.scene import SceneError
from validation.verdict.mitsuba_render import render_passes
from validation.verdict.protocol import ALPHA
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SPP
from .test_xml_features import scene_errors

SCENE, SIZE = SCENES / "hide_emitters.xml", 16
ENVIRONMENT = '    <emitter type="constant">\n        <rgb name="radiance" value="0.2, 0.25, 0.3"/>\n    </emitter>\n'
DEPTH = '\n        <integer name="max_depth" value="$max_depth"/>'


def variant(tmp_path, integrator: str):
    """The scene for `integrator`: direct takes no max_depth; ptracer no environment (README 'ptracer')."""
    text = SCENE.read_text().replace('<default name="integrator" value="path"/>',
                                     f'<default name="integrator" value="{integrator}"/>')
    if integrator == "direct":
        text = text.replace(DEPTH, "")
    if integrator == "ptracer":
        text = text.replace(ENVIRONMENT, "")
    path = tmp_path / f"hide_{integrator}.xml"
    path.write_text(text)
    return path


def compare(path, seed: int, hide: str | None = None):
    scene = tracer.load_scene(path, width=SIZE, height=SIZE)
    if hide is not None:
        scene.hide_emitters = hide
    ours = np.stack([render(scene, "path", spp=SPP, seed=seed + k).image for k in range(PASSES)])
    return compare_passes(ours, render_passes(path, PASSES, SPP, seed=12345, width=SIZE, height=SIZE), ALPHA)


@pytest.mark.parametrize("integrator, seed", [("path", 7700), ("direct", 7720), ("ptracer", 7740)])
def test_agrees_with_mitsuba(tmp_path, integrator, seed):
    path = variant(tmp_path, integrator)
    assert tracer.load_scene(path).hide_emitters == ("dark" if integrator == "ptracer" else "pass")
    result = compare(path, seed)
    assert result.verdict == "agree", result.summary()


@pytest.mark.parametrize("integrator, wrong", [("path", "dark"), ("ptracer", "pass")])
def test_fails_with_the_other_meaning(tmp_path, integrator, wrong):
    result = compare(variant(tmp_path, integrator), 7760, hide=wrong)
    assert result.verdict == "disagree", result.summary()


def test_shown_when_false():
    assert tracer.load_scene(SCENE, hide_emitters="false").hide_emitters is None


@pytest.mark.parametrize("edit, words", [
    (('<default name="integrator" value="path"/>', '<default name="integrator" value="volpath"/>'),
     "hide_emitters = true with volpath: the tracer hides emitters with path, direct, ptracer"),
    (('<bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.4, 0.3"/></bsdf>', '<bsdf type="null"/>'),
     "hide_emitters = true with a surface rays pass through (bsdf 'null')"),
])
def test_refusals(tmp_path, edit, words):
    path = tmp_path / "scene.xml"
    path.write_text(SCENE.read_text().replace(*edit))
    errors = scene_errors(path)
    assert len(errors) == 1 and words in errors[0] and f"{path}:" in errors[0], errors


def test_info_and_the_report_estimator():
    scene = tracer.load_scene(SCENE)
    assert any("camera rays pass through emitting shapes" in n for n in scene.notes())
    with pytest.raises(SceneError, match="report estimator does not hide emitters"):
        render(scene, "report", spp=1, max_depth=3)
