"""Ray-primitive intersections (the report's section 2.3). Each returns the ray parameter t, inf on a miss.

Directions are unit vectors; t_min/t_max bound the accepted hits.

Edge tests are conservative by EDGE_MARGIN (in the primitive's own coordinates: barycentrics, or the
rectangle's [-1, 1]): float32 rounding computes a shared edge differently in each neighbour, and an
exact test lets rays aimed at the edge slip between them (a crack that light leaks through). The
margin grows each primitive by 1e-6 of its size, far below any image's resolution.
"""
import drjit as dr
import numpy as np

from .jit import INF, Array3f, Bool, Float

EDGE_MARGIN = 2.0 ** -20


def ray_rectangle(o: Array3f, d: Array3f, center, du, dv, n, t_min, t_max) -> tuple[Float, Float, Float]:
    """Ray-plane intersection (eq. 2-4) and a bounds test in the rectangle's own coordinates.

    `du`, `dv` are the dual edge vectors, so dot(p - center, du) is the local x in [-1, 1].
    Returns t and the hit's local coordinates (x, y). A ray parallel to the plane (N.D = 0) misses.
    """
    cos_nd = dr.dot(n, d)                                        # eq. 2
    t = dr.dot(n, center - o) / cos_nd                           # eq. 3
    rel = dr.fma(d, t, o) - center                               # eq. 4, relative to the centre
    x, y = dr.dot(rel, du), dr.dot(rel, dv)
    bound = 1.0 + EDGE_MARGIN
    inside = (dr.abs(x) <= bound) & (dr.abs(y) <= bound)
    hit = (cos_nd != 0) & inside & (t > t_min) & (t < t_max)
    return dr.select(hit, t, INF), x, y


def inset_point(origin, e1, e2, c1: Float, c2: Float, rectangle: Bool) -> Array3f:
    """origin + c1 e1 + c2 e2 with the coordinates clamped EDGE_MARGIN inside the primitive: a rectangle's
    local (x, y) to [-1, 1], a triangle's barycentrics to b1, b2 >= 0, b1 + b2 <= 1.

    The conservative edge tests accept hits up to EDGE_MARGIN beyond an edge, outside a closed mesh
    where the neighbour meets it at an angle; a path continued from there could miss the neighbour's
    plane and leave the mesh. Points kept inside cannot, nor can points on an edge that rounding puts
    behind the neighbour's plane. They move by at most 2^-20 of the primitive's size, far below a pixel."""
    bound = 1.0 - EDGE_MARGIN
    b1, b2 = dr.maximum(c1, EDGE_MARGIN), dr.maximum(c2, EDGE_MARGIN)
    over = dr.maximum((b1 + b2) / bound, 1.0)
    c1 = dr.select(rectangle, dr.clip(c1, -bound, bound), b1 / over)
    c2 = dr.select(rectangle, dr.clip(c2, -bound, bound), b2 / over)
    return dr.fma(e1, c1, dr.fma(e2, c2, origin))


def ray_triangle(o: Array3f, d: Array3f, v0, e1, e2, t_min, t_max) -> tuple[Float, Float, Float]:
    """Moeller-Trumbore: t and the barycentrics (b1, b2) of v1 = v0 + e1 and v2 = v0 + e2.

    Points on edges and vertices count as inside (up to EDGE_MARGIN), so a ray through a shared edge
    hits a neighbour; a ray in the triangle's plane (det = 0) misses.
    """
    pvec = dr.cross(d, e2)
    det = dr.dot(e1, pvec)
    inv_det = dr.rcp(det)
    tvec = o - v0
    b1 = dr.dot(tvec, pvec) * inv_det
    qvec = dr.cross(tvec, e1)
    b2 = dr.dot(d, qvec) * inv_det
    t = dr.dot(e2, qvec) * inv_det
    inside = (b1 >= -EDGE_MARGIN) & (b2 >= -EDGE_MARGIN) & (b1 + b2 <= 1.0 + EDGE_MARGIN)
    hit = (det != 0) & inside & (t > t_min) & (t < t_max)
    return dr.select(hit, t, INF), b1, b2


def ray_sphere(o: Array3f, d: Array3f, center, radius: float, t_min, t_max, leaving: Bool) -> Float:
    """Nearest root of |o + t d - c|^2 = r^2 in (t_min, t_max).

    The discriminant is formed as r^2 - |oc - b d|^2 (Haines et al., Ray Tracing Gems ch. 7), which
    stays accurate far from the sphere. `leaving` marks rays that start on this sphere: they can only
    hit its far side, and only when heading inward.
    """
    oc = o - center
    b = dr.dot(oc, d)
    perp = dr.fma(d, -b, oc)
    disc = radius * radius - dr.squared_norm(perp)
    c = dr.squared_norm(oc) - radius * radius
    q = -b - dr.copysign(dr.safe_sqrt(disc), b)   # numerically stable pair of roots: q and c / q
    r0, r1 = q, c / q
    t_near, t_far = dr.minimum(r0, r1), dr.maximum(r0, r1)
    t_far = dr.select(dr.isnan(t_far), t_near, t_far)
    t_near = dr.select(leaving, INF, t_near)
    t_far = dr.select(leaving & (b >= 0), INF, t_far)
    ok_near = (t_near > t_min) & (t_near < t_max)
    ok_far = (t_far > t_min) & (t_far < t_max)
    t = dr.select(ok_near, t_near, dr.select(ok_far, t_far, INF))
    return dr.select(disc >= 0, t, INF)


def ray_cylinder(o: Array3f, d: Array3f, to_local: np.ndarray, t_min, t_max, leaving: Bool) -> Float:
    """Nearest t in (t_min, t_max) where o + t d meets the open tube x^2 + y^2 = 1, 0 <= z <= 1 of the frame
    with inverse affine map `to_local`. The quadratic in the frame's x, y is solved as ray_sphere's (Haines'
    discriminant, the stable pair of roots); `leaving` marks rays that start on this tube: they can only meet
    its far side, and only when heading inward."""
    m = to_local
    ox, oy, oz = (o.x * float(m[r, 0]) + o.y * float(m[r, 1]) + o.z * float(m[r, 2]) + float(m[r, 3]) for r in range(3))
    dx, dy, dz = (d.x * float(m[r, 0]) + d.y * float(m[r, 1]) + d.z * float(m[r, 2]) for r in range(3))
    a = dr.fma(dx, dx, dy * dy)
    b = dr.fma(ox, dx, oy * dy)
    c = dr.fma(ox, ox, dr.fma(oy, oy, -1.0))
    s = b / a
    px, py = dr.fma(dx, -s, ox), dr.fma(dy, -s, oy)
    disc = a * (1.0 - dr.fma(px, px, py * py))
    q = -b - dr.copysign(dr.safe_sqrt(disc), b)
    r0, r1 = q / a, c / q
    t_near, t_far = dr.minimum(r0, r1), dr.maximum(r0, r1)
    t_far = dr.select(dr.isnan(t_far), t_near, t_far)
    t_near = dr.select(leaving, INF, t_near)
    t_far = dr.select(leaving & (b >= 0), INF, t_far)
    z_near, z_far = dr.fma(dz, t_near, oz), dr.fma(dz, t_far, oz)
    ok_near = (t_near > t_min) & (t_near < t_max) & (z_near >= 0) & (z_near <= 1)
    ok_far = (t_far > t_min) & (t_far < t_max) & (z_far >= 0) & (z_far <= 1)
    t = dr.select(ok_near, t_near, dr.select(ok_far, t_far, INF))
    return dr.select((disc >= 0) & (a > 0), t, INF)
