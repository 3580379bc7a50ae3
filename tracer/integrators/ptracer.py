"""Mitsuba 3's `ptracer` (a particle tracer: paths start at the lights and each vertex is connected to the
camera) rendered with the path estimator, where both estimate the same image.

A light path ends at the camera by a connection: the BSDF evaluated towards the camera at a vertex, a
shadow ray, the camera's importance (Veach 1997, ch. 10; src/integrators/ptracer.cpp). Its depth counts
as `path`'s: the vertex reached by the k-th segment from the light is connected when k < max_depth, giving
a path of k + 1 segments; lights seen directly (one segment) are connected when max_depth != 0, as `path`
sees them at max_depth >= 1. Russian roulette changes the noise, not the expectation. So the expected
image is `path`'s at the same max_depth, except where the light tracer cannot form or weights a path
otherwise; `differences` lists those a scene holds, conservatively from its content:
- a delta lobe or a null pass-through (smooth conductor, dielectric, plastic, thindielectric, null,
  polarizer, a mask): its eval towards the camera is 0, so the camera never sees a mirror, glass or what
  lies behind a null surface (the shadow ray to the camera is blocked by it);
- transmission (rough dielectrics, principled): refraction transported as importance, not checked here;
- normalmap and bumpmap: the light tracer drops a vertex whose shading and geometric normals disagree on
  a direction's side (its guard against light leaks), `path` does not;
- an environment (constant, envmap): seen directly through a point sampled 2 scene radii away;
- a sensor other than a pinhole `perspective`: Mitsuba 3.9.1's thinlens and orthographic sensors cannot
  be connected to (no sample_direction);
- an emitting mesh with interpolated normals: the light tracer weights a point sampled on it (seen
  directly, or emitting a ray) by the cosine to the interpolated normal, `path` sees it by its geometry;
- a film crop window: the light tracer's splats into it are not checked against `path`'s;
- a reconstruction filter other than `box`: a splat's filter weights are normalized over its footprint,
  including pixels outside the film, where `path` divides each pixel by the weights of its own samples,
  so pixels within the filter's radius of the border (and, by the discrete sum, all) differ.
"""
from __future__ import annotations

import numpy as np

from ..materials.bsdf import DELTA, DIFFUSE_TRANSMISSION, GLOSSY_TRANSMISSION, NULL
from ..materials.dispatch import KINDS, KIND_CODE

NOTE = ("ptracer (a light tracer): rendered with the path estimator, which estimates the same image with "
        "other noise (tracer/integrators/ptracer.py)")


def _parts(bsdf) -> list:
    """The material, its back and its blend's second material, each with theirs."""
    out = [bsdf]
    for other in (bsdf.back, bsdf.blend[1] if bsdf.blend else None):
        if other is not None:
            out += _parts(other)
    return out


def passes_through(bsdf) -> bool:
    """Whether rays pass through the material somewhere (a null lobe: null, polarizer, thindielectric's
    transmission; a mask), it, its back or its blend's second material."""
    return any(KINDS[KIND_CODE[p.kind]].FLAGS & NULL or p.masked for p in _parts(bsdf))


def _bsdf_difference(bsdf) -> str | None:
    for part in _parts(bsdf):
        flags = KINDS[KIND_CODE[part.kind]].FLAGS
        if flags & DELTA:
            return f"bsdf '{part.kind}' has a delta lobe or a null pass-through, which a light tracer cannot " \
                   "connect to the camera (mirrors, glass and what lies behind them are missing from its image)"
        if part.masked:
            return "a mask's pass-through blocks a light tracer's connection to the camera"
        if flags & (DIFFUSE_TRANSMISSION | GLOSSY_TRANSMISSION):
            return f"bsdf '{part.kind}' transmits: the light tracer's refraction is not checked against path's"
        if part.normalmap is not None or part.texture_of("bumpmap") is not None:
            return "a normalmap or bumpmap: the light tracer drops vertices whose shading and geometric normals " \
                   "disagree, path does not"
    return None


def _curved_normals(mesh) -> bool:
    """Whether the mesh's interpolated normals differ from its triangles' (a flat mesh's do not)."""
    if mesh.normals is None:
        return False
    corners = mesh.vertices[mesh.faces]
    face = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    face /= np.maximum(np.linalg.norm(face, axis=1, keepdims=True), 1e-30)
    return not np.allclose(mesh.normals[mesh.faces], face[:, None, :], atol=1e-5)


def differences(scene) -> list[str]:
    """Why Mitsuba's ptracer image of `scene` is not path's, one reason each (empty: the same image)."""
    out = []
    cam = scene.camera
    if cam is not None and (cam.projection != "perspective" or cam.aperture_radius > 0):
        kind = "orthographic" if cam.projection == "orthographic" else "thinlens"
        out.append(f"a {kind} sensor: Mitsuba 3.9.1's ptracer connects only to a perspective sensor")
    if cam is not None and cam.rfilter.kind != "box":
        out.append(f"rfilter '{cam.rfilter.kind}': a light tracer's splats are normalized over pixels outside the "
                   "film too, so its image is not path's near the border; ptracer is rendered with the box filter")
    if cam is not None and cam.cropped:
        out.append("a film crop window: the light tracer's splats into a crop window are not checked against path's")
    if scene.environment is not None or scene.envmap is not None:
        kind = "constant" if scene.environment is not None else "envmap"
        out.append(f"emitter '{kind}': an environment seen directly by a light tracer is not checked against path's")
    lamp = next((m for m in scene.meshes if m.radiance is not None and _curved_normals(m)), None)
    if lamp is not None:
        out.append(f"the emitting mesh '{lamp.name}' has interpolated normals: a light tracer weights its emission "
                   "by their cosine where path sees it by the triangles' own (face_normals true is the same image)")
    for bsdf in scene.bsdfs:
        reason = _bsdf_difference(bsdf)
        if reason is not None:
            out.append(reason)
            break
    return out
