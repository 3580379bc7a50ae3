"""Mitsuba's `pplastic` as its RGB (unpolarized) variants render it: a rough dielectric interface of relative
index eta over a Lambertian base, one-sided, without roughplastic's internal reflections (pplastic.cpp):

  f cos_o = s F(wi.h) D(h) G(wi, wo, h) / (4 cos_i) + rho (1 - F(cos_i)) (1 - F(cos_o)) cos_o / pi,

F the unpolarized dielectric Fresnel reflectance, s the specular reflectance (1 unless given), rho the
diffuse one. Sampling picks the specular lobe with probability mean(s) / (mean(rho) + mean(s)) (Mitsuba's
specular sampling weight, s counted 1 when not given), else the cosine-weighted base; a sample's weight is
eval / pdf of the mixture."""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from ..jit import Array3f, Bool, Float
from ..spectra import rgb
from . import microfacet as mf
from .bsdf import BSDF, DIFFUSE_REFLECTION, GLOSSY_REFLECTION, BSDFSample
from .microfacet import Microfacet, pick
from .reading import check_unit_interval, read_ior, read_microfacet
from .roughdielectric import fresnel
from .roughplastic import sample_layer

NAME, FLAGS = "pplastic", GLOSSY_REFLECTION | DIFFUSE_REFLECTION
PLUGINS = {"pplastic": ("diffuse_reflectance", "specular_reflectance", "eta", "int_ior", "ext_ior", "distribution",
                        "alpha", "alpha_u", "alpha_v", "sample_visible")}
FIELDS = 9           # microfacet.row (4), eta, the specular sampling weight, the specular reflectance (3)


@dataclass
class PPlasticParams:
    distr: Microfacet
    eta: Float
    specular_weight: Float
    specular_reflectance: Array3f
    diffuse_reflectance: Array3f


def from_xml(ctx, props, node) -> BSDF:
    distribution = read_microfacet(ctx, props, node)
    if props.has("eta") and (props.has("int_ior") or props.has("ext_ior")):
        raise ctx.error(node, "give either eta or int_ior and ext_ior, not both (as in Mitsuba)")
    if props.has("eta"):
        ior = {"int_ior": float(props.get("eta", 1.5, ("float", "integer"))), "ext_ior": 1.0}
    else:
        ior = {k: read_ior(ctx, props, k, d) for k, d in (("int_ior", "polypropylene"), ("ext_ior", "air"))}
    rho = props.colour("diffuse_reflectance", 0.5, textured=True)
    given = props.has("specular_reflectance")
    spec = props.colour("specular_reflectance", 1.0)
    props.finish()
    if min(ior.values()) < 0 or ior["int_ior"] == ior["ext_ior"]:
        raise ctx.error(node, "the interior and exterior indices of refraction must be positive and differ "
                              f"(as in Mitsuba), got {ior['int_ior']} and {ior['ext_ior']}")
    texture = None if isinstance(rho, np.ndarray) else rho
    if texture is not None:     # its mean steers only which lobe is sampled, not the estimate
        rho = np.full(3, 0.5)
    for name, value in (("diffuse_reflectance", rho), ("specular_reflectance", spec)):
        check_unit_interval(ctx, node, name, value)
    # the sampling weight's specular mean: 1 where no specular reflectance is given (Mitsuba's)
    weight = (np.mean(spec) if given else 1.0) / ((np.mean(spec) if given else 1.0) + np.mean(rho))
    if not np.isfinite(weight):
        raise ctx.error(node, "specular_reflectance and diffuse_reflectance are both 0: Mitsuba samples neither")
    return BSDF(NAME, reflectance=rgb(rho), texture=texture, specular_reflectance=rgb(spec),
                pplastic_weight=float(weight), **ior, **distribution)


def table(bsdfs: list[BSDF]) -> np.ndarray:
    rows = np.zeros((len(bsdfs), FIELDS))
    for i, b in enumerate(bsdfs):
        if b.kind == NAME:
            rows[i] = [*mf.row(b), b.int_ior / b.ext_ior, b.pplastic_weight, *b.specular_reflectance]
    return rows


def params(tables, surf, active: Bool) -> PPlasticParams:
    r = tables.row(NAME, surf.material, active, FIELDS)
    return PPlasticParams(mf.from_row(tables, NAME, r, surf, active), r[4], r[5], Array3f(*r[6:9]),
                          tables.reflectance(surf, active))


def sample(p: PPlasticParams, wi: Array3f, u1: Float, u2, active: Bool) -> tuple[BSDFSample, Array3f]:
    active = active & (wi.z > 0)
    return sample_layer(p, wi, u1 < p.specular_weight, u2, active, pdf, eval)


def eval(p: PPlasticParams, wi: Array3f, wo: Array3f, active: Bool) -> Array3f:
    cos_i, cos_o = wi.z, wo.z
    active = active & (cos_i > 0) & (cos_o > 0)
    h = dr.normalize(wo + wi)
    f = fresnel(dr.dot(wi, h), p.eta)[0]
    value = p.specular_reflectance * (f * p.distr.D(h) * p.distr.G(wi, wo, h) / (4.0 * cos_i))
    t_io = (1.0 - fresnel(cos_i, p.eta)[0]) * (1.0 - fresnel(cos_o, p.eta)[0])
    value += p.diffuse_reflectance * (t_io * cos_o * dr.inv_pi)
    return dr.select(active, value, 0.0)


def pdf(p: PPlasticParams, wi: Array3f, wo: Array3f, active: Bool) -> Float:
    cos_i, cos_o = wi.z, wo.z
    active = active & (cos_i > 0) & (cos_o > 0)
    h = dr.normalize(wo + wi)
    spec = pick(p.distr.sample_visible, lambda: p.distr.D(h) * p.distr.smith_g1(wi, h) / (4.0 * cos_i),
                lambda: p.distr.pdf(wi, h) / (4.0 * dr.dot(wo, h)))
    spec = dr.select((dr.dot(wi, h) <= 0) | (dr.dot(wo, h) <= 0), 0.0, spec)
    return dr.select(active, p.specular_weight * spec + (1.0 - p.specular_weight) * cos_o * dr.inv_pi, 0.0)
