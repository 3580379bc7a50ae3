"""Mitsuba's `directional` emitter: a delta light at infinity."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..jit import Float, UInt32, vec3
from ..spectra import rgb
from .sample import DIRECTIONAL_LIGHT, LightSample

PLUGINS = {"directional": ("direction", "to_world", "irradiance", "sampling_weight")}
ENVIRONMENT = False


@dataclass(eq=False)
class DirectionalLight:
    """Mitsuba's `directional` emitter: `irradiance` arriving along the unit vector `direction` (the way the
    light travels) from infinitely far away."""

    direction: np.ndarray
    irradiance: tuple[float, float, float]
    name: str = ""
    sampling_weight: float = 1.0       # Mitsuba's: relative to the other lights' (lights.choice)

    def sample(self, pmf: float, spots: bool = False) -> LightSample:
        """y: the direction towards it; n: the one it shines along; chosen with probability pmf (it has no
        cone, whether or not the scene has spot lights)."""
        return LightSample(vec3(-self.direction), vec3(self.direction), vec3(self.irradiance),
                           Float(pmf), UInt32(DIRECTIONAL_LIGHT))


def from_xml(ctx, props, node) -> DirectionalLight:
    """Mitsuba's `directional` emitter: along `direction`, or along to_world's +z."""
    if props.has("direction") and props.has("to_world"):
        raise ctx.error(node, "give either direction or to_world, not both (as in Mitsuba)")
    if props.has("direction"):
        d = props.get("direction", tags=("vector",))
    else:
        linear = props.get("to_world", np.eye(4), ("transform",))[:3, :3]
        if not np.allclose(linear.T @ linear, np.eye(3), atol=1e-5):
            raise ctx.error(node, "a directional light's to_world must be a rotation (no scale or shear)")
        d = linear[:, 2]
    irradiance = props.colour("irradiance", 1.0)
    weight = props.sampling_weight()
    props.finish()
    if not np.any(d):
        raise ctx.error(node, "the direction is zero")
    if np.any(irradiance < 0):
        raise ctx.error(node, f"irradiance must be non-negative, got {rgb(irradiance)}")
    return DirectionalLight(d / np.linalg.norm(d), rgb(irradiance), node.attrib.get("id", f"directional@{node.line}"),
                            weight)
