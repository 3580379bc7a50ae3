"""Mitsuba's `cylinder` (an open tube): the quadratic ray test in its frame and the radial normal."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import drjit as dr
import numpy as np

from ..jit import HOST_FLOAT, INF, Array3f, ArrayXf, Bool, Float, UInt32, opaque_f, opaque_vec3
from .base import ShapeArgs, ShapeSet
from .bvh import BVHKernel, layout, leaf_prim, leaf_rows

if TYPE_CHECKING:
    from ..materials import BSDF

BVH_THRESHOLD = 16   # cylinders above which a BVH beats the unrolled tests (measured: see CylinderSet.uses_bvh)
PLUGINS = {"cylinder": ("p0", "p1", "radius", "to_world", "flip_normals", "silhouette_sampling_weight")}


@dataclass(eq=False)
class Cylinder:
    """Mitsuba's `cylinder`: the open tube x^2 + y^2 = 1, 0 <= z <= 1 of the local frame `to_world` (which
    already holds p0, p1 and the radius; it scales x and y alike), normals outward unless `flipped`."""

    to_world: np.ndarray
    bsdf: BSDF
    flipped: bool = False
    name: str = ""
    radiance: None = None

    @property
    def corners(self) -> np.ndarray:
        """The corners of its local bounding box [-1, 1]^2 x [0, 1], in world space."""
        local = np.array([[x, y, z, 1.0] for x in (-1, 1) for y in (-1, 1) for z in (0, 1)])
        return (local @ self.to_world.T)[:, :3]

    @property
    def to_local(self) -> np.ndarray:
        """The inverse of to_world: world space to the local frame of the tube."""
        return np.linalg.inv(self.to_world)

    def extent_points(self) -> list[np.ndarray]:
        return [self.corners]


def from_xml(ctx, props, a: ShapeArgs) -> Cylinder:
    """Mitsuba's `cylinder`: the frame to_world * translate(p0) * (a frame along p1 - p0) * scale(r, r, |p1 - p0|)."""
    p0 = props.get("p0", np.zeros(3), ("point",))
    p1 = props.get("p1", np.array([0.0, 0.0, 1.0]), ("point",))
    radius = float(props.get("radius", 1.0, ("float", "integer")))
    props.finish()
    node = a.node
    if a.radiance is not None:
        raise ctx.error(node, "area emitters are supported on rectangle, disk, sphere and mesh shapes only")
    axis = p1 - p0
    length = float(np.linalg.norm(axis))
    if length == 0 or radius <= 0:
        raise ctx.error(node, f"a cylinder needs p0 != p1 and a positive radius, got length {length}, radius {radius}")
    z = axis / length
    x, y = coordinate_system(z)
    frame = np.eye(4)
    frame[:3, :3] = np.stack([x, y, z], axis=1) @ np.diag([radius, radius, length])
    frame[:3, 3] = p0
    m = a.to_world @ frame
    cols = m[:3, :3].T
    tol = 1e-6 * float(np.max(np.abs(cols)) ** 2)
    if (abs(cols[0] @ cols[1]) > tol or abs(cols[0] @ cols[2]) > tol or abs(cols[1] @ cols[2]) > tol
            or abs(cols[0] @ cols[0] - cols[1] @ cols[1]) > tol or np.linalg.det(m[:3, :3]) <= 0):
        raise ctx.error(node, "a cylinder's to_world must keep it circular (equal scale across the axis, no shear "
                              "or mirroring)")
    return Cylinder(m, a.bsdf, a.flip, a.name)


def coordinate_system(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing the unit n to a right-handed frame, as Mitsuba's `coordinate_system` (Duff
    et al. 2017, "Building an orthonormal basis, revisited"): the tube's local x and y, from which its texture
    coordinates' angle is measured."""
    sign = 1.0 if n[2] >= 0 else -1.0
    a = -1.0 / (sign + n[2])
    b = n[0] * n[1] * a
    return (np.array([1.0 + sign * n[0] * n[0] * a, sign * b, -sign * n[0]]),
            np.array([b, sign + n[1] * n[1] * a, -n[1]]))


def constants(m: np.ndarray) -> list[list[Float]]:
    """The rows of a 3 x 4 affine map as the kernel's run-time constants (what `local` and ray_cylinder take;
    the linear part's zeros and ones folded, jit.opaque_f)."""
    return [[opaque_f(m[r, c], fold=c < 3) for c in range(4)] for r in range(3)]


def local(m, p: Array3f, rows: int = 3, offset: bool = True) -> tuple:
    """The first `rows` coordinates of the affine map m (3 x 4: literals, or a gathered row's values) applied
    to p (a direction without `offset`)."""
    return tuple(p.x * m[r][0] + p.y * m[r][1] + p.z * m[r][2] + m[r][3] if offset else
                 p.x * m[r][0] + p.y * m[r][1] + p.z * m[r][2] for r in range(rows))


def ray_cylinder(o: Array3f, d: Array3f, to_local, t_min, t_max, leaving: Bool) -> Float:
    """Nearest t in (t_min, t_max) where o + t d meets the open tube x^2 + y^2 = 1, 0 <= z <= 1 of the frame
    with inverse affine map `to_local` (3 x 4, `local`'s; inf if none). The quadratic in the frame's x, y is
    solved as ray_sphere's (Haines' discriminant, the stable pair of roots); `leaving` marks rays that start
    on this tube: they can only meet its far side, and only when heading inward."""
    ox, oy, oz = local(to_local, o)
    dx, dy, dz = local(to_local, d, offset=False)
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


class CylinderBVH(BVHKernel):
    """Cylinders in a BVH over the bounding boxes of their local boxes' corners (each box given to the build
    as the triangle of its corners lo, hi, hi); a leaf slot's row holds the rows of the inverse map
    (m00 m01 m02 prim, m03 m10 m11 m12, m13 m20 m21 m22, m23): what ray_cylinder reads."""

    def __init__(self, cylinders: list[Cylinder], prim_base: int):
        corners = np.array([c.corners for c in cylinders], float)
        lo, hi = corners.min(1), corners.max(1)
        tables = layout(np.stack([lo, hi, hi], 1))
        self._set_nodes(tables)
        rows = leaf_rows(tables.order, prim_base, 16)
        m = np.array([c.to_local[:3].ravel() for c in cylinders])[tables.order]
        rows[:, [0, 1, 2, 4, 5, 6, 7, 8, 9, 10, 11, 12]] = m
        self.prims = Float(rows.ravel())

    def _primitive(self, slot, o, d, t_min, t_max, skip, target):
        """The cylinder in leaf slot `slot`: (t, prim, 0, 0) as BVHKernel's, by ray_cylinder."""
        x = dr.gather(ArrayXf, self.prims, slot, shape=(16, dr.width(slot)))
        prim = leaf_prim(x)
        m = [[x[0], x[1], x[2], x[4]], [x[5], x[6], x[7], x[8]], [x[9], x[10], x[11], x[12]]]
        t = ray_cylinder(o, d, m, t_min, t_max, prim == skip)
        if target is not None:
            t = dr.select(prim == target, INF, t)
        return t, prim, Float(0), Float(0)


class CylinderSet(ShapeSet):
    kind = Cylinder

    def __init__(self, shapes: list[Cylinder], base: int):
        super().__init__(shapes, base)
        if self.uses_bvh(self.count):
            self.bvh = CylinderBVH(self.shapes, base)
            # per cylinder: the inverse map's 12 values, to_world's first two columns, the normal's sign
            table = [[*c.to_local[:3].ravel(), *c.to_world[:3, 0], *c.to_world[:3, 1],
                      -1.0 if c.flipped else 1.0] for c in self.shapes]
            self.frames_table = Float(np.array(table, HOST_FLOAT).ravel())

    @staticmethod
    def uses_bvh(cylinders: int) -> bool:
        """Whether a CylinderSet of this many cylinders puts them into a BVH (above BVH_THRESHOLD). Measured on
        tests/test_cylinder_bvh.py's room of n random cylinders at 128 x 128, path, 64 spp, max_depth 6, CPU
        seconds of a render with warm kernel caches (machine loaded, load ~9), unrolled against BVH: 0.43
        against 0.48 at 8, 0.68 against 0.62 at 16, 1.08 against 0.69 at 32; unrolled, every count compiles
        its kernel anew (its cold compile grows with the count), the BVH's kernel serves every count."""
        return cylinders > BVH_THRESHOLD

    def sides(self, p0: np.ndarray, n: np.ndarray) -> np.ndarray:
        return (np.reshape([c.corners for c in self.shapes], (-1, 3)) - p0) @ n

    def describe(self) -> str:
        return f"{self.count} cylinders (quadratic{', in a BVH' if self.bvh is not None else ''})"

    def _constants(self) -> list[tuple[list, Array3f, Array3f, Float]]:
        """Per cylinder, as run-time constants: its inverse map's rows, to_world's x and y columns, the
        normal's sign (the unrolled tests' values, _gathered's in the BVH's scenes); new variables at each
        call, which callers may update in place."""
        return [(constants(c.to_local), opaque_vec3(c.to_world[:3, 0], fold=True),
                 opaque_vec3(c.to_world[:3, 1], fold=True), opaque_f(-1.0 if c.flipped else 1.0, fold=True))
                for c in self.shapes]

    def candidates(self, o, d, t_min, skip, target, only):
        skip, target = self.local_ends(skip, target)
        for k, (m, _, _, _) in enumerate(self._constants() if self.bvh is None else ()):
            t = ray_cylinder(o, d, m, t_min, INF, skip == k)
            yield self.prim(k), (t if target is None else dr.select(target == k, INF, t)), None, None

    def _gathered(self, prim: UInt32) -> tuple[Bool, list, Array3f, Array3f, Float]:
        """(lanes on one of the set's cylinders, its inverse map's rows, to_world's x and y columns, the
        normal's sign), gathered from the table by primitive (the BVH's scenes)."""
        index = self.local(prim)
        mine = index < self.size
        x = dr.gather(ArrayXf, self.frames_table, index, mine, shape=(19, dr.width(prim)))
        m = [[x[4 * r + c] for c in range(4)] for r in range(3)]
        return mine, m, Array3f(x[12], x[13], x[14]), Array3f(x[15], x[16], x[17]), x[18]

    def normal(self, prim: UInt32, p: Array3f, n: Array3f) -> Array3f:
        if self.bvh is not None and self.shapes:
            mine, m, _, _, sign = self._gathered(prim)
            return dr.select(mine, _radial(m, p, sign), n)
        index = self.local(prim)
        for k, (m, _, _, sign) in enumerate(self._constants()):
            n = dr.select(index == k, _radial(m, p, sign), n)
        return n

    def uv(self, prim, valid, p, b1, b2, uv):
        """Mitsuba's: (phi / 2 pi, z) of p in the tube's frame, phi in [0, 2 pi) from local +x towards +y."""
        u, v = uv
        if self.bvh is not None and self.shapes:
            mine, m, _, _, _ = self._gathered(prim)
            frames = [(mine, m)]
        else:
            index = self.local(prim)
            frames = [(index == k, m) for k, (m, _, _, _) in enumerate(self._constants())]
        for here, m in frames:
            x, y, z = local(m, p)
            phi = dr.atan2(y, x)
            phi = dr.select(phi < 0, phi + 2.0 * dr.pi, phi)
            u, v = dr.select(here, phi * (0.5 / dr.pi), u), dr.select(here, z, v)
        return u, v

    def tangent(self, prim, valid, p, b1, b2, dpdu):
        """Mitsuba's dp/du: along phi, the local (-y, x, 0) in world space."""
        if self.bvh is not None and self.shapes:
            mine, m, wx, wy, _ = self._gathered(prim)
            frames = [(mine, m, wx, wy)]
        else:
            index = self.local(prim)
            frames = [(index == k, m, wx, wy) for k, (m, wx, wy, _) in enumerate(self._constants())]
        for here, m, wx, wy in frames:
            x, y = local(m, p, rows=2)
            dpdu = dr.select(here, Array3f(*(wy[j] * x - wx[j] * y for j in range(3))), dpdu)
        return dpdu


def _radial(m, p: Array3f, sign) -> Array3f:
    """The tube's normal at p: the local radial direction (x, y, 0) taken to world space as a normal, outward
    for sign 1 (-1: a flipped cylinder); from the inverse map's rows m (run-time constants or gathered)."""
    x, y = local(m, p, rows=2)
    return dr.normalize(Array3f(*((x * m[0][k] + y * m[1][k]) * sign for k in range(3))))
