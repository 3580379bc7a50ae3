"""Mitsuba's `bumpmap`: its nested BSDF seen in a shading frame tilted by a height field, the texture's value
(eval_1) times `scale`, as Mitsuba 3.9.1 defines it. With g = scale * (dh/du, dh/dv) (the texture's gradient,
materials.textures.TextureTables.grad_1), the surface's true-length dp/du and dp/dv (a mesh's, from its texture
coordinates) have their components along the shading normal n replaced by g:

    dp/du' = dp/du + n (g_u - n . dp/du),   dp/dv' = dp/dv + n (g_v - n . dp/dv),

the tilted normal is dp/du' x dp/dv' normalised, turned to the geometric normal's side. From there it is a
normal map (materials.normalmap: `flip_invalid_normals`, nothing below either surface, Estevez et al.'s
shadowing with `use_shadowing_function`), except for the tilted frame's first tangent: Mitsuba makes the world
dp/du's components, taken as a vector of the unperturbed frame, orthogonal to the new normal (which turns
anisotropic BSDFs about the normal; isotropic ones do not see it). The dispatcher applies it to any kind
(materials.dispatch.SurfaceBSDF); only meshes carry dp/dv (other shapes refuse a bump map)."""
from __future__ import annotations

from dataclasses import replace

import drjit as dr

from ..jit import Array2f, Array3f
from .bsdf import BSDF
from .textures import MeshAttribute

PLUGINS = {"bumpmap": ("scale", "flip_invalid_normals", "use_shadowing_function")}
SHAPES = ("obj", "ply", "serialized")      # the shapes whose dp/dv the tracer computes


def from_xml(ctx, props, node) -> BSDF:
    inner = props.children("bsdf")
    textures = props.children("texture")
    scale = props.get("scale", 1.0, ("float", "integer"))
    flip = props.get("flip_invalid_normals", True, ("boolean",))
    shadowing = props.get("use_shadowing_function", True, ("boolean",))
    props.finish()
    if len(inner) != 1 or len(textures) != 1:
        raise ctx.error(node, "bumpmap wraps one bsdf and one texture (as in Mitsuba)")
    texture = ctx.texture(textures[0])
    if isinstance(texture, MeshAttribute):
        raise ctx.error(textures[0], "bumpmap of a mesh_attribute: unsupported (it has no gradient: Mitsuba 3.9.1 "
                                     "throws); supported: bitmap, checkerboard, rawconstant")
    nested = ctx.bsdf(inner[0])
    if (nested.twosided or nested.masked or nested.normalmap is not None or nested.blend is not None
            or nested.texture_of("bumpmap") is not None):
        raise ctx.error(inner[0], "bumpmap around twosided, mask, blendbsdf, normalmap or bumpmap is not supported; "
                                  "supported: bumpmap around one BSDF of any other kind")
    return replace(nested.with_texture("bumpmap", texture), bump_scale=float(scale), normalmap_flip=bool(flip),
                   normalmap_shadowing=bool(shadowing))


def bumped_normal(n: Array3f, ng: Array3f, dpdu: Array3f, dpdv: Array3f, grad: Array2f) -> Array3f:
    """The tilted normal (world space) from the shading normal n, the geometric normal ng, dp/du, dp/dv and
    the height's gradient (scale included)."""
    du = dr.fma(n, grad.x - dr.dot(n, dpdu), dpdu)
    dv = dr.fma(n, grad.y - dr.dot(n, dpdv), dpdv)
    m = dr.normalize(dr.cross(du, dv))
    return dr.select(dr.dot(ng, m) < 0, -m, m)
