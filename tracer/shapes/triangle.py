"""The ray-triangle test (Moeller and Trumbore 1997), shared by brute-force meshes and the BVH's leaves."""
import drjit as dr

from ..jit import INF, Array3f, Float
from .planar import EDGE_MARGIN


def ray_triangle(o: Array3f, d: Array3f, v0, e1, e2, t_min, t_max) -> tuple[Float, Float, Float]:
    """Moeller-Trumbore: t and the barycentrics (b1, b2) of v1 = v0 + e1 and v2 = v0 + e2; t = inf on a miss.

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
