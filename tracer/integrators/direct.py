"""What both estimators share: one shadow ray to a light (eq. 10), weighted by the surface's BSDF."""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr

from ..geometry import SceneGeometry, Surface
from ..lights import DIRECTIONAL_LIGHT, POINT_LIGHT
from ..materials import SurfaceBSDF
from ..jit import INF, NO_PRIM, Array3f, Bool, Float


@dataclass
class DirectSample:
    value: Array3f    # f * cos_x * Le * cos_y / (d^2 * pdf_area): one term of eq. 10, A = 1 / pdf_area
    pdf_light: Float  # the same sample's density in solid angle, for MIS
    pdf_bsdf: Float   # the density with which the BSDF samples its direction, for MIS
    occluded: Bool    # meaningful where the sample is lit (f cos_x > 0, cos_y > 0)


@dataclass
class LightDirection:
    """A light sample seen from a point: the light's sample, the unit direction w towards it, its distance
    (inf for lights at infinity, whose dist2 is 1) and cos_y (1 for point lights and lights at infinity)."""
    ls: object
    w: Array3f
    dist: Float
    dist2: Float
    cos_y: Float


def light_direction(geo: SceneGeometry, p: Array3f, u_select: Float, u1: Float, u2: Float) -> LightDirection:
    """A light chosen uniformly and a point drawn uniformly on it (geo.sample_light), seen from p: a point on
    an area light, a point light's position, or a direction towards the environment or of a directional
    light (at infinity: distance 1 and cos_y 1 in the formulas, the shadow ray unbounded)."""
    ls = geo.sample_light(u_select, u1, u2, p)
    to_light = ls.y - p
    dist2 = dr.squared_norm(to_light)
    if geo.has_infinite_lights:
        infinite = ls.prim == NO_PRIM if not geo.directionals else (
            (ls.prim == NO_PRIM) | (ls.prim == DIRECTIONAL_LIGHT))
        to_light = dr.select(infinite, ls.y, to_light)
        dist2 = dr.select(infinite, 1.0, dist2)
    dist = dr.sqrt(dist2)
    w = to_light / dist
    cos_y = -dr.dot(ls.n, w)
    if geo.has_infinite_lights:
        cos_y = dr.select(infinite, 1.0, cos_y)
        dist = dr.select(infinite, INF, dist)
    if geo.points:           # a point light: intensity / d^2, no surface to be seen at an angle
        cos_y = dr.select(ls.prim == POINT_LIGHT, 1.0, cos_y)
    return LightDirection(ls, w, dist, dist2, cos_y)


def light_weight(geo: SceneGeometry, ld: LightDirection) -> tuple[Float, Float]:
    """(cos_y / (d^2 pdf_area), times a spot light's falloff towards the point; the sample's density in
    solid angle for MIS, infinite for delta lights, which no other strategy finds): the light's radiance
    times the first is eq. 10's term without the BSDF."""
    ls, w = ld.ls, ld.w
    geometry_term = ld.cos_y / ld.dist2
    if geo.spots:            # a spot light's falloff in the direction of the shaded point (1 off spot lights)
        cos_cutoff, cos_beam, cutoff, inv_width = ls.cone
        cos_t = -dr.dot(ls.n, w)
        falloff = dr.select(cos_t >= cos_beam, 1.0, (cutoff - dr.safe_acos(cos_t)) * inv_width)
        geometry_term *= dr.select(cos_t > cos_cutoff, falloff, 0.0)
    pdf_light = ls.pdf_area * ld.dist2 / dr.maximum(ld.cos_y, 1e-30)
    if geo.points:           # a delta light: no other strategy can find it, its MIS weight is 1
        pdf_light = dr.select(ls.prim == POINT_LIGHT, INF, pdf_light)
    if geo.directionals:
        pdf_light = dr.select(ls.prim == DIRECTIONAL_LIGHT, INF, pdf_light)
    return geometry_term / ls.pdf_area, pdf_light


def sample_direct(geo: SceneGeometry, surf: Surface, bsdf: SurfaceBSDF, u_select: Float, u1: Float, u2: Float,
                  active: Bool) -> DirectSample:
    """One shadow ray to a light (light_direction); the BSDF evaluates the light's direction (f cos_x,
    and its own pdf there)."""
    ld = light_direction(geo, surf.p, u_select, u1, u2)
    ls, w, dist, dist2, cos_y = ld.ls, ld.w, ld.dist, ld.dist2, ld.cos_y
    f, pdf_bsdf = bsdf.eval_pdf(w, active)
    lit = active & (dr.max(f) > 0) & (cos_y > 0) & (dist2 > 0)
    geo.keep(surf, f, pdf_bsdf, ls, w, dist2, cos_y, lit)
    occluded = geo.occluded(surf.p, w, dist, surf.prim, ls.prim, lit)   # traced only where it counts
    weight, pdf_light = light_weight(geo, ld)
    value = f * ls.radiance * weight
    ok = lit & ~occluded
    return DirectSample(dr.select(ok, value, Array3f(0.0)), pdf_light, pdf_bsdf, occluded)


def power_heuristic(pdf_a: Float, pdf_b: Float) -> Float:
    """Veach's power heuristic a^2 / (a^2 + b^2), written with ratios in [0, 1] so no square overflows."""
    a_larger = pdf_a >= pdf_b
    r = dr.select(a_larger, pdf_b / pdf_a, pdf_a / pdf_b)
    r2 = r * r
    w = dr.select(a_larger, dr.rcp(1.0 + r2), r2 / (1.0 + r2))
    return dr.select((pdf_a > 0) & ~dr.isnan(w), w, 0.0)
