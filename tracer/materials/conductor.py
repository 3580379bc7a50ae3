"""Mitsuba's smooth `conductor`: a mirror weighted by its specular reflectance and the exact conductor Fresnel
term (materials.fresnel.fresnel_conductor) of a complex index, given as eta and k or by a material's name (a
BSDF kind, materials.bsdf)."""
from __future__ import annotations

import numpy as np

from ..jit import Array2f, Array3f, Bool, Float, UInt32
from ..spectra import rgb
from .bsdf import BSDF, DELTA_REFLECTION, BSDFSample, front, reflect_local, zero_unless
from .fresnel import fresnel_conductor
from .reading import check_unit_interval, read_complex_ior

NAME, FLAGS = "conductor", DELTA_REFLECTION
PLUGINS = {"conductor": ("material", "eta", "k", "specular_reflectance")}


def from_xml(ctx, props, node) -> BSDF:
    eta, k = read_complex_ior(ctx, props, node)
    spec = props.colour("specular_reflectance", 1.0)
    props.finish()
    check_unit_interval(ctx, node, "specular_reflectance", spec)
    return BSDF("conductor", rgb(spec), eta=rgb(eta), k=rgb(k))


def table(bsdfs: list[BSDF]) -> np.ndarray | None:
    """Per conductor: specular reflectance, eta, k. None where every conductor is a perfect mirror: the
    kernel then carries no Fresnel term."""
    if all(b.perfect_mirror for b in bsdfs if b.kind == NAME):
        return None
    rows = np.zeros((len(bsdfs), 9))
    for i, b in enumerate(bsdfs):
        if b.kind == NAME:
            rows[i] = [*b.reflectance, *b.eta, *b.k]
    return rows


def params(tables, surf, active: Bool) -> tuple[Array3f, Array3f, Array3f] | None:
    """Specular reflectance, eta and k (None in a scene of perfect mirrors)."""
    if not tables.has_table(NAME):
        return None
    r = tables.row(NAME, surf.material, active)
    return Array3f(*r[0:3]), Array3f(*r[3:6]), Array3f(*r[6:9])


def sample(p, wi: Array3f, u1: Float, u2: Array2f, active: Bool) -> tuple[BSDFSample, Array3f]:
    """The mirror direction (eq. 5), weighted by the specular reflectance times the Fresnel reflectance."""
    weight = Array3f(1.0)
    if p is not None:
        spec, eta, k = p
        weight = spec * fresnel_conductor(wi.z, eta, k)
    return (BSDFSample(reflect_local(wi), Float(1.0), Float(1.0), UInt32(DELTA_REFLECTION)),
            zero_unless(active & front(wi), weight))


def eval(p, wi: Array3f, wo: Array3f, active: Bool) -> Array3f:
    return Array3f(0.0)


def pdf(p, wi: Array3f, wo: Array3f, active: Bool) -> Float:
    return Float(0.0)
