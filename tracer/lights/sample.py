"""A light sample, as every kind of light returns it, and the uniform choice among the scene's lights."""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr

from ..jit import NO_PRIM, Array3f, Bool, Float, UInt32

POINT_LIGHT = NO_PRIM - 1   # the `prim` of a sample on a point light (NO_PRIM: on the environment)
DIRECTIONAL_LIGHT = NO_PRIM - 2


@dataclass
class LightSample:
    y: Array3f
    n: Array3f
    radiance: Array3f
    pdf_area: Float   # includes the choice of the light among the scene's lights
    prim: UInt32
    cone: tuple | None = None   # a spot light's (cos cutoff, cos beam width, cutoff, 1 / transition width)


def select_sample(mask: Bool, a: LightSample, b: LightSample) -> LightSample:
    """a where mask, else b (a light without a cone admits every direction at full intensity)."""
    cone = None
    if a.cone is not None or b.cone is not None:
        a_cone, b_cone = (s.cone if s.cone is not None else (Float(-2.0),) * 2 + (Float(0.0),) * 2 for s in (a, b))
        cone = tuple(dr.select(mask, x, y) for x, y in zip(a_cone, b_cone))
    return LightSample(dr.select(mask, a.y, b.y), dr.select(mask, a.n, b.n), dr.select(mask, a.radiance, b.radiance),
                       dr.select(mask, a.pdf_area, b.pdf_area), dr.select(mask, a.prim, b.prim), cone)
