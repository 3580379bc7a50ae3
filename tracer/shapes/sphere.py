"""Mitsuba's `sphere`: the quadratic ray test, the outward normal, area sampling; many spheres in a BVH
over their bounding boxes."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import drjit as dr
import numpy as np

from .. import transform
from ..jit import INF, Array3f, ArrayXf, Bool, Float, UInt32, gather_vec3, opaque_f, opaque_vec3, row_table
from ..sampling import square_to_uniform_sphere
from .base import ShapeArgs, ShapeSet
from .bvh import BVHKernel, layout, leaf_prim, leaf_rows

if TYPE_CHECKING:
    from ..materials import BSDF

PLUGINS = {"sphere": ("center", "radius", "to_world", "flip_normals", "silhouette_sampling_weight")}
BVH_THRESHOLD = 20   # spheres above which a BVH beats the unrolled tests (measured: see SphereSet.uses_bvh)


@dataclass(eq=False)
class Sphere:
    center: np.ndarray
    radius: float
    bsdf: BSDF
    name: str = ""
    radiance: tuple[float, float, float] | None = None   # an area light on it emits outward
    frame: np.ndarray = field(default_factory=lambda: np.eye(3))   # to_world's rotation: the local axes (columns)
    sampling_weight: float = 1.0      # an area emitter's (tracer.lights.choice)

    @property
    def area(self) -> float:
        return 4.0 * np.pi * self.radius * self.radius

    def extent_points(self) -> list[np.ndarray]:
        return [np.stack([self.center - self.radius, self.center + self.radius])]


def from_xml(ctx, props, a: ShapeArgs) -> Sphere:
    center = props.get("center", np.zeros(3), ("point",))
    radius = float(props.get("radius", 1.0, ("float", "integer")))
    props.finish()
    if a.flip:
        raise ctx.error(props.values["flip_normals"], "flip_normals on a sphere is unsupported")
    linear = a.to_world[:3, :3]
    scale = float(np.cbrt(abs(np.linalg.det(linear))))
    if not np.allclose(linear.T @ linear, scale * scale * np.eye(3), rtol=0, atol=1e-6 * scale * scale):
        raise ctx.error(a.node, "a sphere's to_world must scale uniformly (no shear or non-uniform scale)")
    center = transform.apply_point(a.to_world, center)[0]
    radius *= scale
    if radius <= 0:
        raise ctx.error(a.node, f"sphere radius must be positive, got {radius}")
    return Sphere(center, radius, a.bsdf, a.name, a.radiance, linear / scale, a.sampling_weight)


def ray_sphere(o: Array3f, d: Array3f, center, r2, t_min, t_max, leaving: Bool) -> Float:
    """Nearest root of |o + t d - c|^2 = r2 (the squared radius) in (t_min, t_max), inf if none.

    The discriminant is formed as r^2 - |oc - b d|^2 (Haines et al., Ray Tracing Gems ch. 7), which
    stays accurate far from the sphere. `leaving` marks rays that start on this sphere: they can only
    hit its far side, and only when heading inward.
    """
    oc = o - center
    b = dr.dot(oc, d)
    perp = dr.fma(d, -b, oc)
    disc = r2 - dr.squared_norm(perp)
    c = dr.squared_norm(oc) - r2
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


class SphereBVH(BVHKernel):
    """Spheres in a BVH over their bounding boxes (each box given to the build as the triangle of its
    corners lo, hi, hi); a leaf slot's row holds the centre, the primitive id and the squared radius."""

    def __init__(self, spheres: list[Sphere], prim_base: int):
        center = np.array([s.center for s in spheres], float).reshape(-1, 3)
        radius = np.array([s.radius for s in spheres], float)[:, None]
        tables = layout(np.stack([center - radius, center + radius, center + radius], 1))
        self._set_nodes(tables)
        rows = leaf_rows(tables.order, prim_base, 8)     # (centre, prim, r^2, 0, 0, 0)
        rows[:, :3], rows[:, 4] = center[tables.order], radius[tables.order, 0] ** 2
        self.prims = Float(rows.ravel())

    def _primitive(self, slot, o, d, t_min, t_max, skip, target):
        """The sphere in leaf slot `slot`: (t, prim, 0, 0) as BVHKernel's, by ray_sphere."""
        x = dr.gather(ArrayXf, self.prims, slot, shape=(8, dr.width(slot)))
        prim = leaf_prim(x)
        t = ray_sphere(o, d, Array3f(x[0], x[1], x[2]), x[4], t_min, t_max, prim == skip)
        if target is not None:
            t = dr.select(prim == target, INF, t)
        return t, prim, Float(0), Float(0)


class SphereSet(ShapeSet):
    kind = Sphere

    def __init__(self, shapes: list[Sphere], base: int):
        super().__init__(shapes, base)
        if self.uses_bvh(self.count):
            self.bvh = SphereBVH(self.shapes, base)
            self.centers = row_table(np.array([s.center for s in self.shapes]))
            self.axes = row_table(np.array([s.frame.T for s in self.shapes]))

    @staticmethod
    def uses_bvh(spheres: int) -> bool:
        """Whether a SphereSet of this many spheres puts them into a BVH (above BVH_THRESHOLD). Measured on
        the Cornell box's walls and light around small spheres, path, 256 x 256, 16 spp, median of 5
        renders, unrolled against BVH: 0.193 against 0.223 s at 16 spheres, 0.243 against 0.229 s at 24,
        0.278 against 0.207 s at 32; unrolled, every new count compiles its kernel anew (0.5 s at 24, 5-8 s
        at 400 spheres), the BVH's kernel serves every count."""
        return spheres > BVH_THRESHOLD

    def sides(self, p0: np.ndarray, n: np.ndarray) -> np.ndarray:
        return np.array([[(s.center - p0) @ n - s.radius, (s.center - p0) @ n + s.radius]
                         for s in self.shapes]).ravel()

    def describe(self) -> str:
        return f"{self.count} spheres (quadratic, {'in a BVH' if self.bvh is not None else 'brute force'})"

    def _constants(self, k: int) -> tuple[Array3f, Float, Float, list[Array3f]]:
        """Sphere k's centre, squared radius, radius and frame's axes as run-time constants (the axes' zeros
        and ones folded, jit.opaque_f); new variables at each call, which callers may update in place."""
        s = self.shapes[k]
        return (opaque_vec3(s.center), opaque_f(s.radius * s.radius), opaque_f(s.radius),
                [opaque_vec3(a, fold=True) for a in s.frame.T])

    def candidates(self, o, d, t_min, skip, target, only):
        skip, target = self.local_ends(skip, target)
        for k, s in enumerate(self.shapes if self.bvh is None else ()):
            center, r2, _, _ = self._constants(k)
            t = ray_sphere(o, d, center, r2, t_min, INF, skip == k)
            yield self.prim(k), (t if target is None else dr.select(target == k, INF, t)), None, None

    def normal(self, prim: UInt32, p: Array3f, n: Array3f) -> Array3f:
        if not self.shapes:
            return n
        local = self.local(prim)
        is_sphere = local < self.size
        if self.bvh is not None:
            center = gather_vec3(self.centers, local, is_sphere)
        else:
            center = self._constants(0)[0]
            for k in range(1, self.count):
                center = dr.select(local == k, self._constants(k)[0], center)
        return dr.select(is_sphere, dr.normalize(p - center), n)  # unit even where p is off the surface

    def uv(self, prim, valid, p, b1, b2, uv):
        """Mitsuba's: the spherical angles of p in the sphere's local frame, (phi / 2 pi, theta / pi), phi in
        [0, 2 pi) from local +x towards +y, theta from local +z."""
        if not self.shapes:
            return uv
        is_sphere, (x, y, z), _ = self._local(prim, valid, p)
        phi = dr.atan2(y, x)
        phi = dr.select(phi < 0, phi + 2.0 * dr.pi, phi)
        theta = dr.acos(dr.clip(z * dr.rsqrt(dr.fma(x, x, dr.fma(y, y, z * z))), -1.0, 1.0))
        return dr.select(is_sphere, phi * (0.5 / dr.pi), uv[0]), dr.select(is_sphere, theta / dr.pi, uv[1])

    def tangent(self, prim, valid, p, b1, b2, dpdu):
        """Mitsuba's dp/du: along phi, the local (-y, x, 0) in world space."""
        if not self.shapes:
            return dpdu
        is_sphere, (x, y, _), axes = self._local(prim, valid, p)
        return dr.select(is_sphere, axes[1] * x - axes[0] * y, dpdu)

    def _local(self, prim, valid, p) -> tuple[Bool, tuple[Float, Float, Float], list[Array3f]]:
        """(lanes on one of the set's spheres, p in its local frame, the frame's axes in world space)."""
        local = self.local(prim)
        is_sphere = local < self.size
        if self.bvh is not None:
            center = gather_vec3(self.centers, local, is_sphere)
            axes = [gather_vec3(self.axes, local * 3 + j, is_sphere) for j in range(3)]
        else:
            center, _, _, axes = self._constants(0)
            for k in range(1, self.count):
                here = local == k
                c, _, _, a = self._constants(k)
                center = dr.select(here, c, center)
                axes = [dr.select(here, x, y) for x, y in zip(a, axes)]
        return is_sphere, tuple(dr.dot(p - center, a) for a in axes), axes

    def sample(self, s: Sphere, lo: int, u1: Float, u2: Float, geo) -> tuple[Array3f, Array3f, UInt32]:
        center, _, radius, _ = self._constants(lo - self.base)
        n = square_to_uniform_sphere(u1, u2)
        return dr.fma(n, radius, center), n, self.prim(lo - self.base)
