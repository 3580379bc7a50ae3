"""Mitsuba's `polarizer` (a linear polarizer) as Mitsuba's RGB, unpolarized variants render it: a null surface
that passes a ray unchanged, its radiance scaled by half its `transmittance` (polarizer.cpp: an ideal linear
polarizer lets through half of unpolarized light; `theta`, its axis, and `polarizing` matter only to
polarized variants, which the tracer is not). As `null` (materials.null), the crossing is a path vertex and
shadow rays are blocked by it."""
from __future__ import annotations

import numpy as np

from ..jit import Array2f, Array3f, Bool, Float, UInt32
from ..spectra import rgb
from .bsdf import BSDF, NULL, BSDFFlags, BSDFSample, zero_unless
from .reading import check_unit_interval

NAME, FLAGS = "polarizer", BSDFFlags.NULL | BSDFFlags.FRONT_SIDE | BSDFFlags.BACK_SIDE
PLUGINS = {"polarizer": ("theta", "transmittance", "polarizing")}


def from_xml(ctx, props, node) -> BSDF:
    transmittance = props.colour("transmittance", 1.0)
    props.ignore("theta", "polarizing")    # the polarizer's axis: no effect on unpolarized light
    props.finish()
    check_unit_interval(ctx, node, "polarizer transmittance", transmittance)
    return BSDF(NAME, rgb(0.5 * np.asarray(transmittance)))


def params(tables, surf, active: Bool) -> Array3f:
    """Half the transmittance (BSDF.reflectance holds it)."""
    return tables.reflectance(surf, active)


def sample(half_t: Array3f, wi: Array3f, u1: Float, u2: Array2f, active: Bool) -> tuple[BSDFSample, Array3f]:
    """wo = -wi with weight T / 2."""
    return BSDFSample(-wi, Float(1.0), Float(1.0), UInt32(NULL)), zero_unless(active, half_t)


def eval(half_t: Array3f, wi: Array3f, wo: Array3f, active: Bool) -> Array3f:
    return Array3f(0.0)


def pdf(half_t: Array3f, wi: Array3f, wo: Array3f, active: Bool) -> Float:
    return Float(0.0)
