"""Mitsuba's `rectangle` and `disk`: ray-plane intersection (the report's eq. 2-4), area sampling."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import drjit as dr
import numpy as np

from .. import transform
from ..jit import INF, Array3f, Bool, Float, UInt32, vec3
from ..sampling import square_to_uniform_disk_concentric
from .base import ShapeArgs, ShapeSet, exclude
from .planar import EDGE_MARGIN

if TYPE_CHECKING:
    from ..materials import BSDF

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
    return Rectangle(to_world, a.bsdf, a.radiance, a.name, disk=a.kind == "disk")


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


class RectangleSet(ShapeSet):
    kind = Rectangle
    planar = True

    def normals(self) -> np.ndarray:
        return np.array([r.normal for r in self.shapes]).reshape(-1, 3)

    def frames(self) -> np.ndarray:
        return np.array([[r.center, *r.edges] for r in self.shapes]).reshape(-1, 3, 3)

    def culling_planes(self) -> list[tuple[int, np.ndarray, np.ndarray]]:
        return [(self.base + i, r.center, r.normal) for i, r in enumerate(self.shapes)]

    def sides(self, p0: np.ndarray, n: np.ndarray) -> np.ndarray:
        corners = [r.center + a * e1 + b * e2 for r in self.shapes for e1, e2 in [r.edges]
                   for a in (-1, 1) for b in (-1, 1)]
        return (np.reshape(corners, (-1, 3)) - p0) @ n

    def describe(self) -> str:
        return f"{self.count} rectangles (ray-plane, eq. 2-4)"

    def candidates(self, o, d, t_min, skip, target, only):
        for k, r in enumerate(self.shapes):
            i = self.base + k
            if only is not None and i not in only:
                continue
            du, dv = r.dual_edges
            t, x, y = ray_rectangle(o, d, vec3(r.center), vec3(du), vec3(dv), vec3(r.normal), t_min, INF)
            if r.disk:
                t = dr.select(dr.fma(x, x, y * y) > 1.0, INF, t)
            yield i, exclude(t, i, skip, target), x, y

    def uv(self, prim, valid, p, b1, b2, uv):
        """Mitsuba's: a rectangle's local (x, y) in [-1, 1]^2 mapped to [0, 1]^2; a disk's polar (r, phi / 2 pi)."""
        if not self.shapes:
            return uv
        mine = (prim >= self.base) & (prim < self.base + self.count)
        u, v = dr.fma(b1, 0.5, 0.5), dr.fma(b2, 0.5, 0.5)
        disks = [self.base + k for k, r in enumerate(self.shapes) if r.disk]
        if disks:
            is_disk = Bool(False)
            for i in disks:
                is_disk |= prim == i
            turn = dr.atan2(b2, b1) * (0.5 / dr.pi)
            u = dr.select(is_disk, dr.sqrt(dr.fma(b1, b1, b2 * b2)), u)
            v = dr.select(is_disk, dr.select(turn < 0, turn + 1.0, turn), v)
        return dr.select(mine, u, uv[0]), dr.select(mine, v, uv[1])

    def tangent(self, prim, valid, p, b1, b2, dpdu):
        """Mitsuba's dp/du: a rectangle's local x axis; a disk's radial direction (local (x, y, 0))."""
        for k, r in enumerate(self.shapes):
            e1, e2 = (vec3(e) for e in r.edges)
            dpdu = dr.select(prim == self.base + k, dr.fma(e1, b1, e2 * b2) if r.disk else e1, dpdu)
        return dpdu

    def sample(self, r: Rectangle, lo: int, u1: Float, u2: Float, geo) -> tuple[Array3f, Array3f, UInt32]:
        e1, e2 = r.edges
        a, b = square_to_uniform_disk_concentric(u1, u2) if r.disk else (2.0 * u1 - 1.0, 2.0 * u2 - 1.0)
        return vec3(r.center) + vec3(e1) * a + vec3(e2) * b, vec3(r.normal), UInt32(lo)
