"""Mitsuba's `point` and `spot` emitters: delta lights at a position."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..jit import Float, UInt32, vec3
from .sample import POINT_LIGHT, LightSample


@dataclass(eq=False)
class PointLight:
    """Mitsuba's `point` emitter: `intensity` (radiant intensity) from `position` in every direction; with
    `spot` = (axis, cutoff_angle, beam_width) in degrees, Mitsuba's `spot`: full intensity within beam_width
    of the axis, falling linearly in angle to 0 at cutoff_angle."""

    position: np.ndarray
    intensity: tuple[float, float, float]
    name: str = ""
    spot: tuple[np.ndarray, float, float] | None = None

    def cone(self) -> tuple[tuple[float, float, float], float, float, float, float]:
        """(axis, cos cutoff, cos beam width, cutoff in radians, 1 / transition width in radians); a point
        light's cone admits every direction at full intensity."""
        if self.spot is None:
            return (0.0, 0.0, 0.0), -2.0, -2.0, 0.0, 0.0
        axis, cutoff, beam = self.spot
        c, b = np.radians(cutoff), np.radians(beam)
        return tuple(float(x) for x in axis), float(np.cos(c)), float(np.cos(b)), float(c), float(1.0 / (c - b))

    def sample(self, n_lights: int, spots: bool) -> LightSample:
        """Its position, chosen with probability 1 / n_lights; the spot's axis rides in n, its cone in `cone`
        where the scene has spot lights."""
        axis, *cone = self.cone()
        return LightSample(vec3(self.position), vec3(axis), vec3(self.intensity), Float(1.0 / n_lights),
                           UInt32(POINT_LIGHT), tuple(Float(x) for x in cone) if spots else None)
