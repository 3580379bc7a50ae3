"""Mitsuba's smooth `plastic`: a dielectric interface over a diffuse base (its per-material table and the
layer model's terms; the path integrator samples it)."""
from __future__ import annotations

import drjit as dr
import numpy as np

from ..jit import Array3f, Bool, Float, UInt32
from ..spectra import rgb
from .bsdf import BSDF
from .reading import check_unit_interval, read_ior
from .fresnel import fresnel_diffuse_reflectance

PLUGINS = {"plastic": ("diffuse_reflectance", "specular_reflectance", "int_ior", "ext_ior", "nonlinear")}
FIELDS = 8


def from_xml(ctx, props, node) -> BSDF:
    ior = {k: read_ior(ctx, props, k, d) for k, d in (("int_ior", "polypropylene"), ("ext_ior", "air"))}
    rho, spec = props.colour("diffuse_reflectance", 0.5, textured=True), props.colour("specular_reflectance", 1.0)
    nonlinear = props.get("nonlinear", False, ("boolean",))
    props.finish()
    texture = None if isinstance(rho, np.ndarray) else rho
    if texture is not None:     # its mean steers only which layer is sampled, not the estimate
        rho = np.full(3, 0.5)
    for name, value in (("diffuse_reflectance", rho), ("specular_reflectance", spec)):
        check_unit_interval(ctx, node, name, value)
    if min(ior.values()) <= 0:
        raise ctx.error(node, "indices of refraction must be positive")
    return BSDF("plastic", rgb(rho), int_ior=ior["int_ior"], ext_ior=ior["ext_ior"], specular_reflectance=rgb(spec),
                nonlinear=bool(nonlinear), texture=texture)


def table(materials: list) -> Float:
    """Per material, for smooth plastic: specular reflectance, then eta, 1 / eta^2, the interior's diffuse
    Fresnel reflectance, the specular sampling weight (Mitsuba's: the specular share of the two mean
    reflectances) and whether the internal scattering is nonlinear."""
    rows = np.zeros((len(materials), FIELDS))
    for i, b in enumerate(materials):
        if b.kind == "plastic":
            eta = b.int_ior / b.ext_ior
            s_mean, d_mean = np.mean(b.specular_reflectance), np.mean(b.reflectance)
            rows[i] = [*b.specular_reflectance, eta, 1.0 / (eta * eta), fresnel_diffuse_reflectance(1.0 / eta),
                       s_mean / (d_mean + s_mean), float(b.nonlinear)]
    return Float(rows.ravel())


def lookup(rows: Float, material: UInt32, active: Bool) -> tuple[Array3f, list[Float]]:
    """A plastic material's specular reflectance and [eta, 1 / eta^2, fdr_int, specular weight, nonlinear]."""
    spec = Array3f(*(dr.gather(Float, rows, material * FIELDS + k, active) for k in range(3)))
    return spec, [dr.gather(Float, rows, material * FIELDS + 3 + k, active) for k in range(5)]


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
