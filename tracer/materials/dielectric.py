"""Mitsuba's smooth `dielectric`: reflection and refraction at an interface of two indices."""
import drjit as dr

import numpy as np

from ..jit import Array3f, Float
from .bsdf import BSDF
from .reading import read_ior
from .fresnel import fresnel_dielectric, reflect, refract

PLUGINS = {"dielectric": ("int_ior", "ext_ior", "specular_reflectance", "specular_transmittance")}


def from_xml(ctx, props, node) -> BSDF:
    ior = {k: read_ior(ctx, props, k, d) for k, d in (("int_ior", "bk7"), ("ext_ior", "air"))}
    for name in ("specular_reflectance", "specular_transmittance"):
        if np.any(props.colour(name, 1.0) != 1.0):
            raise ctx.error(props.values[name], f"{name} other than 1 is unsupported")
    props.finish()
    if min(ior.values()) <= 0:
        raise ctx.error(node, "indices of refraction must be positive")
    return BSDF("dielectric", (1.0, 1.0, 1.0), int_ior=ior["int_ior"], ext_ior=ior["ext_ior"])


def dielectric_interface(d: Array3f, n: Array3f, int_ior: Float, ext_ior: Float):
    """Everything both estimators need at a smooth dielectric hit by a ray of direction d.

    Returns (F, reflected, refracted, radiance_scale): refracted radiance is scaled by (n1/n2)^2,
    the 1/eta^2 of radiance crossing an interface.
    """
    cos_nd = dr.dot(n, d)
    entering = cos_nd < 0
    n_facing = dr.select(entering, n, -n)
    cos_i = dr.abs(cos_nd)
    eta = dr.select(entering, int_ior / ext_ior, ext_ior / int_ior)
    f, cos_t, ratio = fresnel_dielectric(cos_i, eta)
    reflected = reflect(d, n_facing)
    refracted = refract(d, n_facing, cos_i, cos_t, ratio)
    return f, reflected, refracted, ratio * ratio
