"""Mitsuba's `mask`: a material that scatters by its nested BSDF with probability `opacity` and lets the ray
pass unchanged otherwise (a null lobe), so camera rays and rays sampled from other surfaces see through it.
As in Mitsuba's `path`, shadow rays are blocked by it. The dispatcher applies it to any kind
(materials.dispatch.SurfaceBSDF)."""
from __future__ import annotations

from dataclasses import replace

from .bsdf import BSDF

PLUGINS = {"mask": ("opacity",)}


def from_xml(ctx, props, node) -> BSDF:
    inner = props.children("bsdf")
    opacity = props.get("opacity", 0.5, ("float", "integer"))
    props.finish()
    if len(inner) != 1:
        raise ctx.error(node, "mask wraps one bsdf")
    if not 0.0 <= opacity <= 1.0:
        raise ctx.error(props.values.get("opacity", node), f"opacity must lie in [0, 1], got {opacity}")
    nested = ctx.bsdf(inner[0])
    return replace(nested, opacity=nested.opacity * float(opacity))
