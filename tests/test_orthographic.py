"""Mitsuba's `orthographic` sensor (tracer.camera): mitsuba_scenes/orthographic.xml, its view sized by a scale
in to_world and cut by its clip planes, against Mitsuba: Welch's t-test per 4x4 block and channel,
Bonferroni-corrected, family-wise false-positive rate ALPHA; the same test failing when the film's aspect
is not applied to the view's height."""
import numpy as np
import pytest

import tracer.camera as camera
from tracer.cli import main
from tracer.jit import vec3
from validation.verdict.protocol import ALPHA
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import HEADER, write_scene

SCENE = "orthographic.xml"
SIZE = (32, 20)


def compared(seed: int):
    import tracer
    from tracer.rendering import render

    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE[0], height=SIZE[1], max_depth=3)
    scene = tracer.load_scene(SCENES / SCENE, width=SIZE[0], height=SIZE[1])
    ours = np.stack([render(scene, "path", spp=SPP, seed=seed + k, max_depth=3).image for k in range(PASSES)])
    return compare_passes(ours, ref, ALPHA)


def test_orthographic_agrees_with_mitsuba():
    result = compared(9700)
    assert result.verdict == "agree", result.summary()


def test_fails_without_the_aspect(monkeypatch):
    def square(cam, x, y):
        o, d, t_min, t_max = ortho(cam, x, y)
        aspect = cam.width / cam.height
        m = cam.to_world
        ly = (1.0 - 2.0 * y / cam.height)
        return o + vec3(m[:3, 1]) * (ly - ly / aspect), d, t_min, t_max

    ortho = camera._orthographic
    monkeypatch.setattr(camera, "_orthographic", square)
    result = compared(9800)
    assert result.verdict == "disagree", result.summary()


def test_info_names_the_projection(capsys):
    assert main(["info", str(SCENES / SCENE)]) == 0
    assert "camera: orthographic, 64 x 40" in capsys.readouterr().out


@pytest.mark.parametrize("extra, words", [
    ('<float name="fov" value="30"/>', "unreferenced property 'fov'"),
    ('<transform name="to_world"><scale x="0"/></transform>', "singular"),
])
def test_bad_orthographic_is_refused(tmp_path, extra, words):
    header = HEADER.replace('<sensor type="perspective">', f'<sensor type="orthographic">{extra}')
    (error,) = scene_errors(write_scene(tmp_path, "", header=header))
    assert words in error
