"""Shadow rays skip primitives whose plane has the whole scene on one side (they can never block one)."""
import numpy as np
import pytest

import tracer
from tracer.geometry import SceneGeometry
from tracer.shapes.mesh import Mesh, MeshSet
from tracer.jit import Array3f, Float, UInt32

from .conftest import SCENES


def test_convex_room_walls_are_not_occluders():
    geo = SceneGeometry(tracer.load_scene(SCENES / "hexagon_room.xml"))
    names = {i: r.name for i, r in enumerate(geo.rectangles.shapes)}
    kept = {names.get(i, "mesh or sphere") for i in geo.occluders}
    assert kept == {"light", "mesh or sphere"}
    tetra = set(range(geo.meshes.base + 8, geo.meshes.base + 12))  # floor (4) and ceiling (4) triangles come first
    assert tetra <= geo.occluders and not (set(range(geo.meshes.base, geo.meshes.base + 8)) & geo.occluders)


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
    hit = culled.closest_hit(o, d, 0.0, float("inf"), none)          # points on the room's surfaces
    ok = hit.valid.numpy()
    p = (o + d * hit.t).numpy().T[ok]
    prim = hit.prim.numpy()[ok]
    half = len(p) // 2
    x, y = p[:half], p[half:2 * half]                                 # segments between pairs of them
    seg = y - x
    dist = np.linalg.norm(seg, axis=1)
    w = Array3f(*(seg / dist[:, None]).T)
    args = (Array3f(*x.T), w, Float(dist), UInt32(prim[:half]), UInt32(prim[half:2 * half]))
    a = culled.occluded(*args).numpy()
    b = full.occluded(*args).numpy()
    assert 0.1 < b.mean() < 0.9                                       # both blocked and free segments
    # They may differ only for segments lying in a culled primitive's plane (two points on the floor):
    # the full test then reports a rounding-level graze of a coplanar neighbour, the culled one cannot.
    culled_planes = [(p0, n) for shapes in culled.shape_sets for i, p0, n in shapes.culling_planes()
                     if i not in culled.occluders]
    in_plane = np.zeros(half, bool)
    for p0, n in culled_planes:
        in_plane |= (np.abs((x - p0) @ n) < 1e-5) & (np.abs((y - p0) @ n) < 1e-5)
    differ = a != b
    assert not np.any(differ & ~in_plane), np.flatnonzero(differ & ~in_plane)


def test_mesh_side_bounds_hold_every_side():
    """The bounds from which the culling decides without a mesh's sides hold each side it would compute,
    for planes through or beside its vertices, and decide planes clear of it."""
    rng = np.random.default_rng(5)
    vertices = rng.normal(size=(500, 3)) * [1, 20, 3e-3] + [4, 0, -1]
    meshes = MeshSet([Mesh(vertices, rng.integers(0, 500, (800, 3)), bsdf=None)], base=0)
    axes = [s * np.eye(3)[k] * (1 + 1e-9 * rng.normal(size=3)) for k in range(3) for s in (-1, 1)]
    for _ in range(300):
        n = axes[rng.integers(6)] if rng.random() < 0.3 else rng.normal(size=3)   # the box touches the sides
        n /= np.linalg.norm(n)
        p0 = vertices[np.argmin(vertices @ n) if rng.random() < 0.5 else rng.integers(500)]
        p0 = p0 + n * rng.choice([0, 1e-12, -1e-12, 1e-3])
        side = meshes.sides(p0, n)
        lo, hi = meshes.side_bounds(p0, n)
        assert lo <= side.min() and side.max() <= hi
    assert meshes.side_bounds(np.array([30.0, 0, 0]), np.array([1.0, 0, 0]))[1] < 0


def _occluders_from_every_side(geo: SceneGeometry) -> set[int]:
    """SceneGeometry._possible_occluders computing every side (no bounds)."""
    eps = 1e-6 * geo.scene.extent()
    lights = np.array([light.position for light in geo.points]).reshape(-1, 3)
    keep = set(range(geo.curved_base, geo.n_prims))
    for shapes in geo.shape_sets:
        for i, p0, n in shapes.culling_planes():
            side = np.concatenate([(lights - p0) @ n] + [s.sides(p0, n) for s in geo.shape_sets if s.count])
            if not (np.all(side >= -eps) or np.all(side <= eps)):
                keep.add(i)
    return keep


@pytest.mark.parametrize("bvh_threshold", [0, 10 ** 6])
def test_occluders_decided_from_bounds_are_those_of_every_side(bvh_threshold):
    geo = SceneGeometry(tracer.load_scene(SCENES / "hexagon_room.xml"), bvh_threshold=bvh_threshold)
    assert geo.occluders == _occluders_from_every_side(geo)
