"""The choice of one light per shadow ray among a scene's lights, and the probability of that choice, which
every light's density for MIS includes (Veach's thesis, sec. 9.2: the density of a light sample is the
choice's probability times the density on the light chosen).

As Mitsuba 3's Scene::sample_emitter: lights are chosen in proportion to their `sampling_weight` where a
scene gives one other than 1 (a weight of 0: never chosen, so a delta light with weight 0 adds nothing;
negative weights, or all 0, are refused, as Mitsuba refuses them); otherwise by the tracer's policy:

- "uniform": each light with probability 1 / n (Mitsuba's default);
- "power": in proportion to an estimate of each light's emitted power (power(); pbrt-v4's
  PowerLightSampler, Pharr, Jakob and Humphreys, Physically Based Rendering, 4th ed., sec. 12.6.3);
- "mixed": half of each (a defensive mixture, Hesterberg 1995: no light's probability falls below half its
  uniform one, so the variance is at most about twice uniform choice's).

Any choice that gives every light that emits a positive probability leaves the estimate unbiased; the
policies differ in variance only. DEFAULT is uniform because nothing beat it: on the project's 17 scenes with
lights of unequal power, power-proportional choice gave 1.35 times uniform's error at equal time (geometric mean;
worse on 12, up to 4.4 times where the environment's power, over the scene's bounding sphere, far exceeds what
reaches a room), the mixture 1.00 at equal spp and 1.005 at equal time (worse on 8, up to 1.6 times):
reports/light_choice.md (`validate light-choice`). The other policies are kept for that study; a scene that
wants another choice states sampling_weight, which Mitsuba reads too.
A non-uniform choice is a cumulative table searched by binary search (one gather per step), not one
unrolled test per light.
"""
from __future__ import annotations

import drjit as dr
import numpy as np

from ..jit import Float, UInt32, opaque_f, opaque_u32
from ..sampling import GuidedCDF
from .constant import ConstantEnvironment
from .directional import DirectionalLight
from .envmap import LUMINANCE, EnvironmentMap
from .point import PointLight

POLICIES = ("uniform", "power", "mixed")
DEFAULT = "uniform"


class LightChoice:
    """Relative weights over a scene's lights, in the kernel's order (area lights, delta lights, the
    environment). `pmf(k)`: the probability that light k is chosen; `sample(u)`: the index chosen by u in
    [0, 1)."""

    def __init__(self, weights: list[float], policy: str = "uniform"):
        self.weights = np.asarray(weights, float)
        self.n = len(self.weights)
        self.total = float(self.weights.sum()) if self.n else 0.0
        self.uniform = bool(np.all(self.weights == self.weights[0])) if self.n else True
        if self.uniform:               # w / (n w) is 1 / n: the same arithmetic as a count of lights
            self.weights, self.total = np.ones(self.n), float(self.n)
        self._cdf = None
        self.policy = policy           # how the weights were set: "uniform", "sampling_weight" or "power"

    def describe(self) -> str:
        if self.n < 2:
            return "one light" if self.n else "no lights"
        how = {"sampling_weight": "by their sampling_weight", "power": "in proportion to their power",
               "mixed": "half uniformly, half in proportion to their power"}
        return f"one chosen per shadow ray {'uniformly' if self.uniform else how[self.policy]}"

    def pmf(self, k: int) -> float:
        return float(self.weights[k]) / self.total

    def pdf_area(self, k: int, area: float) -> float:
        """The area density of a point uniform on light k of area `area`, the choice included."""
        return float(self.weights[k]) / (self.total * area)

    def sample(self, u: Float) -> UInt32:
        if self.uniform:     # the count as a run-time constant: scenes of other light counts run the same kernel
            return dr.minimum(UInt32(u * opaque_f(self.n)), opaque_u32(self.n - 1))
        if self._cdf is None:
            cdf = np.cumsum(self.weights) / self.total
            cdf[np.flatnonzero(self.weights)[-1]:] = 1.0    # u < 1 never reaches the trailing zero weights
            self._cdf = GuidedCDF(cdf.astype(np.float32))
        # the first k with cdf[k] > u: a light of weight 0 spans an empty interval and is never chosen
        return self._cdf.search(u)


def luminance(rgb) -> float:
    return float(np.asarray(rgb, float) @ LUMINANCE)


def power(light, radius: float) -> float:
    """An estimate of a light's emitted power (luminance of watts), `radius` the scene's bounding sphere's:
    a diffuse area light pi A L (one-sided, Mitsuba's `area`); a point light 4 pi I; a spot light I times its
    falloff's integral over the sphere; a projector pi times its image's mean irradiance times the area of its
    frustum's section at distance 1 (its intensity is E pi / cos^3, and d omega = cos^3 dA there); a
    directional light E pi r^2 (what crosses the scene's bounding disk); an environment 4 pi^2 r^2 times its
    mean radiance over directions (what enters the bounding sphere: pi L per unit area; pbrt-v4's Phi of its
    infinite lights)."""
    if isinstance(light, PointLight):
        return luminance(light.intensity) * _point_solid_angle(light)
    if isinstance(light, DirectionalLight):
        return luminance(light.irradiance) * np.pi * radius ** 2
    if isinstance(light, ConstantEnvironment):
        return luminance(light.radiance) * 4 * np.pi ** 2 * radius ** 2
    if isinstance(light, EnvironmentMap):
        h = light.image.shape[0]
        sin_theta = np.sin(np.pi * (np.arange(h) + 0.5) / h)
        mean = float(((light.image.astype(float) @ LUMINANCE).mean(axis=1) * sin_theta).sum() / sin_theta.sum())
        return mean * 4 * np.pi ** 2 * radius ** 2
    return luminance(light.radiance) * np.pi * light.area    # an emitting shape


def _point_solid_angle(light: PointLight) -> float:
    """The integral over the sphere of a point light's intensity profile, times its texture's mean."""
    texture = 1.0 if light.image is None else luminance(np.asarray(light.image.image, float).reshape(-1, 3).mean(0))
    if light.projection is not None:
        tan_x, tan_y = light.projection
        return texture * np.pi * 4 * tan_x * tan_y
    if light.spot is None:
        return 4 * np.pi
    _, cutoff, beam = light.spot        # full within beam, linear in angle to 0 at cutoff (point.profile)
    theta = np.linspace(0.0, np.radians(cutoff), 4097)
    falloff = np.clip((np.radians(cutoff) - theta) / np.radians(cutoff - beam), 0.0, 1.0)
    return texture * 2 * np.pi * np.trapezoid(falloff * np.sin(theta), theta)


def choose(lights: list, explicit: list[float], policy: str, radius: float) -> LightChoice:
    """The choice over `lights` (kernel order): by their sampling weights `explicit` where some differs
    from 1 (Mitsuba's), else by `policy`."""
    if policy not in POLICIES:
        raise ValueError(f"light choice '{policy}': one of {', '.join(POLICIES)}")
    if any(w != 1.0 for w in explicit):
        return LightChoice(explicit, "sampling_weight")
    if policy == "uniform":
        return LightChoice(explicit, policy)
    weights = np.array([power(light, radius) for light in lights])
    if not np.any(weights > 0):            # nothing emits: any choice will do
        return LightChoice(explicit, policy)
    if policy == "mixed":
        weights = 0.5 / len(lights) + 0.5 * weights / weights.sum()
    return LightChoice(weights, policy)
