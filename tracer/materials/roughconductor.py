"""Mitsuba's `roughconductor`: a Torrance-Sparrow microfacet reflector, f = F(wi.h) D(h) G(wi, wo, h) /
(4 cos theta_i cos theta_o) with h the half vector (Walter et al. 2007, (20)), F the exact conductor Fresnel
term of eta + i k (materials.fresnel.fresnel_conductor), times a specular reflectance. One-sided: zero
unless both directions lie above the surface. Sampling draws a microfacet normal (materials.microfacet)
and reflects wi about it; the density of wo is the normal's times the Jacobian 1 / (4 wo.h) (Walter (14))."""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from ..jit import Array3f, Bool, Float, UInt32
from ..spectra import rgb
from . import microfacet as mf
from .bsdf import BSDF, GLOSSY_REFLECTION, BSDFSample
from .fresnel import fresnel_conductor, reflect
from .microfacet import Microfacet, pick
from .reading import check_unit_interval, read_complex_ior, read_microfacet

NAME, FLAGS = "roughconductor", GLOSSY_REFLECTION
PLUGINS = {"roughconductor": ("distribution", "alpha", "alpha_u", "alpha_v", "sample_visible", "material", "eta",
                              "k", "specular_reflectance")}


@dataclass
class RoughConductorParams:
    distr: Microfacet
    eta: Array3f
    k: Array3f
    specular_reflectance: Array3f


def from_xml(ctx, props, node) -> BSDF:
    distribution = read_microfacet(ctx, props, node)
    eta, k = read_complex_ior(ctx, props, node)
    spec = props.colour("specular_reflectance", 1.0)
    props.finish()
    check_unit_interval(ctx, node, "specular_reflectance", spec)
    return BSDF(NAME, rgb(spec), eta=rgb(eta), k=rgb(k), **distribution)


def table(bsdfs: list[BSDF]) -> np.ndarray:
    """Per rough conductor: its distribution (microfacet.row), eta, k; the specular reflectance is the
    shared reflectance column."""
    rows = np.zeros((len(bsdfs), 10))
    for i, b in enumerate(bsdfs):
        if b.kind == NAME:
            rows[i] = [*mf.row(b), *b.eta, *b.k]
    return rows


def params(tables, surf, active: Bool) -> RoughConductorParams:
    r = tables.row(NAME, surf.material, active)
    return RoughConductorParams(mf.from_row(tables, NAME, r, surf, active), Array3f(*r[4:7]), Array3f(*r[7:10]),
                                tables.reflectance(surf, active))


def sample(p: RoughConductorParams, wi: Array3f, u1: Float, u2, active: Bool) -> tuple[BSDFSample, Array3f]:
    """(sample, weight = f cos theta_o / pdf); u1 is unused (one lobe)."""
    cos_i = wi.z
    active = active & (cos_i > 0)
    m, pdf = p.distr.sample(wi, u2)
    wo = reflect(-wi, m)
    active &= (pdf != 0) & (wo.z > 0)
    # the normal's density cancels D: G1(wo) for visible normals, else G |wi.m| / (cos_i cos_m)
    weight = pick(p.distr.sample_visible, lambda: p.distr.smith_g1(wo, m),
                  lambda: p.distr.G(wi, wo, m) * dr.dot(wi, m) / (cos_i * m.z))
    pdf = pdf / (4.0 * dr.dot(wo, m))
    weight = fresnel_conductor(dr.dot(wi, m), p.eta, p.k) * p.specular_reflectance * weight
    bs = BSDFSample(wo, dr.select(active, pdf, 0.0), Float(1.0), UInt32(GLOSSY_REFLECTION))
    return bs, dr.select(active, weight, 0.0)


def eval(p: RoughConductorParams, wi: Array3f, wo: Array3f, active: Bool) -> Array3f:
    """f cos theta_o."""
    cos_i = wi.z
    active = active & (cos_i > 0) & (wo.z > 0)
    h = dr.normalize(wo + wi)
    d = p.distr.D(h)
    active &= d != 0
    value = d * p.distr.G(wi, wo, h) / (4.0 * cos_i)
    value = fresnel_conductor(dr.dot(wi, h), p.eta, p.k) * p.specular_reflectance * value
    return dr.select(active, value, 0.0)


def pdf(p: RoughConductorParams, wi: Array3f, wo: Array3f, active: Bool) -> Float:
    """Density of `sample`'s wo; zero where micro- and macro-surface disagree on the side (G1 would be)."""
    cos_i = wi.z
    h = dr.normalize(wo + wi)
    active = active & (cos_i > 0) & (wo.z > 0) & (dr.dot(wi, h) > 0) & (dr.dot(wo, h) > 0)
    density = pick(p.distr.sample_visible, lambda: p.distr.D(h) * p.distr.smith_g1(wi, h) / (4.0 * cos_i),
                   lambda: p.distr.pdf(wi, h) / (4.0 * dr.dot(wo, h)))
    return dr.select(active, density, 0.0)
