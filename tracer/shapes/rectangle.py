"""Mitsuba's `rectangle` and `disk`: ray-plane intersection (the report's eq. 2-4), area sampling."""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import drjit as dr
import numpy as np

from .. import transform
from ..jit import HOST_FLOAT, INF, Array3f, ArrayXf, Bool, Float, UInt32, aligned_zeros, opaque_u32, opaque_vec3
from ..sampling import square_to_uniform_disk_concentric
from .base import ShapeArgs, ShapeSet, exclude
from .bvh import BVHKernel, layout, leaf_prim, leaf_rows
from .planar import EDGE_MARGIN

if TYPE_CHECKING:
    from ..materials import BSDF

BVH_THRESHOLD = 40  # rectangles and disks above which a BVH beats the unrolled tests (see RectangleSet.uses_bvh)
LARGE, MAX_LARGE = 8, 16   # at most MAX_LARGE rectangles as large as 1/LARGE of all stay out of a BVH (`large`)
# the XML plugins this module reads, with every parameter Mitsuba 3 reads for them
PLUGINS = {"rectangle": ("to_world", "flip_normals", "silhouette_sampling_weight"),
           "disk": ("to_world", "flip_normals", "silhouette_sampling_weight")}


@dataclass(eq=False)
class Rectangle:
    """Mitsuba's `rectangle`: [-1,1]^2 in the local xy-plane, normal +z, placed by `to_world`; with `disk`,
    Mitsuba's `disk`: the unit disk in that plane."""

    to_world: np.ndarray
    bsdf: BSDF
    radiance: tuple[float, float, float] | None = None
    name: str = ""
    disk: bool = False
    sampling_weight: float = 1.0      # an area emitter's (tracer.lights.choice)

    @property
    def center(self) -> np.ndarray:
        return self.to_world[:3, 3].copy()

    @property
    def edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Half-edge vectors: the images of local +x and +y."""
        return self.to_world[:3, 0].copy(), self.to_world[:3, 1].copy()

    @property
    def dual_edges(self) -> tuple[np.ndarray, np.ndarray]:
        """Rows of the inverse transform: dot(p - center, du) is the local x coordinate of p."""
        inv = np.linalg.inv(self.to_world[:3, :3])
        return inv[0].copy(), inv[1].copy()

    @property
    def normal(self) -> np.ndarray:
        return transform.apply_normal(self.to_world, [0.0, 0.0, 1.0])[0]

    @property
    def area(self) -> float:
        e1, e2 = self.edges
        return (np.pi if self.disk else 4.0) * float(np.linalg.norm(np.cross(e1, e2)))

    def extent_points(self) -> list[np.ndarray]:
        """The midpoints of its bounding square's edges (the scene's length scale, Scene.extent)."""
        return [self.center + s * e for e in self.edges for s in (-1, 1)]


def from_xml(ctx, props, a: ShapeArgs) -> Rectangle:
    props.finish()
    to_world = a.to_world
    if a.flip:   # the normal is the image of local +z: mirror z, which leaves the shape in place
        to_world = to_world @ np.diag([1.0, 1.0, -1.0, 1.0])
    return Rectangle(to_world, a.bsdf, a.radiance, a.name, disk=a.kind == "disk", sampling_weight=a.sampling_weight)


def ray_rectangle(o: Array3f, d: Array3f, center, du, dv, n, t_min, t_max) -> tuple[Float, Float, Float]:
    """Ray-plane intersection (eq. 2-4) and a bounds test in the rectangle's own coordinates.

    `du`, `dv` are the dual edge vectors, so dot(p - center, du) is the local x in [-1, 1].
    Returns t (inf on a miss) and the hit's local coordinates (x, y). A ray parallel to the plane (N.D = 0)
    misses.
    """
    cos_nd = dr.dot(n, d)                                        # eq. 2
    t = dr.dot(n, center - o) / cos_nd                           # eq. 3
    rel = dr.fma(d, t, o) - center                               # eq. 4, relative to the centre
    x, y = dr.dot(rel, du), dr.dot(rel, dv)
    bound = 1.0 + EDGE_MARGIN
    inside = (dr.abs(x) <= bound) & (dr.abs(y) <= bound)
    hit = (cos_nd != 0) & inside & (t > t_min) & (t < t_max)
    return dr.select(hit, t, INF), x, y


class RectangleBVH(BVHKernel):
    """Rectangles and disks in a BVH over their bounding boxes (each box given to the build as the triangle
    of its corners lo, hi, hi); a leaf slot's row holds the centre, the primitive id, the dual edges, the
    normal and whether it is a disk: what ray_rectangle reads."""

    def __init__(self, shapes: list[Rectangle], prims: np.ndarray):
        corners = corners_of(shapes)
        lo, hi = corners.min(1), corners.max(1)
        tables = layout(np.stack([lo, hi, hi], 1))
        self._set_nodes(tables)
        rows = leaf_rows(np.asarray(prims)[tables.order], 0, 16)   # (centre, prim, du, 0, dv, 0, n, disk)
        for k, r in enumerate(tables.order):
            du, dv = shapes[r].dual_edges
            rows[k, :3], rows[k, 4:7], rows[k, 8:11], rows[k, 12:15] = shapes[r].center, du, dv, shapes[r].normal
            rows[k, 15] = 1.0 if shapes[r].disk else 0.0
        self.prims = Float(rows.ravel())

    def _primitive(self, slot, o, d, t_min, t_max, skip, target):
        """The rectangle or disk in leaf slot `slot`: (t, prim, x, y) as the unrolled test's (RectangleSet)."""
        x = dr.gather(ArrayXf, self.prims, slot, shape=(16, dr.width(slot)))
        prim = leaf_prim(x)
        t, u, v = ray_rectangle(o, d, Array3f(x[0], x[1], x[2]), Array3f(x[4], x[5], x[6]),
                                Array3f(x[8], x[9], x[10]), Array3f(x[12], x[13], x[14]), t_min, t_max)
        t = dr.select((x[15] > 0) & (dr.fma(u, u, v * v) > 1.0), INF, t)
        out = prim == skip
        if target is not None:
            out |= prim == target
        return dr.select(out, INF, t), prim, u, v


def corners_of(shapes: list[Rectangle]) -> np.ndarray:
    """(count, 4, 3) the corners of rectangles (of disks' bounding squares)."""
    return np.reshape([r.center + a * e1 + b * e2 for r in shapes for e1, e2 in [r.edges]
                       for a in (-1, 1) for b in (-1, 1)], (-1, 4, 3))


def large(corners: np.ndarray) -> list[int]:
    """Of rectangles and disks with `corners` (corners_of), those that stay out of their BVH: the largest
    MAX_LARGE of those whose box spans 1/LARGE of all their bounds along some axis (a room's walls). Such
    boxes overlap the tree's nodes, so that most rays would visit them all; tested one by one, each costs one
    test (see RectangleSet.uses_bvh)."""
    size = np.ptp(corners, axis=1)
    share = (size / np.maximum(np.ptp(corners.reshape(-1, 3), axis=0), 1e-30)).max(1)
    order = np.argsort(-share, kind="stable")[:MAX_LARGE]
    return sorted(int(k) for k in order if share[k] >= 1 / LARGE)


class RectangleSet(ShapeSet):
    kind = Rectangle
    planar = True

    def __init__(self, shapes: list[Rectangle], base: int):
        super().__init__(shapes, base)
        self.unrolled = list(range(self.count))     # the primitives (from base) tested one by one
        self.bvh_prims: list[int] = []              # the primitives in the BVH
        if self.uses_bvh(self.count):
            self.unrolled = large(self._corners.reshape(-1, 4, 3))
            inside = np.setdiff1d(np.arange(self.count), self.unrolled)
            self.bvh = RectangleBVH([self.shapes[k] for k in inside], self.base + inside)
            self.bvh_prims = [int(i) for i in self.base + inside]

    @staticmethod
    def uses_bvh(rectangles: int) -> bool:
        """Whether a RectangleSet of this many rectangles and disks puts them into a BVH (above BVH_THRESHOLD).
        Measured on tests/test_rectangle_bvh.py's room of n random rectangles and disks (a quarter emitting),
        128 x 128, path, 32 spp, max_depth 6, CPU seconds of a render (machine loaded, load ~12), unrolled
        against BVH (the largest 16 staying out of it, `large`): with warm kernel caches 0.12 against 0.13 at
        24, 0.14-0.16 against 0.21 at 32, 0.16-0.20 against 0.18-0.21 at 48; a first render, compiling,
        0.99 against 1.00-1.18 at 24, 1.83-1.95 against 0.94-1.12 at 48, 2.64-3.48 against 1.08-1.31 at 96:
        the unrolled kernel compiles anew for every count and grows with it, the BVH's serves every count.
        Unrolled wins at 32 once compiled, the two tie at 48, where a first render favours the BVH by 2x."""
        return rectangles > BVH_THRESHOLD

    def walked_by_shadow_rays(self, occluders: set[int]) -> bool:
        return self.bvh is not None and any(p in occluders for p in self.bvh_prims)

    def normals(self) -> np.ndarray:
        return np.array([r.normal for r in self.shapes]).reshape(-1, 3)

    def frames(self) -> np.ndarray:
        return np.array([[r.center, *r.edges] for r in self.shapes]).reshape(-1, 3, 3)

    def culling_planes(self) -> list[tuple[int, np.ndarray, np.ndarray]]:
        return [(self.base + i, r.center, r.normal) for i, r in enumerate(self.shapes)]

    def sides(self, p0: np.ndarray, n: np.ndarray) -> np.ndarray:
        return (self._corners - p0) @ n

    @cached_property
    def _corners(self) -> np.ndarray:
        """(4 count, 3) the corners of the rectangles (of the disks' bounding squares)."""
        return corners_of(self.shapes).reshape(-1, 3)

    def describe(self) -> str:
        return f"{self.count} rectangles (ray-plane, eq. 2-4{', in a BVH' if self.bvh is not None else ''})"

    def _constants(self, k: int) -> tuple[Array3f, ...]:
        """Rectangle k's centre, dual edges du, dv, normal and edges e1, e2 as run-time constants (the
        directions' zeros and ones folded, jit.opaque_f); new variables at each call, which callers may update
        in place."""
        r = self.shapes[k]
        return (opaque_vec3(r.center), *(opaque_vec3(v, fold=True) for v in (*r.dual_edges, r.normal, *r.edges)))

    def candidates(self, o, d, t_min, skip, target, only):
        skip, target = self.local_ends(skip, target)
        for k in self.unrolled:
            if only is not None and self.base + k not in only:
                continue
            center, du, dv, n, _, _ = self._constants(k)
            t, x, y = ray_rectangle(o, d, center, du, dv, n, t_min, INF)
            if self.shapes[k].disk:
                t = dr.select(dr.fma(x, x, y * y) > 1.0, INF, t)
            yield self.prim(k), exclude(t, k, skip, target), x, y

    def uv(self, prim, valid, p, b1, b2, uv):
        """Mitsuba's: a rectangle's local (x, y) in [-1, 1]^2 mapped to [0, 1]^2; a disk's polar (r, phi / 2 pi)."""
        if not self.shapes:
            return uv
        local = self.local(prim)
        mine = local < self.size
        u, v = dr.fma(b1, 0.5, 0.5), dr.fma(b2, 0.5, 0.5)
        disks = [k for k, r in enumerate(self.shapes) if r.disk]
        if disks:
            is_disk = Bool(False)
            for k in disks:
                is_disk |= local == k
            turn = dr.atan2(b2, b1) * (0.5 / dr.pi)
            u = dr.select(is_disk, dr.sqrt(dr.fma(b1, b1, b2 * b2)), u)
            v = dr.select(is_disk, dr.select(turn < 0, turn + 1.0, turn), v)
        return dr.select(mine, u, uv[0]), dr.select(mine, v, uv[1])

    def tangent(self, prim, valid, p, b1, b2, dpdu):
        """Mitsuba's dp/du: a rectangle's local x axis; a disk's radial direction (local (x, y, 0))."""
        local = self.local(prim)
        for k, r in enumerate(self.shapes):
            *_, e1, e2 = self._constants(k)
            dpdu = dr.select(local == k, dr.fma(e1, b1, e2 * b2) if r.disk else e1, dpdu)
        return dpdu

    def sample(self, r: Rectangle, lo: int, u1: Float, u2: Float, geo) -> tuple[Array3f, Array3f, UInt32]:
        center, _, _, n, e1, e2 = self._constants(lo - self.base)
        a, b = square_to_uniform_disk_concentric(u1, u2) if r.disk else (2.0 * u1 - 1.0, 2.0 * u2 - 1.0)
        return center + e1 * a + e2 * b, n, self.prim(lo - self.base)


class EmitterTable:
    """Emitting rectangles and disks as rows of a table, sampled by index: one gather for the light a
    sample chose, not one unrolled sample per light. A row: centre, edges, normal, radiance, the area
    density of sampling it (the light's choice included), its primitive and whether it is a disk."""
    WIDTH = 20

    def __init__(self, lights: list[Rectangle], prims: list[int], pdf_area: list[float]):
        rows = aligned_zeros((len(lights), self.WIDTH), HOST_FLOAT)   # read in packets: see aligned_zeros
        for row, r, prim, pdf in zip(rows, lights, prims, pdf_area):
            e1, e2 = r.edges
            row[:15] = np.concatenate([r.center, e1, e2, r.normal, r.radiance])
            row[15], row[16], row[17] = pdf, prim, 1.0 if r.disk else 0.0
        self.count, self.any_disk = len(lights), any(r.disk for r in lights)
        self.last = opaque_u32(self.count - 1)       # a run-time constant: every count runs the same kernel
        self.rows = Float(rows.ravel())

    def sample(self, k: UInt32, u1: Float, u2: Float) -> tuple[Array3f, Array3f, Array3f, Float, UInt32]:
        """Light k's (point, normal, radiance, pdf_area, primitive) for a point uniform on it, as
        RectangleSet.sample places it."""
        x = dr.gather(ArrayXf, self.rows, dr.minimum(k, self.last), shape=(self.WIDTH, dr.width(k)))
        a, b = 2.0 * u1 - 1.0, 2.0 * u2 - 1.0
        if self.any_disk:
            da, db = square_to_uniform_disk_concentric(u1, u2)
            disk = x[17] > 0
            a, b = dr.select(disk, da, a), dr.select(disk, db, b)
        center, e1, e2 = (Array3f(x[i], x[i + 1], x[i + 2]) for i in (0, 3, 6))
        return (center + e1 * a + e2 * b, Array3f(x[9], x[10], x[11]), Array3f(x[12], x[13], x[14]), x[15],
                UInt32(x[16]))
