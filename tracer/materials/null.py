"""Mitsuba's `null`: a surface that does not scatter; a ray crossing it continues unchanged (a BSDF kind,
materials.bsdf). As in Mitsuba's `path`, the crossing is a path vertex, and shadow rays are blocked by the
surface: light behind it is found by the continued ray (a delta lobe, so without MIS)."""
from __future__ import annotations

from ..jit import Array2f, Array3f, Bool, Float, UInt32
from .bsdf import BSDF, NULL, BSDFFlags, BSDFSample, zero_unless

NAME, FLAGS = "null", BSDFFlags.NULL | BSDFFlags.FRONT_SIDE | BSDFFlags.BACK_SIDE
PLUGINS = {"null": ()}


def from_xml(ctx, props, node) -> BSDF:
    props.finish()
    return BSDF(NAME)


def params(tables, surf, active: Bool) -> None:
    return None


def sample(p, wi: Array3f, u1: Float, u2: Array2f, active: Bool) -> tuple[BSDFSample, Array3f]:
    """wo = -wi with weight 1."""
    return BSDFSample(-wi, Float(1.0), Float(1.0), UInt32(NULL)), zero_unless(active, Array3f(1.0))


def eval(p, wi: Array3f, wo: Array3f, active: Bool) -> Array3f:
    return Array3f(0.0)


def pdf(p, wi: Array3f, wo: Array3f, active: Bool) -> Float:
    return Float(0.0)


def null_transmission(p, wi: Array3f, active: Bool) -> Array3f:
    """The fraction of light that passes straight through: all of it."""
    return zero_unless(active, Array3f(1.0))
