"""Mitsuba's `roughdielectric`: microfacet reflection and refraction at a rough interface of relative index
eta = int_ior / ext_ior, lit from either side (Walter et al. 2007).

Reflection: F D G / (4 |cos theta_i cos theta_o|) about the half vector h = wi + wo. Transmission: with the
generalised half vector h = -(wi + eta' wo) (Walter (16); eta' the relative index seen from wi's side, h
turned to the macro normal's side), f = (1 - F) D G eta'^2 |wi.h| |wo.h| / (|cos_i cos_o| (wi.h + eta'
wo.h)^2) (Walter (21)), times 1 / eta'^2: radiance is compressed crossing into the denser medium (Veach
1997, ch. 5), as Mitsuba's path integrator sees it (TransportMode::Radiance). The sample's eta is eta'
for a refraction (1 for a reflection), which Mitsuba's path integrator multiplies up for Russian roulette.

Sampling draws a normal (from the distribution for wi mirrored into the upper hemisphere; with all normals,
Walter's roughness scaled by 1.2 - 0.2 sqrt|cos theta_i|), chooses reflection with probability F and
refraction otherwise, and converts the normal's density by the Jacobian 1 / (4 |wo.h|) or eta'^2 |wo.h| /
(wi.h + eta' wo.h)^2 (Walter (14), (17)).

One deliberate difference from Mitsuba 3.9: sampling all normals (`sample_visible` false) from the widened
distribution D', Mitsuba's sample weight omits the factor D(m) / D'(m), so its weight is not its own
eval / pdf and its estimates are biased (tests/test_microfacet.py shows it with Mitsuba's own API). Here the
weight is eval / pdf. No scene of mitsuba-renderer/mitsuba-data sets `sample_visible`."""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from ..jit import Array3f, Bool, Float, UInt32
from ..spectra import rgb
from . import microfacet as mf
from .bsdf import BSDF, GLOSSY_REFLECTION, GLOSSY_TRANSMISSION, BSDFSample
from .fresnel import fresnel_dielectric, reflect
from .microfacet import Microfacet, mulsign, pick
from .reading import check_unit_interval, read_ior, read_microfacet

NAME = "roughdielectric"
FLAGS = GLOSSY_REFLECTION | GLOSSY_TRANSMISSION
PLUGINS = {"roughdielectric": ("distribution", "alpha", "alpha_u", "alpha_v", "sample_visible", "int_ior",
                               "ext_ior", "specular_reflectance", "specular_transmittance")}


@dataclass
class RoughDielectricParams:
    distr: Microfacet
    eta: Float                       # int_ior / ext_ior
    specular_reflectance: Array3f
    specular_transmittance: Array3f


def from_xml(ctx, props, node) -> BSDF:
    distribution = read_microfacet(ctx, props, node)
    ior = {k: read_ior(ctx, props, k, d) for k, d in (("int_ior", "bk7"), ("ext_ior", "air"))}
    spec = {k: props.colour(k, 1.0) for k in ("specular_reflectance", "specular_transmittance")}
    props.finish()
    if min(ior.values()) < 0 or ior["int_ior"] == ior["ext_ior"]:
        raise ctx.error(node, "the interior and exterior indices of refraction must be positive and differ "
                              f"(as in Mitsuba), got {ior['int_ior']} and {ior['ext_ior']}")
    for name, value in spec.items():
        check_unit_interval(ctx, node, name, value)
    return BSDF(NAME, (1.0, 1.0, 1.0), int_ior=ior["int_ior"], ext_ior=ior["ext_ior"],
                specular_reflectance=rgb(spec["specular_reflectance"]),
                specular_transmittance=rgb(spec["specular_transmittance"]), **distribution)


def table(bsdfs: list[BSDF]) -> np.ndarray:
    """Per rough dielectric: its distribution (microfacet.row), eta, specular reflectance and transmittance."""
    rows = np.zeros((len(bsdfs), 11))
    for i, b in enumerate(bsdfs):
        if b.kind == NAME:
            rows[i] = [*mf.row(b), b.int_ior / b.ext_ior, *b.specular_reflectance, *b.specular_transmittance]
    return rows


def params(tables, surf, active: Bool) -> RoughDielectricParams:
    r = tables.row(NAME, surf.material, active)
    return RoughDielectricParams(mf.from_row(tables, NAME, r, surf, active), r[4], Array3f(*r[5:8]), Array3f(*r[8:11]))


def fresnel(cos_i: Float, eta: Float) -> tuple[Float, Float, Float, Float]:
    """Fresnel reflectance of an interface of relative index eta (inside over outside) for light at
    cos_i of either sign (negative: from inside), as Mitsuba's `fresnel`: (F, cos_t (signed: the
    refracted ray's side), eta_it (relative index seen from the incident side), eta_ti = 1 / eta_it)."""
    eta_it = dr.select(cos_i >= 0, eta, dr.rcp(eta))
    f, cos_t, eta_ti = fresnel_dielectric(dr.abs(cos_i), eta_it)
    f = dr.select(cos_i == 0, 1.0, f)
    return f, -mulsign(cos_t, cos_i), eta_it, eta_ti


def refract(wi: Array3f, m: Array3f, cos_t: Float, eta_ti: Float) -> Array3f:
    """wi (pointing away) refracted through a facet of normal m: m (wi.m eta_ti + cos_t) - eta_ti wi."""
    return m * dr.fma(dr.dot(wi, m), eta_ti, cos_t) - wi * eta_ti


def _sampling_distribution(p: RoughDielectricParams, cos_i: Float) -> Microfacet:
    """Walter's trick for sampling all normals: a slightly wider distribution lowers the weights' variance
    (not needed, and not used, for visible normals)."""
    if p.distr.sample_visible is True:
        return p.distr
    scaled = p.distr.scaled(1.2 - 0.2 * dr.sqrt(dr.abs(cos_i)))
    if p.distr.sample_visible is False:
        return scaled
    return Microfacet(p.distr.ggx, dr.select(p.distr.sample_visible, p.distr.alpha_u, scaled.alpha_u),
                      dr.select(p.distr.sample_visible, p.distr.alpha_v, scaled.alpha_v),
                      p.distr.sample_visible, p.distr.isotropic)


def _half_vector(wi: Array3f, wo: Array3f, eta_it: Float, reflected: Bool) -> Array3f:
    """h = wi + wo (reflection) or wi + eta' wo (refraction), turned to the macro normal's side."""
    m = dr.normalize(wi + wo * dr.select(reflected, 1.0, eta_it))
    return mulsign(m, m.z)


def _jacobian(wi: Array3f, wo: Array3f, m: Array3f, eta_it: Float, reflected: Bool) -> Float:
    """d omega_h / d omega_o: Walter (14) for reflection, (17) for refraction."""
    wo_m = dr.dot(wo, m)
    return dr.abs(dr.select(reflected, dr.rcp(4.0 * wo_m),
                            eta_it * eta_it * wo_m / dr.square(dr.dot(wi, m) + eta_it * wo_m)))


def sample(p: RoughDielectricParams, wi: Array3f, u1: Float, u2, active: Bool) -> tuple[BSDFSample, Array3f]:
    """(sample, weight = f |cos theta_o| / pdf): reflection with probability F, else refraction."""
    cos_i = wi.z
    active = active & (cos_i != 0)
    sampling = _sampling_distribution(p, cos_i)
    m, pdf = sampling.sample(mulsign(wi, cos_i), u2)
    active &= pdf != 0
    f, cos_t, eta_it, eta_ti = fresnel(dr.dot(wi, m), p.eta)
    reflected = u1 <= f
    pdf *= dr.select(reflected, f, 1.0 - f)
    wo = dr.select(reflected, reflect(-wi, m), refract(wi, m, cos_t, eta_ti))
    eta = dr.select(reflected, 1.0, eta_it)
    weight = dr.select(reflected, p.specular_reflectance, p.specular_transmittance * dr.square(eta_ti))
    # the normal's density cancels D: G1(wo) for visible normals; for all normals G |wi.m| / (cos_i cos_m)
    # times D / D' (D' Walter's widened distribution, which Mitsuba 3.9 leaves out: its weight is then
    # not f / pdf; see the module's docstring)
    weight *= pick(p.distr.sample_visible, lambda: p.distr.smith_g1(wo, m),
                   lambda: p.distr.G(wi, wo, m) * dr.dot(wi, m) / (cos_i * m.z) * p.distr.D(m) / sampling.D(m))
    pdf *= _jacobian(wi, wo, m, eta, reflected)
    kind = dr.select(reflected, UInt32(GLOSSY_REFLECTION), UInt32(GLOSSY_TRANSMISSION))
    return BSDFSample(wo, dr.select(active, pdf, 0.0), eta, kind), dr.select(active, weight, 0.0)


def eval(p: RoughDielectricParams, wi: Array3f, wo: Array3f, active: Bool) -> Array3f:
    """f |cos theta_o| (radiance transport)."""
    cos_i, cos_o = wi.z, wo.z
    active = active & (cos_i != 0)
    reflected = cos_i * cos_o > 0
    eta_it = dr.select(cos_i > 0, p.eta, dr.rcp(p.eta))
    m = _half_vector(wi, wo, eta_it, reflected)
    d, g = p.distr.D(m), p.distr.G(wi, wo, m)
    f = fresnel(dr.dot(wi, m), p.eta)[0]
    wi_m, wo_m = dr.dot(wi, m), dr.dot(wo, m)
    r = p.specular_reflectance * (f * d * g / (4.0 * dr.abs(cos_i)))
    # (1 / eta'^2) * eta'^2 of Walter (21): the radiance scaling cancels the Jacobian's eta'^2
    t = p.specular_transmittance * dr.abs((1.0 - f) * d * g * wi_m * wo_m / (cos_i * dr.square(wi_m + eta_it * wo_m)))
    return dr.select(active, dr.select(reflected, r, t), 0.0)


def pdf(p: RoughDielectricParams, wi: Array3f, wo: Array3f, active: Bool) -> Float:
    """Density of `sample`'s wo."""
    cos_i, cos_o = wi.z, wo.z
    reflected = cos_i * cos_o > 0
    eta_it = dr.select(cos_i > 0, p.eta, dr.rcp(p.eta))
    m = _half_vector(wi, wo, eta_it, reflected)
    active = active & (cos_i != 0) & (dr.dot(wi, m) * cos_i > 0) & (dr.dot(wo, m) * cos_o > 0)
    density = _sampling_distribution(p, cos_i).pdf(mulsign(wi, cos_i), m)
    f = fresnel(dr.dot(wi, m), p.eta)[0]
    density *= dr.select(reflected, f, 1.0 - f) * _jacobian(wi, wo, m, eta_it, reflected)
    return dr.select(active, density, 0.0)
