"""Mitsuba's `diffuse`: the Lambertian BRDF (a BSDF kind, materials.bsdf)."""
import drjit as dr
import numpy as np

from ..jit import Array2f, Array3f, Bool, Float, UInt32
from ..sampling import INV_PI, square_to_cosine_hemisphere
from ..spectra import rgb
from .bsdf import BSDF, DIFFUSE_REFLECTION, BSDFSample, front, zero_unless
from .reading import check_unit_interval

NAME, FLAGS = "diffuse", DIFFUSE_REFLECTION
PLUGINS = {"diffuse": ("reflectance",)}


def diffuse_brdf(albedo: Array3f) -> Array3f:
    """Lambertian BRDF f = rho / pi (the f of eq. 10)."""
    return albedo * INV_PI


def params(tables, surf, active: Bool) -> Array3f:
    """The reflectance rho at the surface point (textured where the material is)."""
    return tables.reflectance(surf, active)


def sample(rho: Array3f, wi: Array3f, u1: Float, u2: Array2f, active: Bool) -> tuple[BSDFSample, Array3f]:
    """A cosine-weighted direction: weight (rho / pi) cos / (cos / pi) = rho (the report's eq. 11, cosine)."""
    wo = square_to_cosine_hemisphere(u2.x, u2.y)
    return (BSDFSample(wo, wo.z * INV_PI, Float(1.0), UInt32(DIFFUSE_REFLECTION)),
            zero_unless(active & front(wi), rho))


def eval(rho: Array3f, wi: Array3f, wo: Array3f, active: Bool) -> Array3f:
    return zero_unless(active & front(wi, wo), diffuse_brdf(rho) * wo.z)


def pdf(rho: Array3f, wi: Array3f, wo: Array3f, active: Bool) -> Float:
    return dr.select(active & front(wi, wo), wo.z * INV_PI, 0.0)


def albedo(rho: Array3f) -> Array3f:
    return rho


def from_xml(ctx, props, node) -> BSDF:
    rho = props.colour("reflectance", 0.5, textured=True)
    props.finish()
    check_unit_interval(ctx, node, "diffuse reflectance", rho)
    if not isinstance(rho, np.ndarray):
        return BSDF("diffuse", (0.0, 0.0, 0.0), texture=rho)
    return BSDF("diffuse", rgb(rho))
