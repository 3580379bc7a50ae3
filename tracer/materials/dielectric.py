"""Mitsuba's smooth `dielectric`: reflection and refraction at an interface of two indices."""
import drjit as dr

from ..jit import Array3f, Float
from .fresnel import fresnel_dielectric, reflect, refract


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
