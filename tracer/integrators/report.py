"""The report's branching estimator, traced level by level as a wavefront.

At every diffuse vertex: N shadow rays to the area lights (eq. 10) and M rays into the hemisphere
(eq. 11), each child carrying 1/M of the estimate; a mirror spawns its reflected ray (eq. 5); glass
spawns both the reflected and the refracted ray, weighted by F and 1 - F (eq. 7-8, 12). Light that an
indirect ray reaches is not added again: eq. 10 counted it, so only rays leaving the camera or a
specular vertex see emitters. A vertex is expanded only while the paths it starts can still
contribute at `max_depth` (the report's depth D is max_depth D + 2).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import drjit as dr

from ..geometry import SceneGeometry, Surface
from ..materials import CONDUCTOR, DIELECTRIC, DIFFUSE
from ..materials.dielectric import dielectric_interface
from ..materials.fresnel import reflect
from ..jit import NO_PRIM, PCG32, Array3f, Bool, Float, UInt32, segment_of
from ..sampling import seeded_rng, square_to_cosine_hemisphere, square_to_uniform_hemisphere, to_world
from .direct import facing_normal, sample_direct

if TYPE_CHECKING:
    from ..estimators import BranchingEstimator


@dataclass
class Wavefront:
    """The rays of one level of the tree; `weight` is the product of BRDF weights and 1/M factors."""

    o: Array3f
    d: Array3f
    t_min: Float
    t_max: Float
    weight: Array3f
    sample: UInt32        # the camera sample (index in its chunk) the ray contributes to
    skip: UInt32
    sees_emitters: Bool

    def __len__(self) -> int:
        return dr.width(self.sample)


@dataclass
class Vertices:
    """Where one level's rays ended, classified: the surface found, its shading normal turned towards the
    incoming ray, its material kind, and whether it is a diffuse vertex lit from that side."""

    surf: Surface
    ns: Array3f
    kind: UInt32
    diffuse: Bool


def trace_level(geo: SceneGeometry, wave: Wavefront, vertex: int, max_depth: int, settings: BranchingEstimator,
                radiance: Float, seed: int) -> tuple[Wavefront | None, int]:
    """Intersects one level (its rays end at path vertex `vertex`), adds its emission and eq. 10 estimates
    to `radiance` (flat RGB per camera sample) and returns the next level and the number of rays traced."""
    with geo.batched():   # the level's rays are in memory: a BVH walks them by persistent lanes
        hit = geo.closest_hit(wave.o, wave.d, wave.t_min, wave.t_max, wave.skip)
    surf = geo.surface(hit)
    wi = -wave.d
    if geo.emitters:
        dr.scatter_add(radiance, wave.weight * geo.emitted(surf, wi), wave.sample, wave.sees_emitters & surf.valid)
    if vertex + 1 > max_depth:
        dr.eval(radiance)
        return None, len(wave)
    kind = geo.materials.kind(surf.material, surf.valid)
    ns, lit = facing_normal(geo, surf, wi)
    diffuse = surf.valid & lit & (kind == DIFFUSE)
    dr.eval(radiance, surf.p, surf.prim, surf.material, ns, kind, diffuse)
    rays = len(wave)
    if geo.has_lights and DIFFUSE in geo.materials.kinds:
        rays += _shadow_rays(geo, surf, ns, diffuse, wave, settings.direct, radiance, seed)
    return _spawn(geo, Vertices(surf, ns, kind, diffuse), wave, vertex, max_depth, settings, seed), rays


def _rng(n: int, seed: int, stream: int) -> PCG32:
    return seeded_rng(dr.arange(UInt32, n), (seed * 0x9E3779B97F4A7C15 + stream) % 2**64)


def _gather_surface(surf: Surface, lane: UInt32) -> Surface:
    return Surface(dr.gather(Array3f, surf.p, lane), dr.gather(Array3f, surf.n, lane),
                   dr.gather(Array3f, surf.ns, lane), dr.gather(UInt32, surf.material, lane),
                   dr.gather(UInt32, surf.prim, lane), Bool(True))


def _shadow_rays(geo, surf, ns, diffuse, wave, n_direct, radiance, seed) -> int:
    """Eq. 10 at every diffuse vertex: the mean of N shadow rays, splatted with the vertex's weight."""
    vertices = dr.compress(diffuse)
    count = dr.width(vertices)
    if count == 0:
        return 0
    sub = _gather_surface(surf, vertices)
    estimate = direct_estimate(geo, sub, dr.gather(Array3f, ns, vertices), geo.materials.albedo(sub.material, True),
                               _rng(count, seed, 1), n_direct)
    weight = dr.gather(Array3f, wave.weight, vertices)
    dr.scatter_add(radiance, weight * estimate, dr.gather(UInt32, wave.sample, vertices))
    dr.eval(radiance)
    return count * n_direct


@dr.syntax
def direct_estimate(geo: SceneGeometry, surf: Surface, ns: Array3f, albedo: Array3f, rng: PCG32,
                    n_direct: int) -> Array3f:
    """Eq. 10: (1/N) sum of f Le cos_x cos_y / (d^2 pdf) over N shadow rays, looped within each lane."""
    total, i = Array3f(0.0), UInt32(0)
    while i < n_direct:
        ds = sample_direct(geo, surf, ns, albedo, rng.next_float32(), rng.next_float32(), rng.next_float32(),
                           Bool(True))
        total += ds.value
        i += 1
    return total * (1.0 / n_direct)


def hemisphere_sample(albedo: Array3f, u1: Float, u2: Float, hemisphere: str) -> tuple[Array3f, Array3f]:
    """A direction of eq. 11 about +z and its weight f cos(theta) / pdf."""
    if hemisphere == "cosine":
        return square_to_cosine_hemisphere(u1, u2), albedo               # (rho/pi) cos / (cos/pi)
    local = square_to_uniform_hemisphere(u1, u2)
    return local, albedo * (2.0 * local.z)                               # (rho/pi) cos / (1/(2 pi))


def _child_counts(geo, at: Vertices, wave: Wavefront, vertex: int, max_depth: int,
                  settings: BranchingEstimator) -> UInt32:
    """Children each vertex spawns: M at a diffuse vertex (while they can still reach a light within
    max_depth), one at the front of a mirror, two at glass, none where the ray left the scene."""
    count = UInt32(0)
    if DIFFUSE in geo.materials.kinds and vertex + 2 <= max_depth:
        count = dr.select(at.diffuse, settings.indirect, count)
    if CONDUCTOR in geo.materials.kinds:
        count = dr.select((at.kind == CONDUCTOR) & (dr.dot(at.surf.ns, wave.d) < 0), 1, count)
    if DIELECTRIC in geo.materials.kinds:
        count = dr.select(at.kind == DIELECTRIC, 2, count)
    return dr.select(at.surf.prim != NO_PRIM, count, 0)


def _children(count: UInt32) -> tuple[UInt32, UInt32]:
    """(parent, slot) of every child, in order of parent, then slot 0 to count[parent] - 1: the parents
    that have children are compressed, each one's first child found by a prefix sum of their counts, and
    each child's parent as the segment it falls in (jit.segment_of). A lane per child, not per possible
    child: with M = 8, most vertices' eight slots would else be tested and compressed."""
    parents = dr.compress(count > 0)
    if dr.width(parents) == 0:
        return parents, parents
    count = dr.gather(UInt32, count, parents)
    end = dr.prefix_reduce(dr.ReduceOp.Add, count, exclusive=False)   # past each parent's last child
    first = end - count
    rank = segment_of(first, end[dr.width(end) - 1])   # each child's parent, by its index among `parents`
    return dr.gather(UInt32, parents, rank), dr.arange(UInt32, dr.width(rank)) - dr.gather(UInt32, first, rank)


def _spawn(geo, at: Vertices, wave: Wavefront, vertex: int, max_depth: int, settings: BranchingEstimator,
           seed: int) -> Wavefront | None:
    """The next level: M hemisphere rays per diffuse vertex (while their vertex can still reach a light
    within max_depth), the mirror's reflection, glass's reflection and refraction."""
    surf, ns, kind = at.surf, at.ns, at.kind
    parent, slot = _children(_child_counts(geo, at, wave, vertex, max_depth, settings))
    n = dr.width(parent)
    if n == 0:
        return None
    k = dr.gather(UInt32, kind, parent)
    p = dr.gather(Array3f, surf.p, parent)
    d = dr.gather(Array3f, wave.d, parent)
    n_s = dr.gather(Array3f, ns, parent)
    weight = dr.gather(Array3f, wave.weight, parent)
    new_d, factor = Array3f(0.0), Array3f(0.0)
    rng = _rng(n, seed, 2)
    if DIFFUSE in geo.materials.kinds:
        is_diffuse = k == DIFFUSE
        albedo = geo.materials.albedo(dr.gather(UInt32, surf.material, parent), is_diffuse)
        local, f = hemisphere_sample(albedo, rng.next_float32(), rng.next_float32(), settings.hemisphere)
        new_d = dr.select(is_diffuse, to_world(local, n_s), new_d)
        factor = dr.select(is_diffuse, f * (1.0 / settings.indirect), factor)
    if CONDUCTOR in geo.materials.kinds:
        is_mirror = k == CONDUCTOR
        n_mirror = dr.gather(Array3f, surf.ns, parent)
        new_d = dr.select(is_mirror, reflect(d, n_mirror), new_d)
        weight_mirror = geo.materials.conductor_weight(dr.gather(UInt32, surf.material, parent), -dr.dot(n_mirror, d), is_mirror)
        factor = dr.select(is_mirror, weight_mirror, factor)
    if DIELECTRIC in geo.materials.kinds:
        is_glass = k == DIELECTRIC
        int_ior, ext_ior = geo.materials.iors(dr.gather(UInt32, surf.material, parent), is_glass)
        fr, reflected, refracted, scale = dielectric_interface(d, dr.gather(Array3f, surf.ns, parent), int_ior, ext_ior)
        is_reflection = slot == 0
        new_d = dr.select(is_glass, dr.select(is_reflection, reflected, refracted), new_d)
        factor = dr.select(is_glass, Array3f(dr.select(is_reflection, fr, (1.0 - fr) * scale)), factor)
    specular = k != DIFFUSE
    inf = Float(float("inf"))
    out = Wavefront(p, new_d, Float(0.0), inf, weight * factor, dr.gather(UInt32, wave.sample, parent),
                    dr.gather(UInt32, surf.prim, parent), specular)
    dr.eval(out.o, out.d, out.weight, out.sample, out.skip, out.sees_emitters)
    return out
