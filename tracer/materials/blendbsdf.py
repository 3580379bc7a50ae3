"""Mitsuba's `blendbsdf`: f = (1 - weight) f0 + weight f1 of two nested BSDFs, sampled by the second with
probability weight (a float or a texture, clipped to [0, 1]). The dispatcher applies it to any two kinds (materials.dispatch.SurfaceBSDF)."""
from __future__ import annotations

from dataclasses import replace

from .bsdf import BSDF
from .reading import check_fraction

PLUGINS = {"blendbsdf": ("weight",)}


def from_xml(ctx, props, node) -> BSDF:
    inner = props.children("bsdf")
    weight, texture = props.scalar("weight", 0.5)
    props.finish()
    if len(inner) != 2:
        raise ctx.error(node, "blendbsdf blends two bsdfs")
    check_fraction(ctx, props, node, "weight", weight)
    first, second = (ctx.bsdf(b) for b in inner)
    for child, part in zip(inner, (first, second)):
        if part.blend is not None or part.masked or part.normalmap is not None or part.texture_of("bumpmap"):
            raise ctx.error(child, "blendbsdf blends plain bsdfs (no blendbsdf, mask or normalmap inside; a mask "
                                   "may wrap the blendbsdf)")
    if first.twosided != second.twosided:
        raise ctx.error(node, "blendbsdf's two bsdfs must both be twosided or both not (wrap the blendbsdf "
                              "in twosided instead)")
    return replace(first, blend=(float(weight), second)).with_texture("weight", texture)
