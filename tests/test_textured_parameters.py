"""Parameters given by textures (Mitsuba's eval_1 of a texture: a float per surface point):
mitsuba_scenes/textured_parameters.xml (a mask's opacity, an anisotropic rough conductor's alpha_u and
alpha_v, a rough dielectric's alpha and a blendbsdf's weight, each a checkerboard) rendered by the path
estimator against Mitsuba (Welch's t-test per 4x4 block and channel, Bonferroni-corrected, family-wise
false-positive rate ALPHA per comparison), and the same test failing when any one of those textures is
ignored (its constant used instead) or the two roughnesses are swapped; the loader's reading of them."""
import numpy as np
import pytest

import tracer
from tracer.materials import tables
from tracer.materials.textures import Checkerboard, Constant
from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 5 comparisons: < 0.5% in all
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import mi, scene_errors  # noqa: F401 (mi: Mitsuba in scalar_rgb, restored after)
from .test_xml_loader import write_scene

SCENE = "textured_parameters.xml"
DEPTH = 5


def shape_bsdf(name: str):
    scene = tracer.load_scene(SCENES / SCENE)
    return next(s.bsdf for s in scene.shapes if s.name == name)


def test_textured_parameters_are_read():
    veil, sphere, glass, panel = (shape_bsdf(n) for n in ("veil", "sphere", "glass", "panel"))
    assert veil.masked and isinstance(veil.texture_of("opacity"), Checkerboard)
    assert veil.texture_of("opacity").color0 == (0.9, 0.9, 0.9)
    u, v = sphere.texture_of("alpha_u"), sphere.texture_of("alpha_v")
    assert (u.color0[0], v.color0[0]) == (0.02, 0.5) and not sphere.isotropic
    assert glass.texture_of("alpha_u") is glass.texture_of("alpha_v") and glass.isotropic
    assert isinstance(panel.texture_of("weight"), Checkerboard) and panel.blend[1].kind == "roughconductor"


def test_rawconstant_is_read_as_given(tmp_path):
    path = write_scene(tmp_path, '<shape type="rectangle"><bsdf type="normalmap"><texture type="rawconstant" '
                                 'name="normalmap"><vector name="value" value="0.5, 0.5, 1"/></texture>'
                                 '<bsdf type="diffuse"/></bsdf></shape>')
    assert tracer.load_scene(path).rectangles[0].bsdf.normalmap == Constant((0.5, 0.5, 1.0))


def test_a_texture_where_mitsuba_takes_a_float_is_refused(tmp_path):
    """roughplastic's alpha is a plain float in Mitsuba (its coating is precomputed)."""
    path = write_scene(tmp_path, '<shape type="rectangle"><bsdf type="roughplastic">\n<texture type="checkerboard" '
                                 'name="alpha"/>\n</bsdf></shape>')
    (error,) = scene_errors(path)
    assert "scene.xml:" in error and "'alpha'" in error


def test_checkerboard_as_a_float_and_as_a_colour_as_mitsuba(mi):
    """Mitsuba 3.9.1's checkerboard puts color0 on the other squares when read as a float (eval_1) than as a
    colour (eval); the tracer's lookups at 200 random points against Mitsuba's."""
    import drjit as dr
    from tracer.jit import Float, UInt32
    from tracer.materials.textures import TextureTables

    board = Checkerboard((0.9,) * 3, (0.1,) * 3, ((2.0, 0.5, 0.1), (0.0, 3.0, 0.2), (0.0, 0.0, 1.0)))
    theirs = mi.load_dict({"type": "checkerboard", "color0": 0.9, "color1": 0.1,
                           "to_uv": mi.ScalarTransform4f([[2, 0.5, 0, 0.1], [0, 3, 0, 0.2], [0, 0, 1, 0], [0, 0, 0, 1]])})
    uv = np.random.default_rng(1).random((200, 2))
    si = mi.SurfaceInteraction3f()
    expected = []
    for u, v in uv:
        si.uv = mi.Point2f(u, v)
        expected.append((theirs.eval_1(si), theirs.eval(si)[0]))
    t = TextureTables([board])
    index, at = UInt32(np.ones(200, np.uint32)), (Float(uv[:, 0]), Float(uv[:, 1]))
    ours = np.stack([t.eval_1(index, at, True).numpy(), t.eval(index, at, True).x.numpy()], axis=1)
    assert np.allclose(ours, np.array(expected), atol=1e-6)
    assert len(set(np.round(ours[:, 0], 3))) == 2 and dr.width(index) == 200


def test_report_estimator_refuses_textures():
    (line,) = tracer.load_scene(SCENES / SCENE).estimator_refusals("report")
    assert "textures" in line


def ignoring(slot: str):
    """MaterialTables.textured_value with `slot`'s texture ignored (alpha: alpha_u and alpha_v swapped)."""
    original = tables.MaterialTables.textured_value

    def patched(self, name, surf, value, active):
        if slot == "alpha" and name in ("alpha_u", "alpha_v"):
            return original(self, {"alpha_u": "alpha_v", "alpha_v": "alpha_u"}[name], surf, value, active)
        return value if name == slot else original(self, name, surf, value, active)
    return patched


@pytest.mark.slow
def test_textured_parameters_agree_with_mitsuba():
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=DEPTH)
    result = compare_passes(plugin_passes(SCENE, "path", DEPTH, 9000), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
@pytest.mark.parametrize("slot", ["opacity", "alpha", "weight"])
def test_fails_when_a_texture_is_ignored(monkeypatch, slot):
    monkeypatch.setattr(tables.MaterialTables, "textured_value", ignoring(slot))
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=DEPTH)
    result = compare_passes(plugin_passes(SCENE, "path", DEPTH, 9000), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()
