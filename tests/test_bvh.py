"""The BVH traversal finds exactly the hits of the brute-force tests it replaces."""
import numpy as np
import pytest

import tracer
import tracer.geometry as geometry
from tracer.bvh import build
from tracer.jit import NO_PRIM, Array3f, Float, UInt32

from .conftest import SCENES


def _rays(n, center, spread, seed=0):
    rng = np.random.default_rng(seed)
    o = np.asarray(center) + rng.uniform(-spread, spread, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return Array3f(*o.T), Array3f(*d.T)


def test_build_covers_every_triangle_once():
    tris = np.random.default_rng(1).uniform(-1, 1, (1000, 3, 3))
    flat = build(tris)
    assert sorted(flat.order) == list(range(1000))
    leaves = flat.count > 0
    assert flat.count[leaves].sum() == 1000
    for node in np.flatnonzero(leaves):   # each leaf's box bounds its triangles
        t = tris[flat.order[flat.first[node]:flat.first[node] + flat.count[node]]]
        assert (t.min(axis=(0, 1)) >= flat.bounds[node, 0]).all() and (t.max(axis=(0, 1)) <= flat.bounds[node, 1]).all()


@pytest.mark.parametrize("skip_prim", [False, True])
def test_bvh_matches_brute_force(monkeypatch, skip_prim):
    scene = tracer.load_scene(SCENES / "hexagon_room.xml")
    o, d = _rays(4000, [4, 0, 0], 2.5)
    brute = geometry.SceneGeometry(scene)
    monkeypatch.setattr(geometry, "BVH_THRESHOLD", 0)
    bvh = geometry.SceneGeometry(scene)
    assert bvh.bvh is not None and brute.bvh is None
    h1 = brute.closest_hit(o, d, 0.0, float("inf"), UInt32(NO_PRIM))
    skip = h1.prim if skip_prim else UInt32(NO_PRIM)
    h1 = brute.closest_hit(o, d, 0.0, float("inf"), skip)
    h2 = bvh.closest_hit(o, d, 0.0, float("inf"), skip)
    np.testing.assert_array_equal(h1.prim.numpy(), h2.prim.numpy())
    np.testing.assert_array_equal(h1.t.numpy(), h2.t.numpy())
    brute.occluders = bvh.occluders = set(range(brute.n_prims))  # random segments: every occluder counts
    dist = Float(np.random.default_rng(2).uniform(0.1, 8, 4000))
    np.testing.assert_array_equal(brute.occluded(o, d, dist, skip, UInt32(NO_PRIM)).numpy(),
                                  bvh.occluded(o, d, dist, skip, UInt32(NO_PRIM)).numpy())
