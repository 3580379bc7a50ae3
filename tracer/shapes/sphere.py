"""Mitsuba's `sphere`: the quadratic ray test, the outward normal, area sampling."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import drjit as dr
import numpy as np

from ..jit import INF, Array3f, Bool, Float, UInt32, vec3
from ..sampling import square_to_uniform_sphere
from .base import ShapeSet

if TYPE_CHECKING:
    from ..materials import BSDF


@dataclass(eq=False)
class Sphere:
    center: np.ndarray
    radius: float
    bsdf: BSDF
    name: str = ""
    radiance: tuple[float, float, float] | None = None   # an area light on it emits outward

    @property
    def area(self) -> float:
        return 4.0 * np.pi * self.radius * self.radius

    def extent_points(self) -> list[np.ndarray]:
        return [np.stack([self.center - self.radius, self.center + self.radius])]


def ray_sphere(o: Array3f, d: Array3f, center, radius: float, t_min, t_max, leaving: Bool) -> Float:
    """Nearest root of |o + t d - c|^2 = r^2 in (t_min, t_max), inf if none.

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


class SphereSet(ShapeSet):
    def sides(self, p0: np.ndarray, n: np.ndarray) -> np.ndarray:
        return np.array([[(s.center - p0) @ n - s.radius, (s.center - p0) @ n + s.radius]
                         for s in self.shapes]).ravel()

    def describe(self) -> str:
        return f"{self.count} spheres (quadratic)"

    def candidates(self, o, d, t_min, skip, target, only):
        for k, s in enumerate(self.shapes):
            i = self.base + k
            t = ray_sphere(o, d, vec3(s.center), s.radius, t_min, INF, skip == i)
            yield i, (t if target is None else dr.select(target == i, INF, t)), None, None

    def normal(self, prim: UInt32, p: Array3f, n: Array3f) -> Array3f:
        if not self.shapes:
            return n
        is_sphere = (prim >= self.base) & (prim < self.base + self.count)
        center = vec3(self.shapes[0].center)
        for k, s in enumerate(self.shapes[1:], 1):
            center = dr.select(prim == self.base + k, vec3(s.center), center)
        return dr.select(is_sphere, dr.normalize(p - center), n)  # unit even where p is off the surface

    def sample(self, s: Sphere, lo: int, u1: Float, u2: Float, geo) -> tuple[Array3f, Array3f, UInt32]:
        n = square_to_uniform_sphere(u1, u2)
        return dr.fma(n, s.radius, vec3(s.center)), n, UInt32(lo)
