"""Mitsuba's `constant` emitter: the same radiance arriving from every direction (an environment)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..spectra import rgb

PLUGINS = {"constant": ("radiance", "sampling_weight", "to_world")}
ENVIRONMENT = True    # at most one environment emitter per scene


@dataclass(eq=False)
class ConstantEnvironment:
    radiance: tuple[float, float, float]
    name: str = ""
    sampling_weight: float = 1.0       # Mitsuba's: relative to the other lights' (lights.choice)


def from_xml(ctx, props, node) -> ConstantEnvironment:
    """Mitsuba's `constant` emitter: the same radiance arriving from every direction."""
    value = props.colour("radiance", 1.0)
    weight = props.sampling_weight()
    props.ignore("to_world")              # a uniform environment looks the same however it is turned
    props.finish()
    if np.any(value < 0):
        raise ctx.error(node, f"radiance must be non-negative, got {rgb(value)}")
    return ConstantEnvironment(rgb(value), node.attrib.get("id", f"constant@{node.line}"), weight)
