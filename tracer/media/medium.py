"""Mitsuba 3's participating media: `homogeneous` (a constant extinction sigma_t, anywhere inside the shapes
that hold it) and `heterogeneous` (sigma_t from a volume, zero outside the volume's box), both with a
single-scattering albedo (constant or a volume), a `scale` on sigma_t and a phase function.

A medium is sampled as Mitsuba's Medium::sample_interaction samples it: a tentative collision at distance
t = -ln(1 - u) / m along the ray, m the majorant of the path's chosen colour channel: sigma_t itself in a
homogeneous medium (free-flight sampling: every collision is real), the largest value of scale * sigma_t
over the volume (the same for all channels) in a heterogeneous one (delta tracking: a collision is real with
probability sigma_t / m, null otherwise; Woodcock et al. 1965; Novak et al. 2018, sec. 3). The coefficients
at the collision are sigma_s = albedo * sigma_t, sigma_n = m - sigma_t."""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr

from ..jit import INF, Array3f, Bool, Float
from .phase import Phase
from .volumes import ConstVolume, GridVolume, VolumeKernel

KINDS = ("homogeneous", "heterogeneous")
PARAMETERS = ("albedo", "sigma_t", "scale", "sample_emitters", "has_spectral_extinction")


@dataclass(frozen=True, eq=False)
class Medium:
    kind: str
    sigma_t: ConstVolume | GridVolume
    albedo: ConstVolume | GridVolume
    scale: float = 1.0
    phase: Phase = Phase()
    sample_emitters: bool = True          # shadow rays from scattering events inside it
    spectral_extinction: bool = True      # Mitsuba's has_spectral_extinction (weights for a chromatic sigma_t)
    name: str = ""

    @property
    def homogeneous(self) -> bool:
        return self.kind == "homogeneous"

    @property
    def majorant(self) -> float:
        """A heterogeneous medium's majorant: scale times the largest value of sigma_t's volume."""
        return self.scale * self.sigma_t.max


@dataclass
class Interaction:
    """A tentative collision along a ray (Mitsuba's MediumInteraction): t = inf where none lies within the
    medium's interval; the coefficients there; `combined` the majorant; `mint` where the interval starts."""
    t: Float
    p: Array3f
    sigma_s: Array3f
    sigma_n: Array3f
    sigma_t: Array3f
    combined: Array3f
    mint: Float

    @property
    def valid(self) -> Bool:
        return dr.isfinite(self.t)


def channel_value(v: Array3f, channel) -> Float:
    """The component of v of each lane's colour channel (0, 1, 2)."""
    return dr.select(channel == 0, v.x, dr.select(channel == 1, v.y, v.z))


class MediumKernel:
    """One medium as kernel code; its constants are literals of the kernel."""

    def __init__(self, medium: Medium):
        self.medium = medium
        self.sigma_t, self.albedo = VolumeKernel(medium.sigma_t), VolumeKernel(medium.albedo)

    def sample_interaction(self, o: Array3f, d: Array3f, t_max: Float, u: Float, channel, active: Bool) -> Interaction:
        """Mitsuba's Medium::sample_interaction on the ray o + t d, 0 <= t <= t_max."""
        m = self.medium
        if m.homogeneous:
            hit, mint, maxt = Bool(True), Float(0.0), Float(t_max)
            combined = self.sigma_t.eval(o) * m.scale
        else:
            hit, mint, maxt = self.sigma_t.interval(o, d)
            hit &= active & (dr.isfinite(mint) | dr.isfinite(maxt))
            mint, maxt = dr.select(hit, dr.maximum(mint, 0.0), 0.0), dr.select(hit, dr.minimum(maxt, t_max), INF)
            combined = Array3f(m.majorant)
        t = mint - dr.log(1.0 - u) / channel_value(combined, channel)
        valid = active & hit & (t <= maxt)
        t = dr.select(valid, t, INF)
        p = dr.fma(d, dr.select(valid, t, 0.0), o)
        sigma_t = self.sigma_t.eval(p, valid) * m.scale
        sigma_s = sigma_t * self.albedo.eval(p, valid)
        sigma_n = Array3f(0.0) if m.homogeneous else combined - sigma_t
        return Interaction(t, p, sigma_s, sigma_n, sigma_t, combined, mint)
