"""Mitsuba's `mask`: a material that scatters by its nested BSDF with probability `opacity` (a float or a
texture, clipped to [0, 1]) and lets the ray pass unchanged otherwise (a null lobe), so camera rays and rays
sampled from other surfaces see through it. As in Mitsuba's `path`, shadow rays are blocked by it. The
dispatcher applies it to any kind (materials.dispatch.SurfaceBSDF)."""
from __future__ import annotations

from dataclasses import replace

from .bsdf import BSDF
from .reading import check_fraction

PLUGINS = {"mask": ("opacity",)}


def from_xml(ctx, props, node) -> BSDF:
    inner = props.children("bsdf")
    opacity, texture = props.scalar("opacity", 0.5)
    props.finish()
    if len(inner) != 1:
        raise ctx.error(node, "mask wraps one bsdf")
    check_fraction(ctx, props, node, "opacity", opacity)
    nested = ctx.bsdf(inner[0])
    if nested.masked and (texture is not None or nested.texture_of("opacity") is not None):
        raise ctx.error(inner[0], "a mask with a textured opacity inside or around another mask is not supported; "
                                  "supported: nested masks of constant opacity")
    if texture is not None:
        return replace(nested.with_texture("opacity", texture), opacity=0.0)
    return replace(nested, opacity=nested.opacity * float(opacity))
