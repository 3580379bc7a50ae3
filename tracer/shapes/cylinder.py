"""Mitsuba's `cylinder` (an open tube): the quadratic ray test in its frame and the radial normal."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import drjit as dr
import numpy as np

from ..jit import INF, Array3f, Bool, Float, UInt32
from .base import ShapeArgs, ShapeSet

if TYPE_CHECKING:
    from ..materials import BSDF

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


def ray_cylinder(o: Array3f, d: Array3f, to_local: np.ndarray, t_min, t_max, leaving: Bool) -> Float:
    """Nearest t in (t_min, t_max) where o + t d meets the open tube x^2 + y^2 = 1, 0 <= z <= 1 of the frame
    with inverse affine map `to_local` (inf if none). The quadratic in the frame's x, y is solved as
    ray_sphere's (Haines' discriminant, the stable pair of roots); `leaving` marks rays that start on this
    tube: they can only meet its far side, and only when heading inward."""
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


class CylinderSet(ShapeSet):
    kind = Cylinder
    def sides(self, p0: np.ndarray, n: np.ndarray) -> np.ndarray:
        return (np.reshape([c.corners for c in self.shapes], (-1, 3)) - p0) @ n

    def describe(self) -> str:
        return f"{self.count} cylinders (quadratic)"

    def candidates(self, o, d, t_min, skip, target, only):
        for k, c in enumerate(self.shapes):
            i = self.base + k
            t = ray_cylinder(o, d, np.linalg.inv(c.to_world), t_min, INF, skip == i)
            yield i, (t if target is None else dr.select(target == i, INF, t)), None, None

    def normal(self, prim: UInt32, p: Array3f, n: Array3f) -> Array3f:
        for k, c in enumerate(self.shapes):
            n = dr.select(prim == self.base + k, _radial_normal(c, p), n)
        return n


    def uv(self, prim, valid, p, b1, b2, uv):
        """Mitsuba's: (phi / 2 pi, z) of p in the tube's frame, phi in [0, 2 pi) from local +x towards +y."""
        u, v = uv
        for k, c in enumerate(self.shapes):
            m = np.linalg.inv(c.to_world)
            x, y, z = (p.x * float(m[r, 0]) + p.y * float(m[r, 1]) + p.z * float(m[r, 2]) + float(m[r, 3])
                       for r in range(3))
            phi = dr.atan2(y, x)
            phi = dr.select(phi < 0, phi + 2.0 * dr.pi, phi)
            here = prim == self.base + k
            u, v = dr.select(here, phi * (0.5 / dr.pi), u), dr.select(here, z, v)
        return u, v

    def tangent(self, prim, valid, p, b1, b2, dpdu):
        """Mitsuba's dp/du: along phi, the local (-y, x, 0) in world space."""
        for k, c in enumerate(self.shapes):
            m = np.linalg.inv(c.to_world)
            x, y = (p.x * float(m[r, 0]) + p.y * float(m[r, 1]) + p.z * float(m[r, 2]) + float(m[r, 3])
                    for r in range(2))
            w = c.to_world
            along = Array3f(*(float(w[j, 1]) * x - float(w[j, 0]) * y for j in range(3)))
            dpdu = dr.select(prim == self.base + k, along, dpdu)
        return dpdu


def _radial_normal(c: Cylinder, p: Array3f) -> Array3f:
    """The tube's normal at p: the local radial direction (x, y, 0) taken to world space as a normal, outward
    unless the cylinder is flipped."""
    m = np.linalg.inv(c.to_world)
    x, y = (p.x * float(m[r, 0]) + p.y * float(m[r, 1]) + p.z * float(m[r, 2]) + float(m[r, 3]) for r in range(2))
    sign = -1.0 if c.flipped else 1.0
    return dr.normalize(Array3f(*((x * float(m[0, k]) + y * float(m[1, k])) * sign for k in range(3))))
