"""What rectangles and triangles share: conservative edge tests and hit points kept inside.

Edge tests are conservative by EDGE_MARGIN (in the primitive's own coordinates: barycentrics, or the
rectangle's [-1, 1]): float32 rounding computes a shared edge differently in each neighbour, and an
exact test lets rays aimed at the edge slip between them (a crack that light leaks through). The
margin grows each primitive by 1e-6 of its size, far below any image's resolution.
"""
import drjit as dr

from ..jit import Array3f, Bool, Float

EDGE_MARGIN = 2.0 ** -20


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
