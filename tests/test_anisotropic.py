"""Anisotropic roughness oriented as Mitsuba orients it: alpha_u along the shading frame's first tangent, the
surface's dp/du made orthogonal to the shading normal (Mitsuba's SurfaceInteraction sh_frame), on every shape
kind. Each shape's dp/du direction is checked against Mitsuba's at points on it; mitsuba_scenes/anisotropic.xml
rendered by both estimators agrees with Mitsuba (Welch's t-test per 4x4 block and channel, Bonferroni-corrected,
family-wise false-positive rate ALPHA per comparison, as tests/test_agreement.py), and the same comparison
fails with alpha_u and alpha_v swapped, or with the shading frame not following dp/du."""
import numpy as np
import pytest

import tracer
from tracer.materials import dispatch
from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP, mitsuba_passes, plugin_passes

SCENE = "anisotropic.xml"
DEPTHS = {"path": 6, "report": 4}


def compare(estimator: str, seed: int, edit=None):
    depth = DEPTHS[estimator]
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=depth)
    return compare_passes(plugin_passes(SCENE, estimator, depth, seed, edit=edit), ref, ALPHA)


def test_anisotropic_roughness_is_read(tmp_path):
    from .test_xml_loader import write_scene
    path = write_scene(tmp_path, '<shape type="sphere"><bsdf type="roughconductor"><float name="alpha_u" '
                                 'value="0.2"/><float name="alpha_v" value="0.05"/></bsdf></shape>')
    b = tracer.load_scene(path).spheres[0].bsdf
    assert (b.alpha_u, b.alpha_v) == (0.2, 0.05)


def test_tangents_follow_mitsubas_dp_du():
    """The shading frame's first tangent where 400 camera rays first hit the scene, against Mitsuba's
    sh_frame.s at the same points: every shape kind of the scene is hit, and they agree to 1e-3 (float32)."""
    from tracer.geometry import SceneGeometry
    from tracer.jit import Array3f, Float, UInt32
    from validation.verdict.mitsuba_render import mitsuba
    mi = mitsuba()
    rng = np.random.default_rng(3)
    d = np.column_stack([rng.uniform(-0.35, 0.35, 400), rng.uniform(-0.35, 0.35, 400), -np.ones(400)])
    d /= np.linalg.norm(d, axis=1)[:, None]
    o = np.zeros_like(d) + [0.0, 0.0, 4.0]
    ref = mi.load_file(str(SCENES / SCENE))      # kept alive while its lazy arrays are evaluated
    si = ref.ray_intersect(mi.Ray3f(mi.Point3f(*o.T.astype(np.float32)), mi.Vector3f(*d.T.astype(np.float32))))
    s_ref = np.array(mi.TensorXf(si.sh_frame.s)).reshape(3, -1).T
    geo = SceneGeometry(tracer.load_scene(SCENES / SCENE))
    surf = geo.surface(geo.closest_hit(Array3f(*o.T), Array3f(*d.T), 0.0, float("inf"), UInt32(0xFFFFFFFF)))
    prim, names = np.array(surf.prim), np.full(len(d), "", object)
    for shapes in geo.shape_sets:
        for shape, lo, count in shapes.shape_primitives():
            names[(prim >= lo) & (prim < lo + count)] = shape.name
    s = np.array(dispatch.shading_tangents(surf.ns, surf.dpdu)[0]).reshape(3, -1).T
    oriented = ("floor", "sphere", "tube", "disk", "quad", "block")
    on = np.isin(names, oriented)
    assert set(names[on]) == set(oriented)
    assert np.sum(s[on] * s_ref[on], axis=1).min() > 0.999


@pytest.mark.slow
@pytest.mark.parametrize("estimator", ["path", "report"])
def test_agrees_with_mitsuba(estimator):
    result = compare(estimator, 5100)
    assert result.verdict == "agree", result.summary()


def _swap_alphas(scene):
    for b in scene.bsdfs:
        u, v = b.alpha_u, b.alpha_v
        object.__setattr__(b, "alpha_u", v)    # the shapes hold the same (frozen) BSDFs
        object.__setattr__(b, "alpha_v", u)


@pytest.mark.slow
def test_fails_with_alpha_u_and_alpha_v_swapped():
    result = compare("path", 5100, edit=_swap_alphas)
    assert result.verdict == "disagree", result.summary()


@pytest.mark.slow
def test_fails_with_a_frame_that_ignores_dp_du(monkeypatch):
    monkeypatch.setattr(dispatch, "shading_tangents", lambda n, dpdu: dispatch.coordinate_system(n))
    result = compare("path", 5100)
    assert result.verdict == "disagree", result.summary()
