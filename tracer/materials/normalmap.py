"""Mitsuba's `normalmap`: its nested BSDF seen in a shading frame tilted by a bitmap of normals given in the
shading frame's own coordinates (a texel c holds the normal 2 c - 1, as the texture reads it: `raw` keeps the
file's values). As in Mitsuba 3.9.1, with `flip_invalid_normals` (true by default) a normal facing away from
wi is mirrored about the unperturbed normal (its x and y negated); the tilted frame's first tangent is the
unperturbed frame's x made orthogonal to the new normal; a direction below either the unperturbed or the
tilted surface scatters nothing; and with `use_shadowing_function` (true) the response is scaled by Estevez
et al.'s shadowing term (Ray Tracing Gems, 2019, ch. 12). The dispatcher applies it to any kind
(materials.dispatch.SurfaceBSDF)."""
from __future__ import annotations

from dataclasses import replace

import drjit as dr
import numpy as np

from ..jit import Array3f, Float
from .bsdf import BSDF
from .textures import COLOR3, read_as

PLUGINS = {"normalmap": ("normalmap", "flip_invalid_normals", "use_shadowing_function")}


def from_xml(ctx, props, node) -> BSDF:
    inner = props.children("bsdf")
    texture = props.colour("normalmap", 0.5, textured=True)
    flip = props.get("flip_invalid_normals", True, ("boolean",))
    shadowing = props.get("use_shadowing_function", True, ("boolean",))
    props.finish()
    if len(inner) != 1:
        raise ctx.error(node, "normalmap wraps one bsdf (as in Mitsuba)")
    if isinstance(texture, np.ndarray):
        raise ctx.error(node, "normalmap: 'normalmap' must be a <texture> (as in Mitsuba)")
    nested = ctx.bsdf(inner[0])
    if (nested.twosided or nested.masked or nested.normalmap is not None or nested.blend is not None
            or nested.texture_of("bumpmap") is not None):
        raise ctx.error(inner[0], "normalmap around twosided, mask, blendbsdf or normalmap is not supported; "
                                  "supported: normalmap around one BSDF of any other kind")
    return replace(nested, normalmap=read_as(texture, COLOR3), normalmap_flip=bool(flip), normalmap_shadowing=bool(shadowing))


def tilted_frame(m: Array3f, first: Array3f | None = None) -> tuple[Array3f, Array3f, Array3f]:
    """The tilted frame in the unperturbed frame's coordinates, from the (unnormalised) normal m: its first
    tangent `first` (default: the unperturbed x) made orthogonal to it."""
    n = dr.normalize(m)
    first = Array3f(1.0, 0.0, 0.0) if first is None else first
    s = dr.normalize(first - n * dr.dot(n, first))
    return s, dr.cross(n, s), n


def tan2(cos: Float) -> Float:
    c2 = dr.square(cos)
    return dr.maximum(1.0 - c2, 0.0) / c2


def shadowing(n: Array3f, cos_wo: Float) -> Float:
    """Estevez et al.'s shadowing term for the tilted normal n (unperturbed frame) and a direction whose cosine
    to the unperturbed normal is cos_wo: 2 / (1 + sqrt(1 + alpha^2 tan^2(wo))), alpha^2 = min(tan^2(n) / 8, 1)."""
    alpha2 = dr.minimum(0.125 * tan2(n.z), 1.0)
    return 2.0 / (1.0 + dr.sqrt(1.0 + alpha2 * tan2(cos_wo)))
