"""Mitsuba's `principled`: Disney's principled BSDF (Burley, "Physically Based Shading at Disney", SIGGRAPH
2012 course; with Burley 2015's specular transmission) as Mitsuba 3.9.1 writes it (src/bsdfs/principled.cpp,
principledhelpers.h). In the local frame, with weights brdf = (1 - metallic)(1 - spec_trans) and
bsdf = (1 - metallic) spec_trans, f cos theta_o is the sum of

- the main specular lobe: GGX of alpha_x = max(0.001, roughness^2 / aspect), alpha_y = max(0.001, roughness^2
  aspect), aspect = sqrt(1 - 0.9 anisotropic), F D G / (4 |cos_i|) with the principled Fresnel term: on the
  front (1 - metallic)(1 - spec_tint) F_dielectric + metallic Schlick(base_color) + (1 - metallic) spec_tint
  Schlick(tint R0(eta)), on the back bsdf F_dielectric (Schlick(R0) = R0 + (1 - R0)(1 - cos)^5, cos the
  transmitted angle's where the ray leaves the denser side, tint = base_color / its luminance);
- its transmission: sqrt(base_color) bsdf (1 - F) D G eta'^2 |wi.h wo.h| / (|cos_i| (wi.h + eta' wo.h)^2), times
  1 / eta'^2 (radiance), Walter et al. 2007's refraction with the generalised half vector;
- the clearcoat (front only): clearcoat / 4 Schlick(0.04) D_GTR1(h; lerp(0.1, 0.001, clearcoat_gloss))
  G_GGX(0.25) |cos_o| (no 1 / (4 cos_i cos_o): as Mitsuba);
- the diffuse (front only): brdf base_color / pi |cos_o| ((1 - F_i / 2)(1 - F_o / 2) + retro), retro =
  R_r (F_o + F_i + F_o F_i (R_r - 1)), R_r = 2 roughness (h.wo)^2, F = (1 - cos)^5, blended toward Hanrahan
  and Krueger's fake subsurface by `flatness`;
- the sheen (front only): sheen (1 - metallic) (1 - h.wo)^5 lerp(1, tint, sheen_tint) |cos_o|.

Sampling picks the diffuse (cosine-weighted), clearcoat (GTR1 normals), transmission or specular (visible GGX
normals of wi turned to the front) lobe with Mitsuba's probabilities (brdf, clearcoat / 4, bsdf (1 - F) and
1 - bsdf (1 - F), times the sampling rates; inside the material only the specular reflection F and
transmission 1 - F); the weight is f cos / pdf of the mixture. Each parameter but eta and the rates may be a
texture (read as a float, base_color as a colour)."""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from ..jit import Array2f, Array3f, Bool, Float, UInt32
from ..sampling import INV_PI, square_to_cosine_hemisphere_concentric
from ..spectra import rgb
from .bsdf import (BSDF, DIFFUSE_REFLECTION, GLOSSY_REFLECTION, GLOSSY_TRANSMISSION, BSDFSample)
from .fresnel import reflect
from .microfacet import microfacet, mulsign
from .reading import check_unit_interval
from .roughdielectric import fresnel, refract
from .textures import luminance

NAME, FLAGS = "principled", DIFFUSE_REFLECTION | GLOSSY_REFLECTION | GLOSSY_TRANSMISSION
# the float parameters (and their defaults) that textures may give, in table order
WEIGHTS = (("roughness", 0.5), ("anisotropic", 0.0), ("spec_trans", 0.0), ("sheen", 0.0), ("sheen_tint", 0.0),
           ("flatness", 0.0), ("spec_tint", 0.0), ("metallic", 0.0), ("clearcoat", 0.0), ("clearcoat_gloss", 0.0))
RATES = (("main_specular_sampling_rate", 1.0), ("clearcoat_sampling_rate", 1.0),
         ("diffuse_reflectance_sampling_rate", 1.0))
PLUGINS = {NAME: ("base_color", *(n for n, _ in WEIGHTS), "eta", "specular", *(n for n, _ in RATES))}


def from_xml(ctx, props, node) -> BSDF:
    base = props.colour("base_color", 0.5, textured=True)
    weights, textures, rates = read_weights(props, WEIGHTS, RATES)
    transmits = weights["spec_trans"] != 0 or any(n == "spec_trans" for n, _ in textures)
    eta = read_eta(ctx, props, node, transmits)
    props.finish()
    check_unit_interval(ctx, node, "base_color", base)
    texture = None if isinstance(base, np.ndarray) else base
    colour = rgb(base) if texture is None else (0.5, 0.5, 0.5)
    extra = tuple(weights.items()) + tuple(rates.items()) + (("eta", eta), ("transmits", float(transmits)))
    return BSDF(NAME, colour, texture=texture, textures=tuple(textures), extra=extra)


def read_weights(props, weights, rates) -> tuple[dict, list, dict]:
    """A principled kind's float parameters: each weight's value and its texture (name, texture) where it has
    one, and the sampling rates (never textured)."""
    values, textures = {}, []
    for name, default in weights:
        values[name], texture = props.scalar(name, default)
        if texture is not None:
            textures.append((name, texture))
    return values, textures, {name: props.scalar(name, d, textured=False)[0] for name, d in rates}


def read_eta(ctx, props, node, transmits: bool) -> float:
    """`eta`, or the one `specular` maps to, 2 / (1 - sqrt(0.08 specular)) - 1 (0.5: 1.5), not both; as Mitsuba,
    a transmitting material's eta of 1 becomes 1.001 and its specular of 0 becomes 0.001."""
    if props.has("eta") and props.has("specular"):
        raise ctx.error(node, "give either eta or specular, not both (as in Mitsuba)")
    if props.has("eta"):
        eta = float(props.get("eta", 1.5, ("float", "integer")))
        eta = 1.001 if transmits and eta == 1.0 else eta
    else:
        specular = float(props.get("specular", 0.5, ("float", "integer")))
        specular = 1e-3 if transmits and specular == 0.0 else specular
        eta = 2.0 / (1.0 - np.sqrt(np.float32(0.08) * np.float32(specular))) - 1.0
    if eta <= 0:
        raise ctx.error(node, f"eta must be positive, got {eta}")
    return float(eta)


FIELDS = [name for name, _ in WEIGHTS] + [name for name, _ in RATES] + ["eta", "transmits"]


def table(bsdfs: list[BSDF]) -> np.ndarray:
    return table_of(bsdfs, NAME, FIELDS)


def table_of(bsdfs: list[BSDF], name: str, fields) -> np.ndarray:
    """A principled kind's table: one row per material, its fields in table order (zeros for other kinds)."""
    rows = np.zeros((len(bsdfs), len(fields)))
    for i, b in enumerate(bsdfs):
        if b.kind == name:
            rows[i] = [dict(b.extra)[field] for field in fields]
    return rows


@dataclass
class PrincipledParams:
    base_color: Array3f
    w: dict            # each of FIELDS, per lane (textured where the material is)


def params(tables, surf, active: Bool) -> PrincipledParams:
    return read_params(tables, surf, active, NAME, FIELDS, WEIGHTS)


def read_params(tables, surf, active: Bool, name: str, fields, weights) -> PrincipledParams:
    """A principled kind's table row per lane, each weight replaced by its texture where it has one."""
    r = tables.row(name, surf.material, active)
    w = {field: r[k] for k, field in enumerate(fields)}
    for field, _ in weights:
        w[field] = tables.textured_value(field, surf, w[field], active)
    return PrincipledParams(tables.reflectance(surf, active), w)


def albedo(p: PrincipledParams) -> Array3f:
    return p.base_color


# ---- the helpers of Mitsuba's principledhelpers.h ----------------------------------------------------------
def schlick_weight(cos: Float) -> Float:
    m = dr.clip(1.0 - cos, 0.0, 1.0)
    return dr.square(dr.square(m)) * m


def schlick(r0, cos_i: Float, eta: Float):
    """Schlick's Fresnel from R0 at the incident cosine, or the transmitted one where the ray comes from the
    denser side (Mitsuba's calc_schlick)."""
    outside = cos_i >= 0
    eta_it = dr.select(outside, eta, dr.rcp(eta))
    eta_ti = dr.select(outside, dr.rcp(eta), eta)
    cos_t = dr.safe_sqrt(1.0 - (1.0 - cos_i * cos_i) * dr.square(eta_ti))
    w = dr.select(eta_it > 1.0, schlick_weight(dr.abs(cos_i)), schlick_weight(cos_t))
    return r0 + (1.0 - r0) * w


def r0(eta: Float) -> Float:
    return dr.square((eta - 1.0) / (eta + 1.0))


def tint(base_color: Array3f) -> Array3f:
    lum = luminance(base_color)
    return dr.select(lum > 0, base_color / lum, Array3f(1.0))


def gtr1(alpha: Float, m: Array3f) -> Float:
    """Burley's GTR1 (Berry) distribution of the clearcoat's normals."""
    a2 = dr.square(alpha)
    d = (a2 - 1.0) / (dr.pi * dr.log(a2) * (1.0 + (a2 - 1.0) * dr.square(m.z)))
    return dr.select(d * m.z > 1e-20, d, 0.0)


def sample_gtr1(alpha: Float, u: Array2f) -> Array3f:
    s, c = dr.sincos(dr.two_pi * u.x)
    a2 = dr.square(alpha)
    cos2 = (1.0 - dr.power(a2, 1.0 - u.y)) / (1.0 - a2)
    sin_t, cos_t = dr.sqrt(dr.maximum(0.0, 1.0 - cos2)), dr.sqrt(dr.maximum(0.0, cos2))
    return Array3f(c * sin_t, s * sin_t, cos_t)


def smith_ggx1(v: Array3f, m: Array3f, alpha: float) -> Float:
    cos2 = dr.square(v.z)
    g = 2.0 / (1.0 + dr.sqrt(1.0 + alpha * alpha * (1.0 - cos2) / cos2))
    g = dr.select(v.z == 1.0, 1.0, g)
    return dr.select(dr.dot(v, m) * v.z <= 0, 0.0, g)


def compatible(m: Array3f, wi: Array3f, wo: Array3f, cos_i: Float, reflection: bool) -> Bool:
    """Whether micro- and macro-surface agree on the sides of wi and wo (Mitsuba's mac_mic_compatibility)."""
    mm = mulsign(m, cos_i)
    return (dr.dot(wi, mm) > 0) & ((dr.dot(wo, mm) > 0) if reflection else (dr.dot(wo, mm) < 0))


# ---- the lobes ----------------------------------------------------------------------------------------------
def ggx(anisotropic: Float, roughness: Float):
    """The GGX distribution of alpha_x = max(0.001, roughness^2 / aspect), alpha_y = max(0.001, roughness^2
    aspect), aspect = sqrt(1 - 0.9 anisotropic) (Mitsuba's calc_dist_params)."""
    rough2 = dr.square(roughness)
    aspect = dr.sqrt(1.0 - 0.9 * anisotropic)
    return microfacet(True, dr.maximum(0.001, rough2 / aspect), dr.maximum(0.001, rough2 * aspect))


def _distribution(w: dict):
    return ggx(w["anisotropic"], w["roughness"])


def _probabilities(w: dict, f: Float, front: Bool) -> tuple[Float, Float, Float, Float]:
    """(diffuse, clearcoat, transmission, specular) lobe probabilities, normalised; no transmission where the
    material has none (spec_trans not given, or 0: Mitsuba's has_spec_trans)."""
    brdf = (1.0 - w["metallic"]) * (1.0 - w["spec_trans"])
    bsdf = (1.0 - w["metallic"]) * w["spec_trans"]
    rate = w["main_specular_sampling_rate"]
    spec = dr.select(front, rate * (1.0 - bsdf * (1.0 - f)), f)
    trans = dr.select(w["transmits"] > 0, dr.select(front, rate * bsdf * (1.0 - f), 1.0 - f), 0.0)
    coat = dr.select(front, 0.25 * w["clearcoat"] * w["clearcoat_sampling_rate"], 0.0)
    diffuse = dr.select(front, brdf * w["diffuse_reflectance_sampling_rate"], 0.0)
    total = dr.rcp(spec + trans + coat + diffuse)
    return diffuse * total, coat * total, trans * total, spec * total


def _half_vector(wi: Array3f, wo: Array3f, eta: Float) -> tuple[Array3f, Bool, Bool, Float]:
    cos_i, cos_o = wi.z, wo.z
    reflected, refracted = cos_i * cos_o > 0, cos_i * cos_o < 0
    eta_path = dr.select(cos_i > 0, eta, dr.rcp(eta))
    h = dr.normalize(wi + wo * dr.select(reflected, 1.0, eta_path))
    return mulsign(h, h.z), reflected, refracted, eta_path


def sample(p: PrincipledParams, wi: Array3f, u1: Float, u2: Array2f, active: Bool) -> tuple[BSDFSample, Array3f]:
    w, cos_i = p.w, wi.z
    active = active & (cos_i != 0)
    front = cos_i > 0
    bsdf = (1.0 - w["metallic"]) * w["spec_trans"]
    distr = _distribution(w)
    m, _ = distr.sample(mulsign(wi, cos_i), u2)
    f, cos_t, eta_it, eta_ti = fresnel(dr.dot(wi, m), w["eta"])
    active &= front | (bsdf > 0)
    p_diffuse, p_coat, p_trans, _ = _probabilities(w, f, front)
    diffuse = u1 < p_diffuse
    coat = ~diffuse & (u1 < p_diffuse + p_coat)
    trans = ~diffuse & ~coat & (u1 < p_diffuse + p_coat + p_trans)
    spec = ~diffuse & ~coat & ~trans
    m_cc = sample_gtr1(dr.lerp(0.1, 0.001, w["clearcoat_gloss"]), u2)
    wo = dr.select(spec, reflect(-wi, m), refract(wi, m, cos_t, eta_ti))
    wo = dr.select(coat, reflect(-wi, m_cc), wo)
    wo = dr.select(diffuse, square_to_cosine_hemisphere_concentric(u2.x, u2.y), wo)
    cos_o = wo.z
    ok = dr.select(spec, compatible(m, wi, wo, cos_i, True) & (cos_i * cos_o > 0),
                   compatible(m, wi, wo, cos_i, False) & (cos_i * cos_o < 0))
    ok = dr.select(coat, compatible(m_cc, wi, wo, cos_i, True) & (cos_i * cos_o > 0), ok)
    ok = dr.select(diffuse, cos_i * cos_o > 0, ok)
    active &= ok
    density = pdf(p, wi, wo, active)
    active &= density > 0
    kind = dr.select(diffuse, UInt32(DIFFUSE_REFLECTION),
                     dr.select(trans, UInt32(GLOSSY_TRANSMISSION), UInt32(GLOSSY_REFLECTION)))
    weight = eval(p, wi, wo, active) / density
    bs = BSDFSample(wo, dr.select(active, density, 0.0), dr.select(trans, eta_it, 1.0), kind)
    return bs, dr.select(active, weight, 0.0)


def eval(p: PrincipledParams, wi: Array3f, wo: Array3f, active: Bool) -> Array3f:
    """f |cos theta_o| (radiance transport)."""
    w, base = p.w, p.base_color
    cos_i, cos_o = wi.z, wo.z
    active = active & (cos_i != 0)
    metallic, spec_trans = w["metallic"], w["spec_trans"]
    brdf, bsdf = (1.0 - metallic) * (1.0 - spec_trans), (1.0 - metallic) * spec_trans
    front = cos_i > 0
    h, reflected, refracted, eta_path = _half_vector(wi, wo, w["eta"])
    f = fresnel(dr.dot(wi, h), w["eta"])[0]
    distr = _distribution(w)
    d, g = distr.D(h), distr.G(wi, wo, h)
    refl_ok = compatible(h, wi, wo, cos_i, True)
    value = Array3f(0.0)
    # the main specular reflection, its Fresnel term tinted and metallic on the front
    spec_tint, wi_h = w["spec_tint"], dr.dot(wi, h)
    c_tint = tint(base)
    f_front = ((1.0 - metallic) * (1.0 - spec_tint) * f + metallic * schlick(base, wi_h, w["eta"])
               + (1.0 - metallic) * spec_tint * schlick(c_tint * r0(dr.select(wi_h >= 0, w["eta"], dr.rcp(w["eta"]))),
                                                        wi_h, w["eta"]))
    f_principled = dr.select(front, f_front, Array3f(bsdf * f))
    on = active & reflected & refl_ok & (f > 0)
    value += dr.select(on, f_principled * (d * g / (4.0 * dr.abs(cos_i))), 0.0)
    # transmission
    wo_h = dr.dot(wo, h)
    on = active & (bsdf > 0) & refracted & compatible(h, wi, wo, cos_i, False) & (f < 1)
    t = dr.abs((1.0 - f) * d * g * wi_h * wo_h / (cos_i * dr.square(wi_h + eta_path * wo_h)))   # 1/eta'^2 eta'^2
    value += dr.select(on, dr.sqrt(base) * (bsdf * t), 0.0)
    # clearcoat
    clearcoat = w["clearcoat"]
    on = active & (clearcoat > 0) & reflected & refl_ok & front
    f_cc = schlick(Float(0.04), wi_h, w["eta"])
    d_cc = gtr1(dr.lerp(0.1, 0.001, w["clearcoat_gloss"]), h)
    g_cc = smith_ggx1(wi, h, 0.25) * smith_ggx1(wo, h, 0.25)
    value += dr.select(on, Array3f(clearcoat * 0.25 * f_cc * d_cc * g_cc * dr.abs(cos_o)), 0.0)
    # diffuse, retro-reflection and fake subsurface
    on = active & (brdf > 0) & reflected & front
    f_o, f_i = schlick_weight(dr.abs(cos_o)), schlick_weight(dr.abs(cos_i))
    cos_d = dr.dot(h, wo)
    rr = 2.0 * w["roughness"] * dr.square(cos_d)
    lobe = (1.0 - 0.5 * f_i) * (1.0 - 0.5 * f_o) + rr * (f_o + f_i + f_o * f_i * (rr - 1.0))
    fss = dr.lerp(1.0, rr / 2.0, f_o) * dr.lerp(1.0, rr / 2.0, f_i)
    ss = 1.25 * (fss * (1.0 / (dr.abs(cos_o) + dr.abs(cos_i)) - 0.5) + 0.5)
    lobe = dr.lerp(lobe, ss, w["flatness"])
    value += dr.select(on, base * (brdf * dr.abs(cos_o) * INV_PI * lobe), 0.0)
    # sheen (Mitsuba's does not need the diffuse weight brdf)
    sheen = w["sheen"]
    on = active & (sheen > 0) & reflected & (1.0 - metallic > 0) & front
    c_sheen = dr.lerp(Array3f(1.0), c_tint, w["sheen_tint"])
    value += dr.select(on, c_sheen * (sheen * (1.0 - metallic) * schlick_weight(dr.abs(cos_d)) * dr.abs(cos_o)), 0.0)
    return dr.select(active, value, 0.0)


def pdf(p: PrincipledParams, wi: Array3f, wo: Array3f, active: Bool) -> Float:
    w, cos_i = p.w, wi.z
    active = active & (cos_i != 0)
    front = cos_i > 0
    h, reflected, refracted, eta_path = _half_vector(wi, wo, w["eta"])
    distr = _distribution(w)
    f = fresnel(dr.dot(wi, h), w["eta"])[0]
    p_diffuse, p_coat, p_trans, p_spec = _probabilities(w, f, front)
    wi_h, wo_h = dr.dot(wi, h), dr.dot(wo, h)
    jacobian = dr.abs(dr.select(reflected, dr.rcp(4.0 * wo_h), dr.square(eta_path) * wo_h
                                / dr.square(wi_h + eta_path * wo_h)))
    visible = distr.pdf(mulsign(wi, cos_i), h)
    refl_ok = compatible(h, wi, wo, cos_i, True) & reflected
    density = dr.select(refl_ok, p_spec * visible * jacobian, 0.0)
    density += dr.select(reflected, p_diffuse * dr.maximum(wo.z, 0.0) * INV_PI, 0.0)
    density += dr.select(compatible(h, wi, wo, cos_i, False) & refracted, p_trans * visible * jacobian, 0.0)
    coat = gtr1(dr.lerp(0.1, 0.001, w["clearcoat_gloss"]), h)
    density += dr.select(refl_ok, p_coat * dr.select(h.z < 0, 0.0, h.z * coat) * jacobian, 0.0)
    return dr.select(active, density, 0.0)
