"""Mitsuba's normalmap around any BSDF: read with Mitsuba's parameters and refusals, and
mitsuba_scenes/normalmap.xml (a diffuse floor, a rough gold sphere, a plastic mesh, one tangent-space map)
rendered by the path estimator against Mitsuba (Welch's t-test per 4x4 block and channel,
Bonferroni-corrected, family-wise false-positive rate ALPHA per comparison, as tests/test_agreement.py); the
same comparison fails on realistic mistakes: the map's y read the other way (DirectX against OpenGL
convention), and the shadowing term left out."""
import drjit as dr
import pytest

import tracer
from tracer.jit import Array3f
from tracer.materials import normalmap
from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

SCENE = "normalmap.xml"
DEPTH = 5
MAP = '<texture type="bitmap" name="normalmap"><string name="filename" value="{}"/></texture>'


def test_parameters_are_read(tmp_path):
    src = SCENES / "textures/bumps_normalmap.png"
    path = write_scene(tmp_path, f'<shape type="sphere"><bsdf type="normalmap">{MAP.format(src)}'
                                 '<boolean name="use_shadowing_function" value="false"/>'
                                 '<bsdf type="roughconductor"/></bsdf></shape>')
    b = tracer.load_scene(path).spheres[0].bsdf
    assert (b.kind, b.normalmap_flip, b.normalmap_shadowing) == ("roughconductor", True, False)
    assert b.normalmap.image.shape[:2] == (32, 32)


@pytest.mark.parametrize("inner, message", [
    ('<bsdf type="normalmap"><rgb name="normalmap" value="0.5, 0.5, 1"/><bsdf type="diffuse"/></bsdf>',
     "must be a <texture>"),
    ('<bsdf type="normalmap">{map}</bsdf>', "normalmap wraps one bsdf"),
    ('<bsdf type="normalmap">{map}<bsdf type="twosided"><bsdf type="diffuse"/></bsdf></bsdf>',
     "normalmap around twosided, mask, blendbsdf or normalmap is not supported"),
    ('<bsdf type="twosided"><bsdf type="normalmap">{map}<bsdf type="diffuse"/></bsdf></bsdf>',
     "twosided around normalmap or bumpmap is not supported"),
])
def test_refusals(tmp_path, inner, message):
    src = SCENES / "textures/bumps_normalmap.png"
    path = write_scene(tmp_path, f'<shape type="sphere">{inner.format(map=MAP.format(src))}</shape>')
    errors = scene_errors(path)
    assert len(errors) == 1 and message in errors[0], errors


def test_the_report_estimator_refuses_it():
    scene = tracer.load_scene(SCENES / SCENE)
    assert any("normalmap" in line for line in scene.estimator_refusals("report"))


def test_shadowing_term_is_estevez_et_al():
    """1 for an untilted normal; for a normal tilted by 45 degrees (alpha^2 = 1/8) and a direction at 60
    degrees (tan^2 = 3): 2 / (1 + sqrt(1 + 3/8))."""
    n = Array3f(0.0, 0.0, 1.0)
    assert normalmap.shadowing(n, dr.cos(1.0))[0] == 1.0
    tilted = dr.normalize(Array3f(1.0, 0.0, 1.0))
    assert abs(normalmap.shadowing(tilted, 0.5)[0] - 2.0 / (1.0 + (1.0 + 3.0 / 8.0) ** 0.5)) < 1e-6


def compare(seed: int):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=DEPTH)
    return compare_passes(plugin_passes(SCENE, "path", DEPTH, seed), ref, ALPHA)


@pytest.mark.slow
def test_agrees_with_mitsuba():
    result = compare(5200)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
@pytest.mark.parametrize("name, fault", [
    # the map's green channel read the other way (a DirectX normal map taken for an OpenGL one)
    ("tilted_frame", lambda honest: lambda m, *rest: honest(Array3f(m.x, -m.y, m.z), *rest)),
    # the shadowing term left out
    ("shadowing", lambda honest: lambda n, cos: dr.full(type(cos), 1.0, dr.width(cos))),
])
def test_fails_on_a_realistic_mistake(monkeypatch, name, fault):
    monkeypatch.setattr(normalmap, name, fault(getattr(normalmap, name)))
    result = compare(5200)
    assert result.verdict == "disagree", result.summary()
