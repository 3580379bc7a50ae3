"""Microfacet normal distributions as Mitsuba 3 defines them (its `render/microfacet.h`): Beckmann and GGX
(Trowbridge-Reitz), anisotropic roughness alpha_u / alpha_v along the local x / y axes, Smith's separable
shadowing-masking G = G1(wi, m) G1(wo, m), and the sampling of either all normals (density D(m) cos theta_m)
or only the normals visible from wi (density D_wi(m) = G1(wi, m) |wi.m| D(m) / cos theta_i).

Literature: Walter, Marschner, Li and Torrance, "Microfacet Models for Refraction through Rough Surfaces"
(EGSR 2007; Beckmann D (25) and its rational G1 (27), GGX D (33) and G1 (34), sampling (28)/(35));
Heitz, "Understanding the Masking-Shadowing Function in Microfacet-Based BRDFs" (JCGT 2014; anisotropic
D and the projected roughness in G1, section 5); Heitz and d'Eon, "Importance Sampling Microfacet-Based
BSDFs using the Distribution of Visible Normals" (EGSR 2014; stretch, sample the alpha = 1 slopes, rotate
and unstretch); Heitz, "Sampling the GGX Distribution of Visible Normals" (JCGT 2018) for GGX; Jakob, "An
Improved Visible Normal Sampling Routine for the Beckmann Distribution" (2014) for Beckmann.

`ggx` and `sample_visible` may be Python booleans (one branch traced) or per-lane masks (both computed and
selected), so that a kernel over several materials can carry them as data.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr

from ..jit import Array3f, Bool, Float
from ..sampling import square_to_uniform_disk_concentric

ALPHA_MIN = 1e-4            # Mitsuba clamps both roughnesses to this (a smooth BSDF is the model for zero)
INV_SQRT_PI = 0.5641895835477563


def pick(flag: bool | Bool, if_true, if_false):
    """if_true() where flag holds, if_false() elsewhere: only one is traced when flag is a Python bool."""
    if isinstance(flag, bool):
        return if_true() if flag else if_false()
    a, b = if_true(), if_false()
    if isinstance(a, tuple):
        return tuple(dr.select(flag, x, y) for x, y in zip(a, b))
    return dr.select(flag, a, b)


def mulsign(v, s: Float):
    """v times the sign of s (+1 at s = 0), as Dr.Jit's mulsign."""
    return v * dr.select(s >= 0, 1.0, -1.0)


@dataclass(frozen=True)
class Microfacet:
    """A distribution of microfacet normals about +z. Construct with `microfacet(...)`, which clamps the
    roughnesses as Mitsuba does. `isotropic` is True when alpha_u and alpha_v are one and the same array
    (Mitsuba's test too): sampling all normals then draws the azimuth uniformly."""

    ggx: bool | Bool
    alpha_u: Float
    alpha_v: Float
    sample_visible: bool | Bool = True
    isotropic: bool = False

    def scaled(self, factor: Float) -> Microfacet:
        """The distribution with both roughnesses multiplied by `factor` (Mitsuba's scale_alpha)."""
        if self.isotropic:
            a = self.alpha_u * factor
            return Microfacet(self.ggx, a, a, self.sample_visible, True)
        return Microfacet(self.ggx, self.alpha_u * factor, self.alpha_v * factor, self.sample_visible, False)

    # -- the distribution --------------------------------------------------------------------------------
    def D(self, m: Array3f) -> Float:
        """Microfacet normal density D(m) (per unit projected area: integral of D(m) cos theta_m = 1)."""
        au, av = self.alpha_u, self.alpha_v
        cos2 = m.z * m.z
        sx, sy = m.x / au, m.y / av

        def beckmann():    # Walter (25), anisotropic: exp(-tan^2 theta (cos^2 phi/au^2 + sin^2 phi/av^2))
            return dr.exp(-(sx * sx + sy * sy) / cos2) / (dr.pi * au * av * cos2 * cos2)

        def ggx():         # Walter (33), anisotropic (Heitz 2014, section 5.4)
            t = sx * sx + sy * sy + cos2
            return dr.rcp(dr.pi * au * av * t * t)

        d = pick(self.ggx, ggx, beckmann)
        return dr.select(d * m.z > 1e-20, d, 0.0)     # Mitsuba's guard against denormal results

    def smith_g1(self, v: Array3f, m: Array3f) -> Float:
        """Smith's masking of direction v by facets of normal m; 0 where v sees m's back."""
        xy_alpha_2 = dr.square(self.alpha_u * v.x) + dr.square(self.alpha_v * v.y)
        tan_theta_alpha_2 = xy_alpha_2 / dr.square(v.z)      # (alpha tan theta)^2, alpha projected on phi

        def beckmann():    # Walter (27): rational fit of the exact G1, exact 1 from a = 1.6 on
            a = dr.rsqrt(tan_theta_alpha_2)
            return dr.select(a >= 1.6, 1.0, (3.535 * a + 2.181 * a * a) / (1.0 + 2.276 * a + 2.577 * a * a))

        def ggx():         # Walter (34)
            return 2.0 / (1.0 + dr.sqrt(1.0 + tan_theta_alpha_2))

        g = pick(self.ggx, ggx, beckmann)
        g = dr.select(xy_alpha_2 == 0, 1.0, g)
        return dr.select(dr.dot(v, m) * v.z <= 0, 0.0, g)

    def G(self, wi: Array3f, wo: Array3f, m: Array3f) -> Float:
        """Smith's separable shadowing-masking."""
        return self.smith_g1(wi, m) * self.smith_g1(wo, m)

    # -- sampling ----------------------------------------------------------------------------------------
    def pdf(self, wi: Array3f, m: Array3f) -> Float:
        """Density of `sample`'s normals (solid angle of m): D_wi(m), or D(m) cos theta_m."""
        d = self.D(m)
        return d * pick(self.sample_visible, lambda: self.smith_g1(wi, m) * dr.abs(dr.dot(wi, m)) / wi.z,
                        lambda: m.z)

    def sample(self, wi: Array3f, u) -> tuple[Array3f, Float]:
        """A microfacet normal m and its density, from a uniform 2D sample u (u[0], u[1]); wi (upper
        hemisphere) matters only when sampling visible normals."""
        return pick(self.sample_visible, lambda: self._sample_visible(wi, u), lambda: self._sample_all(u))

    def _sample_all(self, u) -> tuple[Array3f, Float]:
        """All normals, density D(m) cos theta_m: the azimuth, then tan^2 theta by inverting its CDF
        (Walter (28) and (35), anisotropic as in Mitsuba)."""
        au, av = self.alpha_u, self.alpha_v
        if self.isotropic:
            sin_phi, cos_phi = dr.sincos(dr.two_pi * u[1])
            alpha_2 = au * au
        else:
            tmp = (av / au) * dr.tan(dr.two_pi * u[1])
            cos_phi = mulsign(dr.rsqrt(dr.fma(tmp, tmp, 1.0)), dr.abs(u[1] - 0.5) - 0.25)
            sin_phi = cos_phi * tmp
            alpha_2 = dr.rcp(dr.square(cos_phi / au) + dr.square(sin_phi / av))

        def beckmann():
            cos_theta = dr.rsqrt(1.0 - alpha_2 * dr.log(1.0 - u[0]))
            cos_theta_3 = dr.maximum(cos_theta * cos_theta * cos_theta, 1e-20)
            return cos_theta, (1.0 - u[0]) / (dr.pi * au * av * cos_theta_3)

        def ggx():
            tan_2 = alpha_2 * u[0] / (1.0 - u[0])
            cos_theta = dr.rsqrt(1.0 + tan_2)
            cos_theta_3 = dr.maximum(cos_theta * cos_theta * cos_theta, 1e-20)
            temp = 1.0 + tan_2 / alpha_2
            return cos_theta, dr.rcp(dr.pi * au * av * cos_theta_3 * temp * temp)

        cos_theta, pdf = pick(self.ggx, ggx, beckmann)
        sin_theta = dr.sqrt(1.0 - cos_theta * cos_theta)
        return Array3f(cos_phi * sin_theta, sin_phi * sin_theta, cos_theta), pdf

    def _sample_visible(self, wi: Array3f, u) -> tuple[Array3f, Float]:
        """Visible normals (Heitz and d'Eon 2014): stretch wi to the alpha = 1 configuration, sample its
        visible slopes, rotate back to wi's azimuth and unstretch."""
        au, av = self.alpha_u, self.alpha_v
        w = dr.normalize(Array3f(au * wi.x, av * wi.y, wi.z))
        sin_theta_2 = w.x * w.x + w.y * w.y
        inv = dr.rsqrt(sin_theta_2)
        flat = sin_theta_2 <= 4.0 * 2.0 ** -24        # azimuth undefined: Mitsuba's phi = 0
        cos_phi = dr.select(flat, 1.0, dr.clip(w.x * inv, -1.0, 1.0))
        sin_phi = dr.select(flat, 0.0, dr.clip(w.y * inv, -1.0, 1.0))
        sx, sy = pick(self.ggx, lambda: _ggx_visible_slopes(w.z, u), lambda: _beckmann_visible_slopes(w.z, u))
        slope_x = dr.fma(cos_phi, sx, -sin_phi * sy) * au
        slope_y = dr.fma(sin_phi, sx, cos_phi * sy) * av
        m = dr.normalize(Array3f(-slope_x, -slope_y, 1.0))
        return m, self.D(m) * self.smith_g1(wi, m) * dr.abs(dr.dot(wi, m)) / wi.z


def microfacet(ggx: bool | Bool, alpha_u, alpha_v=None, sample_visible: bool | Bool = True) -> Microfacet:
    """A distribution with Mitsuba's clamp of the roughnesses to ALPHA_MIN; isotropic when alpha_v is
    omitted."""
    au = dr.maximum(Float(alpha_u), ALPHA_MIN)
    if alpha_v is None:
        return Microfacet(ggx, au, au, sample_visible, True)
    return Microfacet(ggx, au, dr.maximum(Float(alpha_v), ALPHA_MIN), sample_visible, False)


def _ggx_visible_slopes(cos_theta_i: Float, u) -> tuple[Float, Float]:
    """Slopes of a GGX (alpha = 1) normal visible from a direction at cos_theta_i in the xz-plane: a point
    uniform on the projected visible hemisphere (a disk, its far half squashed by (1 + cos theta_i) / 2)
    lifted to the hemisphere (Heitz 2018, in slope form as in Mitsuba)."""
    px, py = square_to_uniform_disk_concentric(u[0], u[1])
    s = 0.5 * (1.0 + cos_theta_i)
    py = dr.lerp(dr.safe_sqrt(1.0 - px * px), py, s)
    z = dr.safe_sqrt(1.0 - px * px - py * py)
    sin_theta_i = dr.safe_sqrt(1.0 - cos_theta_i * cos_theta_i)
    norm = dr.rcp(dr.fma(sin_theta_i, py, cos_theta_i * z))
    return dr.fma(cos_theta_i, py, -sin_theta_i * z) * norm, px * norm


def _beckmann_visible_slopes(cos_theta_i: Float, u) -> tuple[Float, Float]:
    """Slopes of a Beckmann (alpha = 1) normal visible from cos_theta_i (Jakob 2014): the x slope by
    inverting its CDF in the erf domain (an initial guess exact at grazing, three Newton steps), the y slope
    an independent Gaussian."""
    tan_theta_i = dr.safe_sqrt(1.0 - cos_theta_i * cos_theta_i) / cos_theta_i
    cot_theta_i = dr.rcp(tan_theta_i)
    maxval = dr.erf(cot_theta_i)
    u0 = dr.clip(u[0], 1e-6, 1.0 - 1e-6)
    u1 = dr.clip(u[1], 1e-6, 1.0 - 1e-6)
    x = maxval - (maxval + 1.0) * dr.erf(dr.sqrt(-dr.log(u0)))
    u0 = u0 * (1.0 + maxval + INV_SQRT_PI * tan_theta_i * dr.exp(-cot_theta_i * cot_theta_i))
    for _ in range(3):
        slope = dr.erfinv(x)
        value = 1.0 + x + INV_SQRT_PI * tan_theta_i * dr.exp(-slope * slope) - u0
        x = x - value / (1.0 - slope * tan_theta_i)
    return dr.erfinv(x), dr.erfinv(2.0 * u1 - 1.0)


def from_row(tables, kind: str, row: list[Float], surf=None, active: Bool = True) -> Microfacet:
    """The distribution of each lane's material from its table row [ggx, sample_visible, alpha_u, alpha_v]
    (see `row`), a roughness given by a texture evaluated at `surf` (tables.textured_value). A choice every
    material of the kind shares is a Python bool, so only its branch is traced; where all are isotropic
    alpha_v is alpha_u (Mitsuba's isotropic sampling of all normals)."""
    ours = [b for b in tables.bsdfs if b.kind == kind]

    def flag(test, column: Float):
        values = {bool(test(b)) for b in ours}
        return values.pop() if len(values) == 1 else column > 0.5

    ggx = flag(lambda b: b.distribution == "ggx", row[0])
    visible = flag(lambda b: b.sample_visible, row[1])
    alpha_u, alpha_v = row[2], row[3]
    if surf is not None:
        alpha_u, alpha_v = (tables.textured_value(slot, surf, a, active) for slot, a in (("alpha_u", alpha_u),
                                                                                         ("alpha_v", alpha_v)))
    if all(b.isotropic for b in ours):
        return microfacet(ggx, alpha_u, None, visible)
    return microfacet(ggx, alpha_u, alpha_v, visible)


def row(b) -> list[float]:
    """A material's distribution as table fields (`from_row` reads them)."""
    return [float(b.distribution == "ggx"), float(b.sample_visible), b.alpha_u, b.alpha_v]
