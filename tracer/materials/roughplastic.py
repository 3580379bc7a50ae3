"""Mitsuba's `roughplastic`: a rough dielectric coating (isotropic microfacet reflection of relative index
eta = int_ior / ext_ior, as materials.roughconductor but with the dielectric Fresnel term) over a
Lambertian base, one-sided.

The base's light crosses the coating twice and is reflected inside it again and again. Mitsuba models that
with two terms of the coating alone, computed once per material (`coating`):
- T(cos theta), the coating's external transmittance at incidence cos theta: the integral over the normals
  visible from that direction of (1 - F(wi.m)) G1(wo, m) for the refracted wo (Gauss-Legendre quadrature
  of the visible-normal sampling map), tabulated at 64 cosines and interpolated linearly;
- R_int, its internal diffuse reflectance: 2 x the mean over the same 64 cosines of cos theta times the
  visible-normal integral of F(wi.m, 1 / eta) G1(wo, m) for the reflected wo.
The diffuse lobe is then f cos_o = rho / (1 - R_int) (or rho / (1 - rho R_int) per colour when
`nonlinear`) * T(cos_i) T(cos_o) cos_o / (pi eta^2): Kelemen and Szirmay-Kalos' coupling as Mitsuba writes
it. Sampling chooses the coating with probability (1 - T(cos_i)) s / ((1 - T(cos_i)) s + T(cos_i) (1 - s)),
s = mean specular / (mean specular + mean diffuse reflectance); a sample's weight is eval / pdf of the
mixture."""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import drjit as dr
import numpy as np

from ..jit import Array3f, Bool, Float, UInt32
from ..sampling import square_to_cosine_hemisphere_concentric
from . import microfacet as mf
from . import plastic
from .bsdf import BSDF, DIFFUSE_REFLECTION, GLOSSY_REFLECTION, BSDFSample
from .fresnel import reflect
from .microfacet import Microfacet, microfacet, pick
from .reading import read_microfacet
from .roughdielectric import fresnel, refract

NAME, FLAGS = "roughplastic", GLOSSY_REFLECTION | DIFFUSE_REFLECTION
PLUGINS = {"roughplastic": ("distribution", "alpha", "alpha_u", "alpha_v", "sample_visible", "int_ior", "ext_ior",
                            "diffuse_reflectance", "specular_reflectance", "nonlinear")}
TRANSMITTANCE_RES = 64       # cosines at which T is tabulated (Mitsuba's MI_ROUGH_TRANSMITTANCE_RES)
MU_CHUNK = 32                # cosines integrated per launch (_visible_normal_integral)
FIELDS = 11                  # table fields before T: microfacet.row, eta, s, R_int, nonlinear, specular (3)


@dataclass
class RoughPlasticParams:
    distr: Microfacet                 # isotropic
    eta: Float
    specular_reflectance: Array3f
    diffuse_reflectance: Array3f
    nonlinear: bool | Bool
    specular_weight: Float            # s: mean specular / (mean specular + mean diffuse reflectance)
    internal_reflectance: Float       # R_int
    transmittance: Float              # T at TRANSMITTANCE_RES cosines: at row * stride + offset + k
    row: UInt32 | int = 0             # this lane's row of `transmittance`
    stride: int = TRANSMITTANCE_RES
    offset: int = 0


def from_xml(ctx, props, node) -> BSDF:
    distribution = read_microfacet(ctx, props, node, anisotropic=False, textured=False)
    layers = plastic.read_layers(ctx, props, node)
    if min(layers["int_ior"], layers["ext_ior"]) < 0 or layers["int_ior"] == layers["ext_ior"]:
        raise ctx.error(node, "the interior and exterior indices of refraction must be positive and differ "
                              f"(as in Mitsuba), got {layers['int_ior']} and {layers['ext_ior']}")
    return BSDF(NAME, **layers, **distribution)


def table(bsdfs: list[BSDF]) -> np.ndarray:
    """Per rough plastic: its distribution (microfacet.row), eta, the specular sampling weight s, R_int,
    nonlinear, the specular reflectance, then T at TRANSMITTANCE_RES cosines (`coating`, computed once per
    distinct coating)."""
    rows = np.zeros((len(bsdfs), FIELDS + TRANSMITTANCE_RES))
    coatings = {}
    for i, b in enumerate(bsdfs):
        if b.kind == NAME:
            eta = b.int_ior / b.ext_ior
            key = (b.distribution, b.alpha_u, eta)
            if key not in coatings:
                coatings[key] = coating(b.distribution == "ggx", b.alpha_u, eta)
            t, r_int = coatings[key]
            s_mean, d_mean = np.mean(b.specular_reflectance), np.mean(b.reflectance)
            rows[i] = [*mf.row(b), eta, s_mean / (s_mean + d_mean), r_int, float(b.nonlinear),
                       *b.specular_reflectance, *t]
    return rows


def params(tables, surf, active: Bool) -> RoughPlasticParams:
    values, stride = tables.table(NAME)
    head = tables.row(NAME, surf.material, active, FIELDS)
    nonlinear = {b.nonlinear for b in tables.bsdfs if b.kind == NAME}
    return RoughPlasticParams(mf.from_row(tables, NAME, head), head[4], Array3f(*head[8:11]),
                              tables.reflectance(surf, active),
                              nonlinear.pop() if len(nonlinear) == 1 else head[7] > 0.5, head[5], head[6],
                              values, surf.material, stride, FIELDS)


@lru_cache(maxsize=64)
def coating(ggx: bool, alpha: float, eta: float) -> tuple[np.ndarray, float]:
    """(T at cos theta = max(1e-6, k / 63), k = 0..63; R_int) of a coating, as Mitsuba precomputes them
    (kept for later scenes: about a second each)."""
    mu = np.maximum(1e-6, np.linspace(0.0, 1.0, TRANSMITTANCE_RES, dtype=np.float32))
    transmittance = _visible_normal_integral(ggx, alpha, eta, mu, transmitted=True)
    reflectance = _visible_normal_integral(ggx, alpha, 1.0 / eta, mu, transmitted=False)
    return transmittance.astype(np.float32), float(np.mean(reflectance * mu) * 2.0)


def _visible_normal_integral(ggx: bool, alpha: float, eta: float, mu: np.ndarray, transmitted: bool) -> np.ndarray:
    """Per cosine mu: the mean over normals visible from wi = (sqrt(1 - mu^2), 0, mu) of (1 - F) G1(wo)
    for refraction (wo below) or F G1(wo) for reflection (wo above), by an n x n Gauss-Legendre rule on the
    sampling map's unit square (n = 32 for eta > 1, else 128, as Mitsuba)."""
    n = 32 if eta > 1 else 128
    nodes, weights = np.polynomial.legendre.leggauss(n)
    ux, uy = (np.meshgrid(nodes, nodes)[k].ravel() * 0.5 + 0.5 for k in (0, 1))
    w = np.outer(weights, weights).ravel() * 0.25
    # MU_CHUNK cosines at a time: all 64 at once (a million lanes at n = 128) took ptracer.xml's peak from
    # 125.6 to 147.5 MiB, above the render's own (tracer.plan), for no time saved (0.06 s a coating either way)
    return np.concatenate([_node_values(ggx, alpha, eta, mu[k:k + MU_CHUNK], ux, uy, transmitted) @ w
                           for k in range(0, len(mu), MU_CHUNK)])


def _node_values(ggx: bool, alpha: float, eta: float, mu: np.ndarray, ux: np.ndarray, uy: np.ndarray,
                 transmitted: bool) -> np.ndarray:
    """(len(mu), nodes) the integrand of _visible_normal_integral at each cosine and node."""
    n2 = len(ux)
    cos = np.repeat(mu.astype(np.float64), n2)
    wi = Array3f(Float(np.sqrt(1.0 - cos * cos)), Float(np.zeros_like(cos)), Float(cos))
    distr = microfacet(ggx, alpha)
    m, _ = distr.sample(wi, (Float(np.tile(ux, len(mu))), Float(np.tile(uy, len(mu)))))
    f, cos_t, _, eta_ti = fresnel(dr.dot(wi, m), Float(eta))
    if transmitted:
        wo = refract(wi, m, cos_t, eta_ti)
        value = dr.select(wo.z * wi.z >= 0, 0.0, distr.smith_g1(wo, m) * (1.0 - f))
    else:
        wo = reflect(-wi, m)
        value = dr.select((wo.z <= 0) | (wi.z <= 0), 0.0, distr.smith_g1(wo, m) * f)
    return np.asarray(value.numpy(), dtype=np.float64).reshape(len(mu), n2)


def _transmittance(p: RoughPlasticParams, cos: Float, active: Bool) -> Float:
    """T(cos), linearly interpolated in the material's row."""
    x = cos * (TRANSMITTANCE_RES - 1)
    index = dr.minimum(UInt32(x), TRANSMITTANCE_RES - 2)
    base = p.row * p.stride + p.offset + index
    v0 = dr.gather(Float, p.transmittance, base, active)
    v1 = dr.gather(Float, p.transmittance, base + 1, active)
    return dr.lerp(v0, v1, x - Float(index))


def _specular_probability(p: RoughPlasticParams, t_i: Float) -> Float:
    spec = (1.0 - t_i) * p.specular_weight
    return spec / (spec + t_i * (1.0 - p.specular_weight))


def sample(p: RoughPlasticParams, wi: Array3f, u1: Float, u2, active: Bool) -> tuple[BSDFSample, Array3f]:
    """(sample, weight = f cos theta_o / pdf): the coating with the probability above, else the base."""
    active = active & (wi.z > 0)
    specular = u1 < _specular_probability(p, _transmittance(p, wi.z, active))
    return sample_layer(p, wi, specular, u2, active, pdf, eval)


def sample_layer(p, wi: Array3f, specular: Bool, u2, active: Bool, pdf, eval) -> tuple[BSDFSample, Array3f]:
    """A rough coating over a diffuse base, sampled: the coating's microfacet reflection where `specular`, the
    base's cosine lobe elsewhere; pdf and weight (f cos / pdf) from the layer's own pdf and eval."""
    m, _ = p.distr.sample(wi, u2)
    wo = dr.select(specular, reflect(-wi, m), square_to_cosine_hemisphere_concentric(u2[0], u2[1]))
    density = pdf(p, wi, wo, active)
    active &= density > 0
    weight = eval(p, wi, wo, active) / density
    kind = dr.select(specular, UInt32(GLOSSY_REFLECTION), UInt32(DIFFUSE_REFLECTION))
    return BSDFSample(wo, dr.select(active, density, 0.0), Float(1.0), kind), dr.select(active, weight, 0.0)


def eval(p: RoughPlasticParams, wi: Array3f, wo: Array3f, active: Bool) -> Array3f:
    """f cos theta_o: the coating's reflection plus the base seen through it."""
    cos_i, cos_o = wi.z, wo.z
    active = active & (cos_i > 0) & (cos_o > 0)
    h = dr.normalize(wo + wi)
    f = fresnel(dr.dot(wi, h), p.eta)[0]
    value = p.specular_reflectance * (f * p.distr.D(h) * p.distr.G(wi, wo, h) / (4.0 * cos_i))
    rho = p.diffuse_reflectance
    rho = rho / (1.0 - pick(p.nonlinear, lambda: rho * p.internal_reflectance,
                            lambda: Array3f(p.internal_reflectance)))
    t_io = _transmittance(p, cos_i, active) * _transmittance(p, cos_o, active)
    value += rho * (dr.inv_pi * cos_o * t_io / dr.square(p.eta))
    return dr.select(active, value, 0.0)


def pdf(p: RoughPlasticParams, wi: Array3f, wo: Array3f, active: Bool) -> Float:
    """Density of `sample`'s wo: the mixture of the coating's and the base's."""
    cos_i, cos_o = wi.z, wo.z
    active = active & (cos_i > 0) & (cos_o > 0)
    p_spec = _specular_probability(p, _transmittance(p, cos_i, active))
    h = dr.normalize(wo + wi)
    spec = pick(p.distr.sample_visible, lambda: p.distr.D(h) * p.distr.smith_g1(wi, h) / (4.0 * cos_i),
                lambda: p.distr.pdf(wi, h) / (4.0 * dr.dot(wo, h)))
    return dr.select(active, p_spec * spec + (1.0 - p_spec) * cos_o * dr.inv_pi, 0.0)
