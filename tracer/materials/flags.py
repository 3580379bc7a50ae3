"""What a BSDF's sample returns, in the local shading frame, and Mitsuba's BSDFFlags (same bits, same
meanings): which lobe a sample came from and what a BSDF can do."""
from __future__ import annotations

from dataclasses import dataclass
from enum import IntFlag

from ..jit import Array3f, Float, UInt32


class BSDFFlags(IntFlag):
    NULL = 1
    DIFFUSE_REFLECTION = 2
    DIFFUSE_TRANSMISSION = 4
    GLOSSY_REFLECTION = 8
    GLOSSY_TRANSMISSION = 16
    DELTA_REFLECTION = 32
    DELTA_TRANSMISSION = 64
    ANISOTROPIC = 128
    SPATIALLY_VARYING = 256
    NON_SYMMETRIC = 512
    FRONT_SIDE = 1024
    BACK_SIDE = 2048


@dataclass
class BSDFSample:
    """A sampled direction wo (pointing away from the surface), its density (solid angle), the relative
    index of refraction crossed (1 for reflection) and the BSDFFlags bit of the sampled lobe."""

    wo: Array3f
    pdf: Float
    eta: Float
    sampled_type: UInt32
