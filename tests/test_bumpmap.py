"""Mitsuba's `bumpmap` around any BSDF: read with Mitsuba's parameters and refusals, and
mitsuba_scenes/bumpmap.xml (a height map on a diffuse panel and on an anisotropic rough gold plate, both
meshes with a rotated, non-uniform texture layout) rendered by the path estimator against Mitsuba (Welch's
t-test per 4x4 block and channel, Bonferroni-corrected, family-wise false-positive rate ALPHA per comparison,
as tests/test_agreement.py); the same comparison fails on realistic mistakes: the height's gradient in u and v
swapped, dp/du and dp/dv taken at unit length (as the shading frame's tangents), and the tilted normal left
on the side it comes out on (the plate's texture layout is mirrored: its OBJ's v is flipped)."""
import drjit as dr
import pytest

import tracer
from tracer.materials import bumpmap, tables
from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 4 comparisons: < 0.4% in all
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

SCENE = "bumpmap.xml"
DEPTH = 5
HEIGHTS = '<texture type="bitmap" name="h"><string name="filename" value="{}"/></texture>'


def test_parameters_are_read():
    scene = tracer.load_scene(SCENES / SCENE)
    panel, metal = (next(m.bsdf for m in scene.meshes if m.name == n) for n in ("panel", "metal"))
    assert (panel.kind, panel.bump_scale, panel.normalmap_shadowing) == ("diffuse", 0.15, True)
    assert (metal.kind, metal.bump_scale, metal.normalmap_shadowing) == ("roughconductor", 0.08, False)
    assert panel.texture_of("bumpmap") is metal.texture_of("bumpmap")


@pytest.mark.parametrize("shape, inner, message", [
    ("sphere", '<bsdf type="bumpmap">{h}<bsdf type="diffuse"/></bsdf>', "a bumpmap on a 'sphere' is not supported"),
    ("obj", '<bsdf type="bumpmap"><bsdf type="diffuse"/></bsdf>', "bumpmap wraps one bsdf and one texture"),
    ("obj", '<bsdf type="bumpmap">{h}<bsdf type="twosided"><bsdf type="diffuse"/></bsdf></bsdf>',
     "bumpmap around twosided"),
])
def test_refusals(tmp_path, shape, inner, message):
    (tmp_path / "t.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    filename = '<string name="filename" value="t.obj"/>' if shape == "obj" else ""
    h = HEIGHTS.format(SCENES / "textures/tiles.png")
    errors = scene_errors(write_scene(tmp_path, f'<shape type="{shape}">{filename}{inner.format(h=h)}</shape>'))
    assert len(errors) == 1 and message in errors[0], errors


def test_the_report_estimator_refuses_it():
    assert any("textures" in line for line in tracer.load_scene(SCENES / SCENE).estimator_refusals("report"))


def compare(seed: int):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=DEPTH)
    return compare_passes(plugin_passes(SCENE, "path", DEPTH, seed), ref, ALPHA)


@pytest.mark.slow
def test_agrees_with_mitsuba():
    result = compare(5300)
    assert result.verdict == "agree", result.summary()


def _swapped_gradient(honest):
    return lambda self, surf, active: (lambda g, has: (type(g)(g.y, g.x), has))(*honest(self, surf, active))


def _unit_tangents(honest):
    return lambda n, ng, dpdu, dpdv, grad: honest(n, ng, dr.normalize(dpdu), dr.normalize(dpdv), grad)


def _not_turned(honest):
    def bumped(n, ng, dpdu, dpdv, grad):
        du = dr.fma(n, grad.x - dr.dot(n, dpdu), dpdu)
        dv = dr.fma(n, grad.y - dr.dot(n, dpdv), dpdv)
        return dr.normalize(dr.cross(du, dv))        # left on its side where the uv layout is mirrored
    return bumped


@pytest.mark.slow
@pytest.mark.parametrize("owner, name, fault", [
    (tables.MaterialTables, "bump_gradient", _swapped_gradient),
    (bumpmap, "bumped_normal", _unit_tangents),
    (bumpmap, "bumped_normal", _not_turned),
])
def test_fails_on_a_realistic_mistake(monkeypatch, owner, name, fault):
    monkeypatch.setattr(owner, name, fault(getattr(owner, name)))
    result = compare(5300)
    assert result.verdict == "disagree", result.summary()
