"""Ray-primitive intersections (tracer/shapes) and the scene-level queries built on them.

Tolerances are float32 forward-error bounds. Every reference is computed in float64 from the *float32*
values the kernel actually receives, so the only error left is the kernel's own rounding: with
u = 2^-24 (unit roundoff), a length-3 dot product or cross product of float32 operands is off by at most
about 3u times the sum of the magnitudes of its terms. We allow twice the first-order bound.
"""
import math

import numpy as np
import pytest

import tracer
from tracer.geometry import SceneGeometry
from tracer.jit import INF, NO_PRIM, Bool, Float, UInt32, vec3
from tracer.materials import BSDF
from tracer.shapes import Rectangle
from tracer.shapes.planar import EDGE_MARGIN
from tracer.shapes.rectangle import ray_rectangle
from tracer.shapes.sphere import ray_sphere
from tracer.shapes.triangle import ray_triangle

from .float32 import U, arr3, f32, unit  # noqa: E402


def rect(o, d, center, du, dv, n, t_min=0.0, t_max=INF) -> np.ndarray:
    t, _, _ = ray_rectangle(arr3(o), arr3(d), vec3(center), vec3(du), vec3(dv), vec3(n), t_min, t_max)
    return t.numpy()


def tri(o, d, v0, v1, v2, t_min=0.0, t_max=INF):
    v0, v1, v2 = (np.asarray(v, np.float64) for v in (v0, v1, v2))
    t, b1, b2 = ray_triangle(arr3(o), arr3(d), vec3(v0), vec3(v1 - v0), vec3(v2 - v0), t_min, t_max)
    return t.numpy(), b1.numpy(), b2.numpy()


def sphere(o, d, center, radius, leaving=False, t_min=0.0, t_max=INF) -> np.ndarray:
    n = len(np.atleast_2d(o))
    leave = Bool(np.broadcast_to(np.asarray(leaving, bool), (n,)).copy())
    return ray_sphere(arr3(o), arr3(d), vec3(center), float(radius) ** 2, t_min, t_max, leave).numpy()


# ---- rectangle ---------------------------------------------------------------------------------------
Z_UP = dict(center=[0, 0, 0], du=[1, 0, 0], dv=[0, 1, 0], n=[0, 0, 1])


def test_rectangle_hit_and_miss_with_known_t():
    o = [[0.3, 0.2, 5.0], [0.3, 0.2, -2.5], [1.5, 0.0, 5.0], [0.0, -1.25, 5.0], [0.3, 0.2, 5.0]]
    d = [[0, 0, -1], [0, 0, 1], [0, 0, -1], [0, 0, -1], [0, 0, 1]]
    t = rect(o, d, **Z_UP)
    # hit from above, hit from below (one-sided normal does not matter), outside in x, outside in y,
    # and the plane behind the ray
    assert t[0] == 5.0 and t[1] == 2.5
    assert np.all(np.isinf(t[2:]))


def test_rectangle_t_min_t_max_are_exclusive_bounds():
    o, d = [[0.0, 0.0, 2.0]], [[0, 0, -1]]
    assert np.isinf(rect(o, d, **Z_UP, t_min=0.0, t_max=2.0)[0])      # t == t_max rejected
    assert np.isinf(rect(o, d, **Z_UP, t_min=2.0, t_max=3.0)[0])      # t == t_min rejected
    assert rect(o, d, **Z_UP, t_min=1.999, t_max=2.001)[0] == 2.0
    assert np.isinf(rect(o, d, **Z_UP, t_min=0.0, t_max=1.0)[0])


def test_rectangle_bounds_are_inclusive_at_plus_minus_one():
    # [-2, 2] x [-0.5, 0.5] around (6, -3, 4): the dual edges (0.5, 2) are powers of two and world
    # coordinates on or next to an edge lie within a factor 2 of the centre's (so p - c is exact,
    # Sterbenz), hence every quantity in the kernel is exact in float32
    c = np.array([6.0, -3.0, 4.0])
    du, dv = [0.5, 0.0, 0.0], [0.0, 2.0, 0.0]
    lo, hi = c[:2] - [2.0, 0.5], c[:2] + [2.0, 0.5]            # world x and y of the four edges
    # beyond the conservative margin: EDGE_MARGIN local units are 2 * EDGE_MARGIN in world x, 0.5 * EDGE_MARGIN in y
    step = {0: 8 * EDGE_MARGIN, 1: 2 * EDGE_MARGIN}
    beyond_axis = lambda v, away, axis: v + math.copysign(step[axis], away - v)
    xy_hit = [(hi[0], c[1]), (lo[0], c[1]), (c[0], hi[1]), (c[0], lo[1]),
              (hi[0], hi[1]), (lo[0], lo[1]), (hi[0], lo[1]), (lo[0], hi[1])]
    xy_miss = [(beyond_axis(hi[0], 9, 0), c[1]), (beyond_axis(lo[0], -9, 0), c[1]), (c[0], beyond_axis(hi[1], 9, 1)),
               (c[0], beyond_axis(lo[1], -9, 1)), (beyond_axis(hi[0], 9, 0), beyond_axis(hi[1], 9, 1))]
    o = [[x, y, c[2] + 3.0] for x, y in xy_hit + xy_miss]
    assert np.array_equal(f32(o), o)
    t = rect(o, [[0, 0, -1]] * len(o), c, du, dv, [0, 0, 1])
    assert np.all(t[:len(xy_hit)] == 3.0), t
    assert np.all(np.isinf(t[len(xy_hit):])), t


def test_rectangle_ray_parallel_to_plane_misses():
    # in the plane (0/0 = NaN in eq. 3) and beside it (x/0 = inf): both must report a clean miss
    o = [[-5.0, 0.0, 0.0], [-5.0, 0.3, 0.0], [-5.0, 0.0, 0.5], [-5.0, 0.0, -0.5]]
    d = [[1, 0, 0], unit([1, 1, 0]), [1, 0, 0], [1, 0, 0]]
    t = rect(o, d, **Z_UP)
    assert np.all(np.isinf(t)) and np.all(t > 0)


def test_rectangle_grazing_rays_axis_aligned_are_exact_or_clean_misses():
    # Plane z = 0: dot(n, .) picks a single component exactly, so eq. 3 is one correctly rounded
    # division of float32 inputs, and t is within one rounding (u relative) of the float64 reference.
    angles = np.array([1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7])
    targets = np.array([[0.3, -0.4], [-0.9, 0.7], [0.0, 0.0], [1.2, 0.0], [0.5, -1.1]])
    o, d = [], []
    for a in angles:
        for p in targets:
            dd = f32([math.cos(a), 0.0, -math.sin(a)])
            length = 0.5e-3 / math.sin(a)                 # start half a millimetre above the plane
            o.append(f32([p[0] - length * dd[0], p[1], 0.5e-3])), d.append(dd)
    o, d = np.array(o), np.array(d)
    ref = o[:, 2] / -d[:, 2]
    t = rect(o, d, **Z_UP)
    assert not np.any(np.isnan(t))
    hit = o[:, :2] + ref[:, None] * d[:, :2]
    # fma(d, t, o) at x ~ -5000 loses ~u * 5000 = 3e-4 to cancellation: classify with that margin
    inside = np.all(np.abs(hit) <= 1.0 - 1e-3, axis=1)
    outside = np.any(np.abs(hit) >= 1.0 + 1e-3, axis=1)
    assert inside.sum() == 3 * len(angles) and outside.sum() == 2 * len(angles)
    assert np.all(np.isfinite(t[inside]))
    assert np.all(np.abs(t[inside] - ref[inside]) <= U * ref[inside])
    assert np.all(np.isinf(t[outside]))


def _sheared_rectangle() -> Rectangle:
    """A rectangle with scale, shear, a rotation and a translation in its to_world."""
    m = np.eye(4)
    m[:3, 0] = [2.0, 0.0, 0.0]            # local +x edge
    m[:3, 1] = [0.7, 1.5, 0.3]            # sheared, not perpendicular to the first edge
    m[:3, 2] = [0.1, -0.2, 0.9]           # irrelevant to the plane but makes the matrix invertible
    m[:3, 3] = [3.0, -1.0, 2.0]
    th = np.radians(37.0)
    r = np.eye(4)
    r[:3, :3] = [[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]]
    return Rectangle(r @ m, BSDF("diffuse"))


def _rect_t_tolerance(o, d, c, n, t_ref):
    """Forward-error bound of eq. 3 in float32 (|n| = |d| = 1): numerator 4u|c-o|, denominator 3u."""
    cos = np.abs(np.sum(n * d, axis=1))
    return 2 * (4 * U * np.linalg.norm(c - o, axis=1) / cos + 4 * U * t_ref)


def test_rectangle_sheared_to_world_uses_dual_edges():
    r = _sheared_rectangle()
    c, n = f32(r.center), f32(r.normal)
    du, dv = r.dual_edges
    e1, e2 = r.edges
    # the properties themselves: dual edges are the biorthogonal basis of the edges, n is normal
    assert np.allclose([du @ e1, du @ e2, dv @ e1, dv @ e2], [1, 0, 0, 1], atol=1e-12)
    assert np.allclose([n @ e1, n @ e2], 0, atol=1e-6) and abs(np.linalg.norm(r.normal) - 1) < 1e-12

    rng = np.random.default_rng(7)
    ab_in = rng.uniform(-0.98, 0.98, size=(400, 2))
    ab_out = rng.uniform(1.02, 2.0, size=(400, 2)) * rng.choice([-1, 1], size=(400, 2))
    ab_out[:200, 1] = rng.uniform(-0.9, 0.9, 200)  # outside in one coordinate only
    ab = np.vstack([ab_in, ab_out])
    p = r.center + ab[:, :1] * e1 + ab[:, 1:] * e2
    # directions within 70 degrees of the normal, from either side
    dirs = unit(rng.normal(size=(len(p), 3)))
    cos = dirs @ r.normal
    dirs[np.abs(cos) < 0.35] = r.normal
    d = f32(unit(dirs))
    o = f32(p - rng.uniform(0.5, 10.0, size=(len(p), 1)) * d)
    t = rect(o, d, r.center, du, dv, r.normal)
    ref = ((c - o) @ n) / (d @ n)
    inside = slice(0, 400)
    assert np.all(np.isfinite(t[inside]))
    assert np.all(np.abs(t[inside] - ref[inside]) <= _rect_t_tolerance(o, d, c, n, ref)[inside])
    assert np.all(np.isinf(t[400:]))


def test_rectangle_sheared_grazing_rays_never_nan():
    r = _sheared_rectangle()
    c, n = f32(r.center), f32(r.normal)
    du, dv = r.dual_edges
    e1, e2 = r.edges
    rng = np.random.default_rng(3)
    m = 600
    ab = rng.uniform(-0.5, 0.5, size=(m, 2))
    p = r.center + ab[:, :1] * e1 + ab[:, 1:] * e2
    # directions at angles 1e-1 ... 1e-7 radians to the plane
    inplane = unit(rng.normal(size=(m, 2)) @ np.stack([unit(e1), unit(np.cross(r.normal, e1))]))
    ang = 10.0 ** rng.uniform(-7, -1, m)
    d = f32(unit(np.cos(ang)[:, None] * inplane - np.sin(ang)[:, None] * r.normal))
    o = f32(p - 2.0 * d)
    t = rect(o, d, r.center, du, dv, r.normal)
    assert not np.any(np.isnan(t))
    ref = ((c - o) @ n) / (d @ n)
    tol = _rect_t_tolerance(o, d, c, n, np.abs(ref))
    finite = np.isfinite(t)
    assert np.all(np.abs(t[finite] - ref[finite]) <= tol[finite])
    # a miss is only acceptable where the hit point's error (|d| * tol) could reach an edge: the aimed-at
    # point is at least 0.5 local units from every edge, i.e. 0.5 * sigma_min([e1 e2]) in world units
    sigma_min = np.linalg.svd(np.stack([e1, e2], axis=1), compute_uv=False).min()
    assert np.all(tol[~finite] >= 0.5 * sigma_min)
    # the well-conditioned half of them must all hit
    assert np.all(finite[ang > 1e-3])


# ---- triangle ----------------------------------------------------------------------------------------
# Unit right triangle in z = 0: all arithmetic below on it with rays along -z is exact in float32.
V0, V1, V2 = np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])


def test_triangle_hit_miss_t_and_barycentrics():
    o = [[0.25, 0.25, 2.0], [0.125, 0.5, -3.0], [0.75, 0.75, 2.0], [-0.25, 0.5, 2.0], [0.25, 0.25, 2.0]]
    d = [[0, 0, -1], [0, 0, 1], [0, 0, -1], [0, 0, -1], [0, 0, 1]]
    t, b1, b2 = tri(o, d, V0, V1, V2)
    assert t[0] == 2.0 and b1[0] == 0.25 and b2[0] == 0.25
    assert t[1] == 3.0 and b1[1] == 0.125 and b2[1] == 0.5     # back face hits too
    assert np.all(np.isinf(t[2:]))                              # b1 + b2 > 1, b1 < 0, behind


def _mt_error_bounds(o, d, v0, e1, e2):
    """Float64 reference (t, b1, b2) of float32 rays, and float32 error bounds of Moeller-Trumbore.

    b1, b2 and t are triple products of tvec = o - v0 (one rounding), d, e1, e2 divided by the triple
    product det: each triple product is off by at most ~6u times the product of its operands' norms,
    and rcp adds ~2u. We allow twice that.
    """
    m = np.stack([-d, np.broadcast_to(e1, d.shape), np.broadcast_to(e2, d.shape)], axis=-1)
    t, b1, b2 = np.linalg.solve(m, (o - v0)[..., None])[..., 0].T
    det = np.abs(np.linalg.det(m))
    ne1, ne2, ntv = np.linalg.norm(e1), np.linalg.norm(e2), np.linalg.norm(o - v0, axis=1)
    err_det = 6 * U * ne1 * ne2 / det                           # relative error of det (and of 1/det)
    err_b = 2 * (7 * U * ntv * max(ne1, ne2) / det + (err_det + 2 * U) * 1.0)
    err_t = 2 * (7 * U * ntv * ne1 * ne2 / det + (err_det + 2 * U) * np.abs(t))
    return t, b1, b2, err_t, err_b


def test_triangle_oblique_ray_matches_float64():
    rng = np.random.default_rng(11)
    v = f32(rng.normal(size=(3, 3)) * 2 + [4, -1, 3])
    b = rng.dirichlet([1, 1, 1], size=300)
    b = b[(b > 0.01).all(axis=1)]                             # points inside, off the edges
    p = b @ v
    d = f32(unit(rng.normal(size=(len(p), 3))))
    nrm = unit(np.cross(v[1] - v[0], v[2] - v[0]))
    keep = np.abs(d @ nrm) > 0.2
    p, d = p[keep], d[keep]
    o = f32(p - rng.uniform(0.5, 5, (len(p), 1)) * d)
    t, b1, b2 = tri(o, d, v[0], v[1], v[2])
    t_ref, b1_ref, b2_ref, err_t, err_b = _mt_error_bounds(o, d, v[0], f32(v[1] - v[0]), f32(v[2] - v[0]))
    assert len(t) > 100 and np.all(np.isfinite(t))
    assert np.all(np.abs(b1 - b1_ref) <= err_b) and np.all(np.abs(b2 - b2_ref) <= err_b)
    assert np.all(np.abs(t - t_ref) <= err_t)
    assert np.max(err_b) < 1e-4                               # the bound is not vacuous


def test_triangle_edges_and_vertices_are_inside():
    pts = [(0, 0), (1, 0), (0, 1),                    # vertices
           (0.5, 0), (0, 0.375), (0.5, 0.5), (0.25, 0.75), (0.875, 0.125)]  # on each edge
    o = [[x, y, 1.0] for x, y in pts]
    t, b1, b2 = tri(o, [[0, 0, -1]] * len(o), V0, V1, V2)
    assert np.all(t == 1.0), t
    assert np.all(b1 >= 0) and np.all(b2 >= 0) and np.all(b1 + b2 <= 1)
    assert np.allclose(np.c_[b1, b2], pts)


def test_ray_through_shared_diagonal_of_a_quad_hits():
    # quad (-2,-2)-(2,-2)-(2,2)-(-2,2) at z = -5 split along its diagonal like a fanned OBJ polygon.
    # Edges are powers of two, so along -z the diagonal's barycentric is exactly 0 in both triangles
    # and the inclusive test (b >= 0) must accept the ray in at least one (here: both).
    q = [np.array([x, y, -5.0]) for x, y in ((-2, -2), (2, -2), (2, 2), (-2, 2))]
    s = np.random.default_rng(5).uniform(-2, 2, 500)
    s = np.concatenate([s, [-2.0, 2.0, 0.0, 1.0 / 3.0]])
    o = f32(np.c_[s, s, np.full_like(s, 2.0)])
    d = [[0, 0, -1]] * len(s)
    ta, _, _ = tri(o, d, q[0], q[1], q[2])
    tb, _, _ = tri(o, d, q[0], q[2], q[3])
    assert np.all(ta == 7.0) and np.all(tb == 7.0)


def test_ray_through_shared_diagonal_of_a_non_dyadic_quad_hits():
    """Moeller-Trumbore in float32 rounds the shared edge's barycentric differently in each triangle;
    the conservative EDGE_MARGIN closes that crack."""
    q = [np.array([x, y, -5.0]) for x, y in ((0, 0), (3, 0), (3, 3), (0, 3))]
    s = np.random.default_rng(5).uniform(0, 3, 500)
    o = f32(np.c_[s, s, np.full_like(s, 2.0)])
    d = [[0, 0, -1]] * len(s)
    ta, _, _ = tri(o, d, q[0], q[1], q[2])
    tb, _, _ = tri(o, d, q[0], q[2], q[3])
    assert np.all(np.isfinite(ta) | np.isfinite(tb))


def test_shared_diagonal_gap_is_only_rounding_wide():
    """Moeller-Trumbore is not watertight: a ray aimed exactly at the shared edge of a tilted quad can
    slip between the two triangles (each computes the edge's barycentric with its own rounding). The
    gap must be no wider than that rounding: wherever the exact barycentrics of the float32 ray put it
    inside a triangle by more than the error bound, that triangle reports the hit."""
    rng = np.random.default_rng(2)
    c = np.array([2.0, -1.0, 3.0])
    e1, e2 = rng.normal(size=3), rng.normal(size=3)
    q = [f32(c), f32(c + e1), f32(c + e1 + e2), f32(c + e2)]
    n = 4000
    nrm = unit(np.cross(q[1] - q[0], q[3] - q[0]))
    d = unit(rng.normal(size=(n, 3)))
    d[np.abs(d @ nrm) < 0.3] = nrm
    d = f32(unit(d))
    s = rng.uniform(0.02, 0.98, n)
    # aim a little off the diagonal, towards v1 (into A) or v3 (into B): 1e-6 ... 3e-4 barycentric units
    off = 10.0 ** rng.uniform(-6, -3.5, n) * np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    toward = np.where(off[:, None] > 0, q[1] - q[0], q[3] - q[0])
    p = q[0] + s[:, None] * (q[2] - q[0]) + np.abs(off)[:, None] * toward
    o = f32(p - rng.uniform(0.5, 5, (n, 1)) * d)
    ta, _, _ = tri(o, d, q[0], q[1], q[2])
    tb, _, _ = tri(o, d, q[0], q[2], q[3])
    _, a1, a2, _, err_a = _mt_error_bounds(o, d, q[0], f32(q[1] - q[0]), f32(q[2] - q[0]))
    _, c1, c2, _, err_b = _mt_error_bounds(o, d, q[0], f32(q[2] - q[0]), f32(q[3] - q[0]))
    must_a = (a1 > err_a) & (a2 > err_a) & (a1 + a2 < 1 - err_a)
    must_b = (c1 > err_b) & (c2 > err_b) & (c1 + c2 < 1 - err_b)
    assert must_a.sum() > n // 5 and must_b.sum() > n // 5    # many aims are beyond the bound
    assert np.all(np.isfinite(ta[must_a])) and np.all(np.isfinite(tb[must_b]))


def test_triangle_ray_parallel_to_plane_misses():
    o = [[-1.0, 0.25, 0.0], [0.25, -1.0, 0.0], [-1.0, 0.25, 0.5], [0.25, 0.25, 0.0]]
    d = [[1, 0, 0], [0, 1, 0], [1, 0, 0], unit([1, 1, 0])]
    t, _, _ = tri(o, d, V0, V1, V2)
    assert np.all(np.isinf(t)) and np.all(t > 0)


def test_triangle_grazing_rays_finite_or_clean_miss():
    ang = np.repeat(10.0 ** np.linspace(-1, -7, 13), 3)
    target = np.tile([[0.3, 0.3, 0.0], [0.8, 0.8, 0.0], [-0.2, 0.5, 0.0]], (13, 1))  # in, out, out
    d = f32(np.c_[np.cos(ang) * 0.6, np.cos(ang) * 0.8, -np.sin(ang)])
    o = f32(target - 1.0 * d)
    t, b1, b2 = tri(o, d, V0, V1, V2)
    assert not np.any(np.isnan(t))
    inside = np.arange(len(t)) % 3 == 0
    assert np.all(np.isfinite(t[inside])) and np.all(np.isinf(t[~inside]))
    # plane z = 0 with edges (1,0,0), (0,1,0): det = -d.z and the numerator of t = o.z exactly, so t is
    # o.z times rcp(-d.z): a few u relative however small d.z is
    ref = o[:, 2] / -d[:, 2]
    assert np.allclose(t[inside], ref[inside], rtol=4 * U, atol=0)
    assert np.allclose(b1[inside], 0.3, atol=1e-6) and np.allclose(b2[inside], 0.3, atol=1e-6)


# ---- sphere ------------------------------------------------------------------------------------------
def test_sphere_from_outside_hits_near_root_and_inside_hits_far_root():
    c, r = np.array([1.0, 2.0, 3.0]), 2.0
    o = [c + [0, 0, -7], c + [0, 0, 0], c + [0, 0, 1], c + [0, 0, -7], c + [3, 0, -7]]
    d = [[0, 0, 1], [1, 0, 0], [0, 0, 1], [0, 0, -1], [0, 0, 1]]
    t = sphere(o, d, c, r)
    assert t[0] == 5.0          # near root of 5 and 9
    assert t[1] == 2.0          # from the centre: the far root, the near one is behind
    assert t[2] == 1.0          # off-centre inside
    assert np.isinf(t[3]) and np.isinf(t[4])   # sphere behind, line misses


def test_sphere_t_min_selects_far_root():
    c = np.zeros(3)
    o, d = [[0.0, 0.0, -5.0]], [[0, 0, 1]]
    assert sphere(o, d, c, 1.0, t_min=4.5)[0] == 6.0
    assert np.isinf(sphere(o, d, c, 1.0, t_max=4.0)[0])


def test_sphere_oblique_matches_float64():
    rng = np.random.default_rng(4)
    c, r = f32([0.5, -1.0, 2.0]), float(np.float32(1.5))
    n = 600
    o = f32(c + unit(rng.normal(size=(n, 3))) * rng.uniform(2.0, 10.0, (n, 1)))
    aim = c + unit(rng.normal(size=(n, 3))) * r * rng.uniform(0, 1.3, (n, 1))   # some miss
    d = f32(unit(aim - o))
    t = sphere(o, d, c, r)
    oc = o - c
    b = np.sum(oc * d, axis=1)
    disc = r * r - np.sum((oc - b[:, None] * d) ** 2, axis=1)
    ref = np.where(disc >= 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
    # away from tangency, where rounding of the discriminant (~4u |oc|^2) decides hit or miss
    clear = np.abs(disc) > 1e-3
    assert np.array_equal(np.isinf(t[clear]), np.isinf(ref[clear]))
    hit = clear & np.isfinite(ref)
    assert hit.sum() > n // 3 and (clear & np.isinf(ref)).sum() > n // 20
    # the root is formed from b and sqrt(disc): error a few u |oc|, plus the sqrt's sensitivity
    # d sqrt(disc) = d disc / (2 sqrt(disc)) with d disc ~ 4u |oc|^2
    noc = np.linalg.norm(oc, axis=1)
    tol = 2 * (4 * U * noc + 4 * U * noc ** 2 / np.sqrt(np.abs(disc)))
    assert np.all(np.abs(t[hit] - ref[hit]) <= tol[hit])


def test_sphere_leaving_inward_gives_chord_outward_gives_inf():
    rng = np.random.default_rng(8)
    c, r = np.array([0.0, 1.0, -2.0]), 1.5
    nrm = unit(rng.normal(size=(300, 3)))
    w = unit(rng.normal(size=(300, 3)))
    w = np.where((np.sum(w * nrm, axis=1) < 0)[:, None], w, -w)   # inward: w . n < 0
    cos = -np.sum(w * nrm, axis=1)
    keep = cos > 0.05
    o, w = f32(c + r * nrm[keep]), f32(w[keep])                    # on the sphere, as after a hit
    t_in = sphere(o, w, c, r, leaving=True)
    oc = o - c
    b = np.sum(oc * w, axis=1)
    far = -b + np.sqrt(b * b - (np.sum(oc * oc, axis=1) - r * r))   # the chord 2 r cos, for these o
    assert np.all(np.isfinite(t_in))
    # o is within float32 rounding (~1e-7) of the sphere, which moves the far root off 2 r cos by
    # at most about 1e-7 * |oc| / (r cos) <= 1e-5
    assert np.allclose(far, 2 * r * cos[keep], rtol=0, atol=1e-5)
    # disc = r^2 cos^2 is formed with error ~4u r^2, so sqrt(disc) is off by ~2u r / cos
    tol = 2 * (4 * U * r + 2 * U * r / cos[keep])
    assert np.all(np.abs(t_in - far) <= tol)
    t_out = sphere(o, -w, c, r, leaving=True)
    assert np.all(np.isinf(t_out))


def test_sphere_leaving_straight_through_centre():
    t = sphere([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]], [[0, 0, 1], [0, 0, -1]], [0, 0, 0], 1.0, leaving=True)
    assert t[0] == 2.0 and np.isinf(t[1])


def test_sphere_far_from_origin_is_accurate():
    # centre at 1e5: a naive discriminant b^2 - c cancels 1e10 against 1e10 (ulp 1024) and is garbage
    c, r = np.array([1e5, 0.0, 0.0]), 1.0
    h = np.array([0.0, 0.3, 0.6, 0.9, 0.99, 1.01, 1.2])        # impact parameters
    d = f32(unit(np.c_[np.full_like(h, 1e5), h, np.zeros_like(h)]))
    o = np.zeros((len(h), 3))
    t = sphere(o, d, c, r)
    b = d @ (o[0] - c)
    perp = (o - c) - b[:, None] * d
    ref = -b - np.sqrt(r * r - np.sum(perp ** 2, axis=1) + 0j).real
    ref = np.where(np.sum(perp ** 2, axis=1) <= r * r, ref, np.inf)
    assert np.all(np.isfinite(t[h < 1])) and np.all(np.isinf(t[h > 1]))
    assert np.allclose(t[h < 1], ref[h < 1], rtol=1e-4, atol=0)
    # stronger: the part of t that depends on the discriminant, t - |b| = -sqrt(r^2 - h^2), is right
    # to a few ulp of 1e5 (2^-7 = 0.0078), far below its size (>= 0.14)
    assert np.all(np.abs(t[h < 1] - ref[h < 1]) <= 8 * 2.0 ** -7)

    # a ray starting close to a sphere that is far from the origin: o - c is exact (Sterbenz),
    # so the hit is as accurate as near the origin
    c2 = np.array([1e5, 1e5, 1e5])
    o2 = f32(c2 + [[-5.0, 0.3, 0.2], [-5.0, 0.0, 0.0], [0.25, -0.5, 0.0]])
    d2 = [[1, 0, 0], [1, 0, 0], [1, 0, 0]]
    t2 = sphere(o2, d2, c2, 1.0)
    oc = o2 - c2
    ref2 = -oc[:, 0] + np.array([-1, -1, 1]) * np.sqrt(1 - oc[:, 1] ** 2 - oc[:, 2] ** 2)
    assert np.allclose(t2, ref2, rtol=1e-4, atol=0)
    assert np.allclose(t2, ref2, rtol=16 * U, atol=0)


def test_sphere_tangent_rays_never_nan():
    c, r = np.zeros(3), 1.0
    eps = np.array([-1e-3, -1e-5, -1e-7, 0.0, 1e-7, 1e-5, 1e-3])
    o = np.c_[np.full_like(eps, -3.0), 1.0 + eps, np.zeros_like(eps)]
    t = sphere(o, [[1, 0, 0]] * len(eps), c, r)
    assert not np.any(np.isnan(t))
    assert np.isfinite(t[0]) and np.isinf(t[-1])
    finite = np.isfinite(t)
    # near tangency t = 3 - sqrt(r^2 - y^2); the error of r^2 - |perp|^2 is ~2u, so sqrt of it ~3e-4
    ref = 3 - np.sqrt(np.maximum(1 - (1 + eps) ** 2, 0))
    assert np.all(np.abs(t[finite] - ref[finite]) <= math.sqrt(4 * U) + 8 * U * 3)


# ---- SceneGeometry on a tiny scene -------------------------------------------------------------------
SCENE_XML = """<?xml version="1.0"?>
<scene version="3.0.0">
    <sensor type="perspective">
        <transform name="to_world"><lookat origin="0, 0, -10" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm">
            <integer name="width" value="4"/><integer name="height" value="4"/>
            <rfilter type="box"/>
        </film>
    </sensor>
    <shape type="rectangle" id="floor"/>
    <shape type="rectangle" id="lamp">
        <transform name="to_world"><rotate x="1" angle="180"/><translate z="2"/></transform>
        <emitter type="area"><rgb name="radiance" value="1, 2, 3"/></emitter>
    </shape>
    <shape type="obj" id="tri">
        <string name="filename" value="tri.obj"/>
    </shape>
    <shape type="sphere">
        <point name="center" value="0, 0, 5"/>
        <float name="radius" value="1"/>
    </shape>
</scene>
"""
FLOOR, LAMP, TRI, BALL = 0, 1, 2, 3   # rectangles first, then triangles, then spheres


@pytest.fixture(scope="module")
def geo(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tiny")
    (folder / "tri.obj").write_text("v -1 -1 1\nv 3 -1 1\nv -1 3 1\nf 1 2 3\n")
    (folder / "tiny.xml").write_text(SCENE_XML)
    g = SceneGeometry(tracer.load_scene(folder / "tiny.xml"))
    assert [(s.base, s.count) for s in g.shape_sets] == [(0, 2), (2, 1), (3, 1), (4, 0)] and g.n_prims == 4
    return g


def _closest(geo, o, d, skip, t_max=INF):
    h = geo.closest_hit(arr3(o), arr3(d), 0.0, t_max, UInt32(skip))
    return h.t.numpy(), h.prim.numpy(), h.valid.numpy()


def test_closest_hit_and_skip(geo):
    zb = 5.0 - math.sqrt(0.95)          # where x = 0.1, y = 0.2 enters the ball
    x, y = 0.1, 0.2
    up, down = [0, 0, 1], [0, 0, -1]
    cases = [  # origin, direction, skip, expected prim, expected t
        ([x, y, -1.0], up, NO_PRIM, FLOOR, 1.0),
        ([x, y, -1.0], up, FLOOR, TRI, 2.0),        # skipping the floor reveals the triangle
        ([x, y, -1.0], up, LAMP, FLOOR, 1.0),       # skipping something else changes nothing
        ([x, y, 0.0], up, FLOOR, TRI, 1.0),         # leaving the floor
        ([x, y, 1.0], up, TRI, LAMP, 1.0),          # leaving the triangle
        ([x, y, 1.0], down, TRI, FLOOR, 1.0),
        ([x, y, 2.0], up, LAMP, BALL, zb - 2.0),
        ([x, y, zb], up, BALL, BALL, 2 * math.sqrt(0.95)),   # leaving the ball inward: far side
        ([x, y, zb], down, BALL, LAMP, zb - 2.0),            # leaving it outward: not itself
        ([x, y, 5.0], up, NO_PRIM, BALL, math.sqrt(0.95)),     # from inside the ball
    ]
    o, d, skip, prim, t_ref = (list(z) for z in zip(*cases))
    t, p, valid = _closest(geo, o, d, skip)
    assert p.tolist() == prim
    assert valid.all()
    assert np.allclose(t, t_ref, rtol=8 * U, atol=0)  # a few roundings of O(1) values


def test_closest_hit_miss_and_t_max(geo):
    t, p, valid = _closest(geo, [[0.0, 0.0, 3.0], [0.1, 0.2, -1.0], [5.0, 5.0, -1.0]],
                           [[1, 0, 0], [0, 0, 1], [0, 0, 1]], [NO_PRIM] * 3, t_max=0.5)
    assert p.tolist() == [NO_PRIM] * 3 and not valid.any()
    assert np.all(t == 0.5)      # t stays at t_max on a miss
    t, p, valid = _closest(geo, [[5.0, 5.0, -1.0]], [[0, 0, 1]], [NO_PRIM])
    assert p[0] == NO_PRIM and np.isinf(t[0])


def test_occluded_excludes_skip_and_target(geo, monkeypatch):
    """Segments that cross the lamp and end beyond it, where no shadow ray ends: every primitive is asked
    (the lamp, with the whole scene's lights in its plane, is otherwise left out: test_occluders.py)."""
    monkeypatch.setattr(geo, "occluders", set(range(geo.n_prims)))
    x, y = 0.1, 0.2
    zb = 5.0 - math.sqrt(0.95)
    up, down = [0, 0, 1], [0, 0, -1]
    cases = [  # origin, direction, dist, skip, target, expected
        ([x, y, -1.0], up, 3.0, NO_PRIM, LAMP, True),     # floor and triangle in between
        ([x, y, 0.0], up, 1.0, FLOOR, TRI, False),        # nothing between floor and triangle
        ([x, y, 0.0], up, 2.0, FLOOR, LAMP, True),        # triangle between floor and lamp
        ([x, y, 0.0], up, 0.999, FLOOR, NO_PRIM, False),  # segment ends before the triangle
        ([x, y, 1.0], up, 1.001, TRI, LAMP, False),       # the target itself does not occlude ...
        ([x, y, 1.0], up, 1.001, TRI, NO_PRIM, True),     # ... but it does when it is not the target
        ([x, y, zb], up, 2 * math.sqrt(0.95) * 1.001, BALL, NO_PRIM, True),   # own far side blocks
        ([x, y, zb], up, 2 * math.sqrt(0.95) * 1.001, BALL, BALL, False),     # unless it is the target
        ([x, y, zb], down, 10.0, BALL, NO_PRIM, True),   # outward from the ball, lamp below
        ([x, y, zb], down, zb - 2.0 - 1e-3, BALL, NO_PRIM, False),
    ]
    o, d, dist, skip, target, expected = (list(z) for z in zip(*cases))
    got = geo.occluded(arr3(o), arr3(d), Float(dist), UInt32(skip), UInt32(target)).numpy()
    assert got.tolist() == expected


def test_sample_light_on_lamp(geo):
    rng = np.random.default_rng(0)
    u = rng.random((3, 20000)).astype(np.float32)
    s = geo.sample_light(Float(u[0]), Float(u[1]), Float(u[2]))
    y, n = s.y.numpy(), s.n.numpy()
    assert np.allclose(y[2], 2.0) and np.all(np.abs(y[:2]) <= 1.0)
    assert np.allclose(n.T, [0, 0, -1], atol=1e-7)       # rotated by 180 degrees about x: faces down
    assert np.allclose(s.pdf_area.numpy(), 1 / 4.0) and np.all(s.prim.numpy() == LAMP)
    assert np.allclose(s.radiance.numpy().T, [1, 2, 3])
    # uniform in area: each quadrant gets a quarter
    q = np.histogram2d(y[0], y[1], bins=2, range=[[-1, 1], [-1, 1]])[0] / y.shape[1]
    assert np.all(np.abs(q - 0.25) < 5 * math.sqrt(0.25 * 0.75 / y.shape[1]))
