"""Mitsuba's `thindielectric`: a thin slab of a dielectric (a window pane), a BSDF kind (materials.bsdf).
Light is reflected with R = 2 r / (1 + r), r the Fresnel reflectance at the slab's surface, which sums the
internal reflections r + t r t + t r^3 t + ... (t = 1 - r); the rest passes straight through (a null lobe,
no refraction: the two surfaces' refractions cancel)."""
from __future__ import annotations

import drjit as dr
import numpy as np

from ..jit import Array2f, Array3f, Bool, Float, UInt32
from ..spectra import rgb
from .bsdf import BSDF, DELTA_REFLECTION, NULL, BSDFFlags, BSDFSample, reflect_local, zero_unless
from .fresnel import fresnel_dielectric
from .reading import check_unit_interval, read_ior

NAME = "thindielectric"
FLAGS = BSDFFlags.DELTA_REFLECTION | BSDFFlags.NULL | BSDFFlags.FRONT_SIDE | BSDFFlags.BACK_SIDE
SPLIT = 2                  # split() lists both lobes
PLUGINS = {"thindielectric": ("int_ior", "ext_ior", "specular_reflectance", "specular_transmittance")}


def from_xml(ctx, props, node) -> BSDF:
    ior = {k: read_ior(ctx, props, k, d) for k, d in (("int_ior", "bk7"), ("ext_ior", "air"))}
    spec, trans = (props.colour(name, 1.0) for name in ("specular_reflectance", "specular_transmittance"))
    props.finish()
    for name, value in (("specular_reflectance", spec), ("specular_transmittance", trans)):
        check_unit_interval(ctx, node, name, value)
    if min(ior.values()) <= 0:
        raise ctx.error(node, "indices of refraction must be positive")
    return BSDF(NAME, rgb(trans), int_ior=ior["int_ior"], ext_ior=ior["ext_ior"], specular_reflectance=rgb(spec))


def table(bsdfs: list[BSDF]) -> np.ndarray:
    """Per thin dielectric: the relative index int_ior / ext_ior, the specular reflectance and transmittance."""
    return np.array([[b.int_ior / b.ext_ior, *b.specular_reflectance, *b.reflectance] if b.kind == NAME
                     else [1.0] * 7 for b in bsdfs])


def params(tables, surf, active: Bool) -> tuple[Float, Array3f, Array3f]:
    r = tables.row(NAME, surf.material, active)
    return r[0], Array3f(*r[1:4]), Array3f(*r[4:7])


def slab_reflectance(r: Float) -> Float:
    """The slab's reflectance from its surface's: r + t r t + t r^3 t + ... = 2 r / (1 + r)."""
    return r * 2.0 / (1.0 + r)


def _reflectance(eta: Float, wi: Array3f) -> Float:
    return slab_reflectance(fresnel_dielectric(dr.abs(wi.z), eta)[0])


def sample(p, wi: Array3f, u1: Float, u2: Array2f, active: Bool) -> tuple[BSDFSample, Array3f]:
    """Reflection with probability R, else straight through; weight the specular reflectance or
    transmittance."""
    eta, spec, trans = p
    r = _reflectance(eta, wi)
    reflect = u1 <= r
    bs = BSDFSample(dr.select(reflect, reflect_local(wi), -wi), dr.select(reflect, r, 1.0 - r), Float(1.0),
                    dr.select(reflect, UInt32(DELTA_REFLECTION), UInt32(NULL)))
    return bs, zero_unless(active, dr.select(reflect, spec, trans))


def split(p, wi: Array3f, active: Bool) -> list[tuple[Array3f, Array3f]]:
    """Both rays, weighted by R and 1 - R (times the specular reflectance and transmittance)."""
    eta, spec, trans = p
    r = _reflectance(eta, wi)
    return [(reflect_local(wi), spec * r), (-wi, trans * (1.0 - r))]


def null_transmission(p, wi: Array3f, active: Bool) -> Array3f:
    """The fraction of light that passes straight through, 1 - R, times the specular transmittance (Mitsuba's
    eval_null_transmission: a shadow ray of `volpath` passes the slab with this weight)."""
    eta, spec, trans = p
    return zero_unless(active, trans * (1.0 - _reflectance(eta, wi)))


def eval(p, wi: Array3f, wo: Array3f, active: Bool) -> Array3f:
    return Array3f(0.0)


def pdf(p, wi: Array3f, wo: Array3f, active: Bool) -> Float:
    return Float(0.0)
