"""Shadow rays skip primitives whose plane has the whole scene on one side (they can never block one)."""
import numpy as np

import tracer
from tracer.geometry import SceneGeometry
from tracer.jit import Array3f, Float, UInt32

from .conftest import SCENES


def test_convex_room_walls_are_not_occluders():
    geo = SceneGeometry(tracer.load_scene(SCENES / "hexagon_room.xml"))
    names = {i: r.name for i, r in enumerate(geo.rects)}
    kept = {names.get(i, "mesh or sphere") for i in geo.occluders}
    assert kept == {"light", "mesh or sphere"}
    tetra = set(range(geo.n_rects + 8, geo.n_rects + 12))  # floor (4) and ceiling (4) triangles come first
    assert tetra <= geo.occluders and not (set(range(geo.n_rects, geo.n_rects + 8)) & geo.occluders)


def test_culled_occluders_change_no_shadow_ray_between_scene_points():
    """Segments between points on the room's surfaces: blocked the same with and without culling."""
    scene = tracer.load_scene(SCENES / "hexagon_room.xml")
    culled, full = SceneGeometry(scene), SceneGeometry(scene)
    full.occluders = set(range(full.n_prims))
    rng = np.random.default_rng(3)
    n = 20000
    o = Array3f(*(np.array([5, 0, 0]) + rng.uniform(-3, 3, (n, 3))).T)
    d = rng.normal(size=(n, 3))
    d = Array3f(*(d / np.linalg.norm(d, axis=1, keepdims=True)).T)
    none = UInt32(0xFFFFFFFF)
    start = culled.closest_hit(o, d, 0.0, float("inf"), none)        # a point on a surface
    ok = start.valid.numpy() & np.isfinite(start.t.numpy())
    p = o + d * start.t
    d2 = rng.normal(size=(n, 3))
    d2 = Array3f(*(d2 / np.linalg.norm(d2, axis=1, keepdims=True)).T)
    end = culled.closest_hit(p, d2, 0.0, float("inf"), start.prim)  # ... and the next one it sees
    ok &= end.valid.numpy()
    dist = end.t * Float(0.999)
    a = culled.occluded(p, d2, dist, start.prim, end.prim).numpy()
    b = full.occluded(p, d2, dist, start.prim, end.prim).numpy()
    assert ok.sum() > n // 2
    np.testing.assert_array_equal(a[ok], b[ok])
