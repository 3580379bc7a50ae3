"""Mitsuba's smooth `dielectric`: reflection and refraction at an interface of two indices (a BSDF kind,
materials.bsdf)."""
from __future__ import annotations

import drjit as dr
import numpy as np

from ..jit import Array2f, Array3f, Bool, Float, UInt32
from .bsdf import BSDF, DELTA_REFLECTION, DELTA_TRANSMISSION, BSDFSample
from .reading import read_ior
from .fresnel import fresnel_dielectric, reflect, refract

NAME, FLAGS = "dielectric", DELTA_REFLECTION | DELTA_TRANSMISSION
SPLIT = 2                  # split() lists both lobes
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


def table(bsdfs: list[BSDF]) -> np.ndarray:
    """Per dielectric: the interior's and the exterior's index."""
    return np.array([[b.int_ior, b.ext_ior] if b.kind == NAME else [1.0, 1.0] for b in bsdfs])


def params(tables, surf, active: Bool) -> list[Float]:
    return tables.row(NAME, surf.material, active)


def _interface(p, wi: Array3f):
    """dielectric_interface in the local frame, and the relative index eta of the refraction."""
    int_ior, ext_ior = p
    f, reflected, refracted, scale = dielectric_interface(-wi, Array3f(0.0, 0.0, 1.0), int_ior, ext_ior)
    return f, reflected, refracted, scale, dr.select(wi.z > 0, int_ior / ext_ior, ext_ior / int_ior)


def sample(p, wi: Array3f, u1: Float, u2: Array2f, active: Bool) -> tuple[BSDFSample, Array3f]:
    """Reflection with probability F, else refraction (weight 1 / eta^2), from either side."""
    f, reflected, refracted, scale, eta = _interface(p, wi)
    choose_reflect = u1 < f
    bs = BSDFSample(dr.select(choose_reflect, reflected, refracted), dr.select(choose_reflect, f, 1.0 - f),
                    dr.select(choose_reflect, 1.0, eta),
                    dr.select(choose_reflect, UInt32(DELTA_REFLECTION), UInt32(DELTA_TRANSMISSION)))
    return bs, dr.select(active, Array3f(dr.select(choose_reflect, 1.0, scale)), Array3f(0.0))


def split(p, wi: Array3f, active: Bool) -> list[tuple[Array3f, Array3f]]:
    """Both rays, weighted by F and (1 - F) / eta^2 (eq. 7-8, 12)."""
    f, reflected, refracted, scale, _ = _interface(p, wi)
    return [(reflected, Array3f(f)), (refracted, Array3f((1.0 - f) * scale))]


def eval(p, wi: Array3f, wo: Array3f, active: Bool) -> Array3f:
    return Array3f(0.0)


def pdf(p, wi: Array3f, wo: Array3f, active: Bool) -> Float:
    return Float(0.0)
