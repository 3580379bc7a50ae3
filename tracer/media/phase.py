"""Phase functions, as Mitsuba 3 defines them: `isotropic` (1 / 4 pi) and Henyey-Greenstein `hg` with
asymmetry g in (-1, 1) (Mitsuba's default 0.8). Directions: d is the direction the light travels before the
scattering event (Mitsuba's wi is -d) and wo the direction after it; g > 0 scatters forward (wo near d).

    p(cos theta) = (1 - g^2) / (4 pi (1 + g^2 - 2 g cos theta)^(3/2)),   cos theta = d . wo

(Henyey and Greenstein 1941; pbrt-v4 sec. 11.3.1). Both are sampled exactly: the weight p / pdf is 1."""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from ..jit import Array2f, Array3f, Float
from ..sampling import coordinate_system, square_to_uniform_sphere

PLUGINS = {"isotropic": (), "hg": ("g",)}
INV_FOUR_PI = 1.0 / (4.0 * np.pi)


@dataclass(frozen=True)
class Phase:
    kind: str = "isotropic"
    g: float = 0.0

    @property
    def isotropic(self) -> bool:
        return self.kind == "isotropic" or abs(self.g) < 1e-7


def from_xml(ctx, props, node) -> Phase:
    if props.kind == "isotropic":
        props.finish()
        return Phase()
    g = float(props.get("g", 0.8, ("float", "integer")))
    props.finish()
    if not -1.0 < g < 1.0:
        raise ctx.error(node, f"the hg asymmetry g must lie in (-1, 1) (as in Mitsuba), got {g}")
    return Phase("hg", g)


def hg(g: float, cos_theta: Float) -> Float:
    """The Henyey-Greenstein density at cos theta = d . wo."""
    temp = 1.0 + g * g - 2.0 * g * cos_theta
    return INV_FOUR_PI * (1.0 - g * g) / (temp * dr.sqrt(temp))


def eval(phase: Phase, d: Array3f, wo: Array3f) -> Float:
    """p(d -> wo), also the density with which `sample` draws wo."""
    if phase.isotropic:
        return dr.full(Float, INV_FOUR_PI, dr.width(wo))
    return hg(phase.g, dr.dot(d, wo))


def sample(phase: Phase, d: Array3f, u: Array2f) -> tuple[Array3f, Float]:
    """wo drawn from p(d -> .) by inverting its CDF in cos theta, and its density."""
    if phase.isotropic:
        return square_to_uniform_sphere(u.x, u.y), Float(INV_FOUR_PI)
    g = phase.g
    s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u.x)
    cos_theta = (1.0 + g * g - s * s) / (2.0 * g)
    sin_theta = dr.safe_sqrt(1.0 - cos_theta * cos_theta)
    sin_phi, cos_phi = dr.sincos(2.0 * np.pi * u.y)
    s_axis, t_axis = coordinate_system(d)
    wo = s_axis * (sin_theta * cos_phi) + t_axis * (sin_theta * sin_phi) + d * cos_theta
    return wo, hg(g, cos_theta)
