"""Mitsuba's smooth `plastic`: a dielectric interface over a diffuse base (a BSDF kind, materials.bsdf): its
per-material table and the layer model's terms."""
from __future__ import annotations

import drjit as dr
import numpy as np

from ..jit import Array2f, Array3f, Bool, Float, UInt32
from ..sampling import INV_PI, square_to_cosine_hemisphere
from ..spectra import rgb
from .bsdf import BSDF, DELTA_REFLECTION, DIFFUSE_REFLECTION, BSDFSample, front, reflect_local, zero_unless
from .reading import check_unit_interval, read_ior
from .fresnel import fresnel_diffuse_reflectance, fresnel_dielectric

NAME, FLAGS = "plastic", DELTA_REFLECTION | DIFFUSE_REFLECTION
PLUGINS = {"plastic": ("diffuse_reflectance", "specular_reflectance", "int_ior", "ext_ior", "nonlinear")}
FIELDS = 8


def from_xml(ctx, props, node) -> BSDF:
    layers = read_layers(ctx, props, node)
    if min(layers["int_ior"], layers["ext_ior"]) <= 0:
        raise ctx.error(node, "indices of refraction must be positive")
    return BSDF(NAME, **layers)


def read_layers(ctx, props, node) -> dict:
    """The parameters smooth and rough plastic share (IORs, the base's and the coating's reflectances,
    `nonlinear`), read and checked, as BSDF's fields; finishes `props`."""
    ior = {k: read_ior(ctx, props, k, d) for k, d in (("int_ior", "polypropylene"), ("ext_ior", "air"))}
    rho, spec = props.colour("diffuse_reflectance", 0.5, textured=True), props.colour("specular_reflectance", 1.0)
    nonlinear = props.get("nonlinear", False, ("boolean",))
    props.finish()
    texture = None if isinstance(rho, np.ndarray) else rho
    if texture is not None:
        check_unit_interval(ctx, node, "diffuse_reflectance", texture)     # its mean steers only which layer is sampled, not the estimate
        rho = np.full(3, 0.5)
    for name, value in (("diffuse_reflectance", rho), ("specular_reflectance", spec)):
        check_unit_interval(ctx, node, name, value)
    return dict(reflectance=rgb(rho), int_ior=ior["int_ior"], ext_ior=ior["ext_ior"], specular_reflectance=rgb(spec),
                nonlinear=bool(nonlinear), texture=texture)


def table(materials: list) -> np.ndarray:
    """Per material, for smooth plastic: specular reflectance, then eta, 1 / eta^2, the interior's diffuse
    Fresnel reflectance, the specular sampling weight (Mitsuba's: the specular share of the two mean
    reflectances) and whether the internal scattering is nonlinear."""
    rows = np.zeros((len(materials), FIELDS))
    for i, b in enumerate(materials):
        if b.kind == NAME:
            eta = b.int_ior / b.ext_ior
            s_mean, d_mean = np.mean(b.specular_reflectance), np.mean(b.reflectance)
            rows[i] = [*b.specular_reflectance, eta, 1.0 / (eta * eta), fresnel_diffuse_reflectance(1.0 / eta),
                       s_mean / (d_mean + s_mean), float(b.nonlinear)]
    return rows


def params(tables, surf, active: Bool) -> tuple:
    """Specular reflectance, [eta, 1 / eta^2, fdr_int, specular weight, nonlinear], diffuse reflectance."""
    r = tables.row(NAME, surf.material, active)
    return Array3f(*r[0:3]), r[3:8], tables.reflectance(surf, active)


def sample(p, wi: Array3f, u1: Float, u2: Array2f, active: Bool) -> tuple[BSDFSample, Array3f]:
    """The specular layer (a Fresnel-weighted mirror) or the diffuse layer (cosine-weighted), chosen with
    Mitsuba's probability."""
    spec, (eta, inv_eta2, fdr_int, spec_weight, nonlinear), rho = p
    f_i = fresnel_dielectric(wi.z, eta)[0]
    p_spec = specular_probability(f_i, spec_weight)
    choose_spec = u1 < p_spec
    local = square_to_cosine_hemisphere(u2.x, u2.y)
    f_o = fresnel_dielectric(local.z, eta)[0]
    diffuse_weight = diffuse_layer(rho, fdr_int, nonlinear, inv_eta2, f_i, f_o) / (1.0 - p_spec)
    bs = BSDFSample(dr.select(choose_spec, reflect_local(wi), local),
                    dr.select(choose_spec, p_spec, (1.0 - p_spec) * local.z * INV_PI), Float(1.0),
                    dr.select(choose_spec, UInt32(DELTA_REFLECTION), UInt32(DIFFUSE_REFLECTION)))
    weight = dr.select(choose_spec, spec * (f_i / p_spec), diffuse_weight)
    return bs, zero_unless(active & front(wi), weight)


def eval(p, wi: Array3f, wo: Array3f, active: Bool) -> Array3f:
    """The diffuse layer's f cos (the specular layer is a delta lobe)."""
    spec, (eta, inv_eta2, fdr_int, spec_weight, nonlinear), rho = p
    f_i, f_o = fresnel_dielectric(wi.z, eta)[0], fresnel_dielectric(dr.maximum(wo.z, 0.0), eta)[0]
    value = diffuse_layer(rho, fdr_int, nonlinear, inv_eta2, f_i, f_o) * (wo.z * INV_PI)
    return zero_unless(active & front(wi, wo), value)


def pdf(p, wi: Array3f, wo: Array3f, active: Bool) -> Float:
    spec, (eta, inv_eta2, fdr_int, spec_weight, nonlinear), rho = p
    p_spec = specular_probability(fresnel_dielectric(wi.z, eta)[0], spec_weight)
    return dr.select(active & front(wi, wo), (1.0 - p_spec) * wo.z * INV_PI, 0.0)


def specular_probability(f_i: Float, specular_weight: Float) -> Float:
    """Probability that Mitsuba's smooth plastic samples its specular layer, given the Fresnel reflectance
    at the incident angle and the specular share of the mean reflectances."""
    spec = f_i * specular_weight
    return spec / (spec + (1.0 - f_i) * (1.0 - specular_weight))


def diffuse_layer(albedo: Array3f, fdr_int: Float, nonlinear: Float, inv_eta2: Float, f_i: Float,
                  f_o: Float) -> Array3f:
    """The diffuse layer's f * pi: the base's reflectance seen through the interface twice, with internal
    reflections summed (linearly, or per colour if `nonlinear`)."""
    denominator = 1.0 - dr.select(nonlinear > 0, albedo * fdr_int, Array3f(fdr_int))
    return albedo / denominator * (inv_eta2 * (1.0 - f_i) * (1.0 - f_o))
