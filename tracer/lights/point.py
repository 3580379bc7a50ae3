"""Mitsuba's `point` and `spot` emitters: delta lights at a position."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..jit import Float, UInt32, vec3
from ..spectra import rgb
from .sample import POINT_LIGHT, LightSample

PLUGINS = {"point": ("position", "to_world", "intensity", "sampling_weight"),
           "spot": ("to_world", "intensity", "cutoff_angle", "beam_width", "texture", "sampling_weight")}
ENVIRONMENT = False


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


def from_xml(ctx, props, node) -> PointLight:
    return (_spot if node.attrib.get("type") == "spot" else _point)(ctx, props, node)


def _point(ctx, props, node) -> PointLight:
    """Mitsuba's `point` emitter: at `position`, or at the translation of `to_world`."""
    if props.has("position") and props.has("to_world"):
        raise ctx.error(node, "give either position or to_world, not both (as in Mitsuba)")
    position = props.get("position", None, ("point",))
    if position is None:
        position = props.get("to_world", np.eye(4), ("transform",))[:3, 3]
    intensity = props.colour("intensity", 1.0)
    props.ignore("sampling_weight")       # changes how often the light is sampled, not the estimate
    props.finish()
    if np.any(intensity < 0):
        raise ctx.error(node, f"intensity must be non-negative, got {rgb(intensity)}")
    return PointLight(np.asarray(position, float), rgb(intensity), node.attrib.get("id", f"point@{node.line}"))


def _spot(ctx, props, node) -> PointLight:
    """Mitsuba's `spot` emitter: at to_world's origin, along its +z, with a linear falloff in angle."""
    to_world = props.get("to_world", np.eye(4), ("transform",))
    intensity = props.colour("intensity", 1.0)
    cutoff = float(props.get("cutoff_angle", 20.0, ("float", "integer")))
    beam = float(props.get("beam_width", cutoff * 3.0 / 4.0, ("float", "integer")))
    props.ignore("sampling_weight")       # changes how often the light is sampled, not the estimate
    props.finish()
    linear = to_world[:3, :3]
    if not np.allclose(linear.T @ linear, np.eye(3), atol=1e-5):
        raise ctx.error(node, "a spot light's to_world must be a rotation and a translation (no scale or shear)")
    if not 0 < beam < cutoff < 180:
        raise ctx.error(node, f"need 0 < beam_width < cutoff_angle < 180 degrees, got {beam} and {cutoff}")
    if np.any(intensity < 0):
        raise ctx.error(node, f"intensity must be non-negative, got {rgb(intensity)}")
    axis = linear[:, 2] / np.linalg.norm(linear[:, 2])
    return PointLight(to_world[:3, 3].copy(), rgb(intensity), node.attrib.get("id", f"spot@{node.line}"),
                      spot=(axis, cutoff, beam))
