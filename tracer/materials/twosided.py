"""Mitsuba's `twosided`: a material that reflects on both sides, the same BSDF on both or a front and a back
one. Seen from below, the back's BSDF is evaluated with wi and wo mirrored through the surface (the
dispatcher does it, materials.dispatch.SurfaceBSDF); as in Mitsuba, only BSDFs without transmission can be
nested."""
from __future__ import annotations

from dataclasses import replace

from .bsdf import BSDF, TRANSMISSION
from .dispatch import KIND_CODE, KINDS

PLUGINS = {"twosided": ("allow_transmission",)}


def from_xml(ctx, props, node) -> BSDF:
    inner = props.children("bsdf")
    if props.get("allow_transmission", False, ("boolean",)):
        raise ctx.error(props.values["allow_transmission"], "allow_transmission = true is not supported")
    props.finish()
    if len(inner) not in (1, 2):
        raise ctx.error(node, "twosided wraps one bsdf (or two: front and back)")
    sides = [ctx.bsdf(b) for b in inner]
    for child, side in zip(inner, sides):
        if side.normalmap is not None or side.texture_of("bumpmap") is not None:
            raise ctx.error(child, "twosided around normalmap or bumpmap is not supported; supported: twosided "
                                   "around one or two BSDFs without them")
        if side.twosided:
            raise ctx.error(child, "a twosided bsdf cannot be nested in twosided")
        for kind in [side.kind] + ([side.blend[1].kind] if side.blend is not None else []):
            if KINDS[KIND_CODE[kind]].FLAGS & TRANSMISSION:
                raise ctx.error(child, f"twosided wraps bsdfs without transmission only (as Mitsuba); "
                                       f"'{kind}' transmits")
    back = sides[-1] if len(sides) == 2 and sides[1] != sides[0] else None
    return replace(sides[0], twosided=True, back=back)
