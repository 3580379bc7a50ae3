"""Mitsuba's `directional` emitter: a delta light at infinity."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..jit import Float, UInt32, vec3
from .sample import DIRECTIONAL_LIGHT, LightSample


@dataclass(eq=False)
class DirectionalLight:
    """Mitsuba's `directional` emitter: `irradiance` arriving along the unit vector `direction` (the way the
    light travels) from infinitely far away."""

    direction: np.ndarray
    irradiance: tuple[float, float, float]
    name: str = ""

    def sample(self, n_lights: int) -> LightSample:
        """y: the direction towards it; n: the one it shines along; chosen with probability 1 / n_lights."""
        return LightSample(vec3(-self.direction), vec3(self.direction), vec3(self.irradiance),
                           Float(1.0 / n_lights), UInt32(DIRECTIONAL_LIGHT))
