"""Mitsuba's `principledthin`: the principled BSDF of a thin sheet (both sides alike, no bending; Burley 2015)
as Mitsuba 3.9.1 writes it (src/bsdfs/principledthin.cpp). Seen from either side (wi and wo mirrored to the
front), with t = diff_trans / 2 (diff_trans runs over [0, 2]) and s = spec_trans, f cos theta_o is the sum of

- specular reflection: s F_thin D G / (4 cos_i), GGX as `principled`'s (roughness, anisotropic), F_thin the
  dielectric Fresnel term of `eta` blended toward the tinted Schlick term by spec_tint;
- specular transmission through the sheet: s base_color (1 - F) D' G' / (4 cos_i) with wo mirrored back
  through the sheet for the half vector, D' of the roughness scaled by 0.65 eta - 0.35 (Burley 2015, fig. 15);
- diffuse reflection, retro-reflection, fake subsurface (`flatness`) and sheen as `principled`'s, times
  (1 - s)(1 - t);
- Lambertian transmission: (1 - s) t base_color / pi |cos_o|.

Sampling picks specular reflection, transmission, cosine-weighted reflection or transmission with Mitsuba's
probabilities (s / 2 each, (1 - s)(1 - t), (1 - s) t, times the sampling rates); the weight is f cos / pdf."""
from __future__ import annotations

import drjit as dr
import numpy as np

from ..jit import Array2f, Array3f, Bool, Float, UInt32
from ..sampling import INV_PI, square_to_cosine_hemisphere_concentric
from ..spectra import rgb
from .bsdf import (BSDF, DIFFUSE_REFLECTION, DIFFUSE_TRANSMISSION, GLOSSY_REFLECTION, GLOSSY_TRANSMISSION,
                   BSDFSample)
from .fresnel import reflect
from .microfacet import mulsign
from .principled import (PrincipledParams, albedo, compatible, ggx, r0, read_params, read_weights,  # noqa: F401 (albedo)
                         schlick, schlick_weight, table_of, tint)
from .reading import check_unit_interval
from .roughdielectric import fresnel

NAME = "principledthin"
FLAGS = DIFFUSE_REFLECTION | DIFFUSE_TRANSMISSION | GLOSSY_REFLECTION | GLOSSY_TRANSMISSION
WEIGHTS = (("roughness", 0.5), ("anisotropic", 0.0), ("spec_trans", 0.0), ("sheen", 0.0), ("sheen_tint", 0.0),
           ("flatness", 0.0), ("spec_tint", 0.0), ("eta", 1.5), ("diff_trans", 0.0))
RATES = (("specular_reflectance_sampling_rate", 1.0), ("specular_transmittance_sampling_rate", 1.0),
         ("diffuse_transmittance_sampling_rate", 1.0), ("diffuse_reflectance_sampling_rate", 1.0))
PLUGINS = {NAME: ("base_color", *(n for n, _ in WEIGHTS), *(n for n, _ in RATES))}
FIELDS = [name for name, _ in WEIGHTS] + [name for name, _ in RATES]


def from_xml(ctx, props, node) -> BSDF:
    base = props.colour("base_color", 0.5, textured=True)
    weights, textures, rates = read_weights(props, WEIGHTS, RATES)
    props.finish()
    check_unit_interval(ctx, node, "base_color", base)
    texture = None if isinstance(base, np.ndarray) else base
    colour = rgb(base) if texture is None else (0.5, 0.5, 0.5)
    return BSDF(NAME, colour, texture=texture, textures=tuple(textures),
                extra=tuple(weights.items()) + tuple(rates.items()))


def table(bsdfs: list[BSDF]) -> np.ndarray:
    return table_of(bsdfs, NAME, FIELDS)


def params(tables, surf, active: Bool) -> PrincipledParams:
    return read_params(tables, surf, active, NAME, FIELDS, WEIGHTS)


def _probabilities(w: dict) -> tuple[Float, Float, Float, Float]:
    """(specular reflection, specular transmission, diffuse reflection, diffuse transmission), normalised."""
    s, t = w["spec_trans"], w["diff_trans"] / 2.0
    spec = s * w["specular_reflectance_sampling_rate"] / 2.0
    trans = s * w["specular_transmittance_sampling_rate"] / 2.0
    diffuse = w["diffuse_reflectance_sampling_rate"] * (1.0 - s) * (1.0 - t)
    diffuse_t = w["diffuse_transmittance_sampling_rate"] * (1.0 - s) * t
    total = dr.rcp(spec + trans + diffuse + diffuse_t)
    return spec * total, trans * total, diffuse * total, diffuse_t * total


def _distributions(w: dict):
    """The specular reflection's GGX and the transmission's, its roughness scaled by 0.65 eta - 0.35."""
    return (ggx(w["anisotropic"], w["roughness"]),
            ggx(w["anisotropic"], (0.65 * w["eta"] - 0.35) * w["roughness"]))


def _front(wi: Array3f, wo: Array3f) -> tuple[Array3f, Array3f, Array3f]:
    """wi and wo mirrored so that wi lies in front, and the half vector of wi and wo mirrored to wi's side."""
    wi_f, wo_t = mulsign(wi, wi.z), mulsign(wo, wi.z)
    return wi_f, wo_t, dr.normalize(wi_f + Array3f(wo_t.x, wo_t.y, dr.abs(wo_t.z)))


def sample(p: PrincipledParams, wi: Array3f, u1: Float, u2: Array2f, active: Bool) -> tuple[BSDFSample, Array3f]:
    w = p.w
    active = active & (wi.z != 0)
    front_wi = mulsign(wi, wi.z)
    p_spec, p_trans, p_diffuse, _ = _probabilities(w)
    spec = u1 < p_spec
    trans = ~spec & (u1 < p_spec + p_trans)
    diffuse = ~spec & ~trans & (u1 < p_spec + p_trans + p_diffuse)
    diffuse_t = ~spec & ~trans & ~diffuse & (w["diff_trans"] > 0)
    distr, distr_t = _distributions(w)
    m = distr.sample(front_wi, u2)[0]
    m_t = distr_t.sample(front_wi, u2)[0]
    wo_r, wo_t = reflect(-front_wi, m), reflect(-front_wi, m_t)
    wo_t = Array3f(wo_t.x, wo_t.y, -wo_t.z)                   # through the sheet, unbent
    cos_dir = square_to_cosine_hemisphere_concentric(u2.x, u2.y)
    wo = dr.select(spec, wo_r, dr.select(trans, wo_t, dr.select(diffuse, cos_dir, -cos_dir)))
    ok = dr.select(spec, compatible(m, front_wi, wo, front_wi.z, True) & (wo.z > 0),
                   dr.select(trans, compatible(m_t, front_wi, wo, front_wi.z, False) & (wo.z < 0),
                             diffuse | diffuse_t))
    active &= ok
    wo = mulsign(wo, wi.z)
    density = pdf(p, wi, wo, active)
    active &= density > 0
    kind = dr.select(spec, UInt32(GLOSSY_REFLECTION), dr.select(trans, UInt32(GLOSSY_TRANSMISSION),
                     dr.select(diffuse, UInt32(DIFFUSE_REFLECTION), UInt32(DIFFUSE_TRANSMISSION))))
    weight = eval(p, wi, wo, active) / density
    return BSDFSample(wo, dr.select(active, density, 0.0), Float(1.0), kind), dr.select(active, weight, 0.0)


def eval(p: PrincipledParams, wi: Array3f, wo: Array3f, active: Bool) -> Array3f:
    """f |cos theta_o|."""
    w, base = p.w, p.base_color
    active = active & (wi.z != 0)
    wi, wo_t, h = _front(wi, wo)
    cos_i, cos_o = wi.z, wo_t.z
    reflected, refracted = cos_o > 0, cos_o < 0
    s, t = w["spec_trans"], w["diff_trans"] / 2.0
    distr, distr_t = _distributions(w)
    f = fresnel(dr.dot(wi, h), w["eta"])[0]
    value = Array3f(0.0)
    # specular reflection, its Fresnel term blended toward the tinted Schlick term
    c_tint = tint(base)
    f_thin = dr.lerp(Array3f(f), schlick(c_tint * r0(w["eta"]), dr.dot(wi, h), w["eta"]), w["spec_tint"])
    on = active & (s > 0) & reflected & compatible(h, wi, wo_t, cos_i, True)
    value += dr.select(on, f_thin * (s * distr.D(h) * distr.G(wi, wo_t, h) / (4.0 * cos_i)), 0.0)
    # specular transmission
    on = active & (s > 0) & refracted & compatible(h, wi, wo_t, cos_i, False)
    value += dr.select(on, base * (s * (1.0 - f) * distr_t.D(h) * distr_t.G(wi, wo_t, h) / (4.0 * cos_i)), 0.0)
    # diffuse, retro-reflection, fake subsurface and sheen
    on = active & reflected & (s < 1) & (t < 1)
    f_o, f_i = schlick_weight(dr.abs(cos_o)), schlick_weight(cos_i)
    cos_d = dr.dot(h, wo_t)
    rr = 2.0 * w["roughness"] * dr.square(cos_d)
    lobe = (1.0 - 0.5 * f_i) * (1.0 - 0.5 * f_o) + rr * (f_o + f_i + f_o * f_i * (rr - 1.0))
    fss = dr.lerp(1.0, rr / 2.0, f_o) * dr.lerp(1.0, rr / 2.0, f_i)
    ss = 1.25 * (fss * (1.0 / (dr.abs(cos_o) + dr.abs(cos_i)) - 0.5) + 0.5)
    lobe = dr.lerp(lobe, ss, w["flatness"])
    value += dr.select(on, base * ((1.0 - s) * cos_o * INV_PI * (1.0 - t) * lobe), 0.0)
    c_sheen = dr.lerp(Array3f(1.0), c_tint, w["sheen_tint"])
    sheen = w["sheen"] * (1.0 - s) * schlick_weight(dr.abs(cos_d)) * (1.0 - t) * dr.abs(cos_o)
    value += dr.select(on & (w["sheen"] > 0), c_sheen * sheen, 0.0)
    # Lambertian transmission
    on = active & refracted & (s < 1) & (t > 0)
    value += dr.select(on, base * ((1.0 - s) * t * INV_PI * dr.abs(cos_o)), 0.0)
    return dr.select(active, value, 0.0)


def pdf(p: PrincipledParams, wi: Array3f, wo: Array3f, active: Bool) -> Float:
    w = p.w
    active = active & (wi.z != 0)
    wi, wo_t, h = _front(wi, wo)
    reflected, refracted = wo_t.z > 0, wo_t.z < 0
    p_spec, p_trans, p_diffuse, p_diffuse_t = _probabilities(w)
    distr, distr_t = _distributions(w)
    jacobian = dr.abs(dr.rcp(4.0 * dr.dot(Array3f(wo_t.x, wo_t.y, dr.abs(wo_t.z)), h)))
    density = dr.select(compatible(h, wi, wo_t, wi.z, True) & reflected, p_spec * distr.pdf(wi, h) * jacobian, 0.0)
    density += dr.select(compatible(h, wi, wo_t, wi.z, False) & refracted,
                         p_trans * distr_t.pdf(wi, h) * jacobian, 0.0)
    density += dr.select(reflected, p_diffuse * wo_t.z * INV_PI, 0.0)
    density += dr.select(refracted, p_diffuse_t * -wo_t.z * INV_PI, 0.0)
    return dr.select(active, density, 0.0)
