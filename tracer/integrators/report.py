"""The report's branching estimator, traced level by level as a wavefront.

Every BSDF goes through the interface of tracer.materials (materials.bsdf). At every vertex whose BSDF has a
non-delta lobe (the report's diffuse vertex): N shadow rays to the lights weighted by the BSDF (eq. 10) and M
directions sampled from the BSDF (eq. 11; `uniform`: uniform over the hemisphere for BSDFs that only reflect
diffusely), each child carrying 1/M of the estimate. A BSDF whose lobes are all delta spawns one sampled ray
(a mirror: eq. 5), or every lobe where its kind lists them (glass: the reflected and the refracted ray,
weighted by F and 1 - F, eq. 7-8, 12). Light that a ray sampled from a non-delta lobe reaches is not added
again: eq. 10 counted it, so only rays leaving the camera or a delta lobe see emitters. A vertex is expanded
only while the paths it starts can still contribute at `max_depth` (the report's depth D is max_depth D + 2).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import drjit as dr

from ..geometry import SceneGeometry, Surface
from ..materials import KINDS, SurfaceBSDF
from ..materials.bsdf import DELTA, DIFFUSE_REFLECTION, LOBES, SMOOTH, BSDFSample, has_flag
from ..materials.dispatch import split_count
from ..jit import NO_PRIM, PCG32, Array2f, Array3f, Bool, Float, UInt32, segment_of
from ..sampling import seeded_rng, square_to_uniform_hemisphere
from .direct import sample_direct

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
    """Where one level's rays ended, classified: the surface found, its material kind, whether its BSDF is
    not black from the incoming ray's side (`lit`), and whether it is lit with a non-delta lobe (`smooth`:
    the report's diffuse vertex), and whether it has a delta lobe."""

    surf: Surface
    kind: UInt32
    lit: Bool
    smooth: Bool
    delta: Bool          # lit, with a delta lobe (rays it samples see emitters)


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
    bsdf = SurfaceBSDF(geo.materials, surf, wi, surf.valid)
    lit = surf.valid & bsdf.lit
    at = Vertices(surf, bsdf.kind, lit, lit & bsdf.smooth, lit & bsdf.delta)
    dr.eval(radiance, surf.p, surf.n, surf.ns, surf.prim, surf.material, at.kind, at.lit, at.smooth, at.delta)
    if surf.uv is not None:
        dr.eval(surf.uv)
    if surf.dpdu is not None:
        dr.eval(surf.dpdu)
    rays = len(wave)
    if geo.has_lights and any(KINDS[code].FLAGS & SMOOTH for code in geo.materials.kinds):
        rays += _shadow_rays(geo, surf, at.smooth, wave, settings.direct, radiance, seed)
    return _spawn(geo, at, wave, vertex, max_depth, settings, seed), rays


def _rng(n: int, seed: int, stream: int) -> PCG32:
    return seeded_rng(dr.arange(UInt32, n), (seed * 0x9E3779B97F4A7C15 + stream) % 2**64)


def _gather_surface(surf: Surface, lane: UInt32) -> Surface:
    uv = None if surf.uv is None else tuple(dr.gather(Float, c, lane) for c in surf.uv)
    dpdu = None if surf.dpdu is None else dr.gather(Array3f, surf.dpdu, lane)
    return Surface(dr.gather(Array3f, surf.p, lane), dr.gather(Array3f, surf.n, lane),
                   dr.gather(Array3f, surf.ns, lane), dr.gather(UInt32, surf.material, lane),
                   dr.gather(UInt32, surf.prim, lane), Bool(True), uv, dpdu)


def _shadow_rays(geo, surf, smooth, wave, n_direct, radiance, seed) -> int:
    """Eq. 10 at every vertex with a non-delta lobe: the mean of N shadow rays, splatted with the vertex's
    weight."""
    vertices = dr.compress(smooth)
    count = dr.width(vertices)
    if count == 0:
        return 0
    sub = _gather_surface(surf, vertices)
    bsdf = SurfaceBSDF(geo.materials, sub, -dr.gather(Array3f, wave.d, vertices), Bool(True))
    estimate = direct_estimate(geo, sub, bsdf, _rng(count, seed, 1), n_direct)
    weight = dr.gather(Array3f, wave.weight, vertices)
    dr.scatter_add(radiance, weight * estimate, dr.gather(UInt32, wave.sample, vertices))
    dr.eval(radiance)
    return count * n_direct


def direct_estimate(geo: SceneGeometry, surf: Surface, bsdf: SurfaceBSDF, rng: PCG32, n_direct: int) -> Array3f:
    """Eq. 10: (1/N) sum of f cos_x Le cos_y / (d^2 pdf) over N shadow rays, looped within each lane."""
    def body(total, i, rng):
        ds = sample_direct(geo, surf, bsdf, rng.next_float32(), rng.next_float32(), rng.next_float32(), Bool(True))
        return total + ds.value, i + 1, rng

    total, _, out = dr.while_loop((Array3f(0.0), UInt32(0), rng), lambda total, i, rng: i < n_direct, body,
                                  labels=("total", "i", "rng"))
    rng.state = out.state
    return total * (1.0 / n_direct)


def indirect_sample(bsdf: SurfaceBSDF, u1: Float, u2: Array2f, hemisphere: str) -> tuple[BSDFSample, Array3f]:
    """A direction of eq. 11 and its weight f |cos| / pdf: sampled from the BSDF, or (`uniform`) uniform over
    the hemisphere where the BSDF only reflects diffusely ((rho/pi) cos / (1/(2 pi)) for `diffuse`)."""
    bs, weight = bsdf.sample(u1, u2, Bool(True))
    if hemisphere == "uniform":
        uniform = bsdf.kinds_where(lambda m: m.FLAGS & LOBES == DIFFUSE_REFLECTION)
        wo = bsdf.to_world(square_to_uniform_hemisphere(u2.x, u2.y))
        bs.wo = dr.select(uniform, wo, bs.wo)
        weight = dr.select(uniform, bsdf.eval(wo, uniform) * dr.two_pi, weight)
    return bs, weight


def _child_counts(geo, at: Vertices, vertex: int, max_depth: int, settings: BranchingEstimator) -> UInt32:
    """Children each vertex spawns: M where its BSDF has a non-delta lobe (while they can still reach a
    light within max_depth, or see one through a delta lobe), the listed lobes of a kind that splits (two
    at glass), one elsewhere (a mirror's front), none where the ray left the scene or the BSDF is black.
    A split kind under a `mask` or in a `blendbsdf` is refused by Scene.estimator_refusals."""
    count = UInt32(1)
    for code in sorted(geo.materials.kinds):
        if split_count(code):
            count = dr.select(at.kind == code, split_count(code), count)
    m = UInt32(settings.indirect) if vertex + 2 <= max_depth else dr.select(at.delta, settings.indirect, 0)
    count = dr.select(at.smooth, m, count)
    return dr.select((at.surf.prim != NO_PRIM) & at.lit, count, 0)


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
    """The next level: M sampled directions per vertex with a non-delta lobe (while their vertex can still
    contribute within max_depth), every lobe of a kind that splits (glass's reflection and refraction), one
    sampled direction elsewhere (a mirror's reflection)."""
    parent, slot = _children(_child_counts(geo, at, vertex, max_depth, settings))
    n = dr.width(parent)
    if n == 0:
        return None
    surf = _gather_surface(at.surf, parent)
    bsdf = SurfaceBSDF(geo.materials, surf, -dr.gather(Array3f, wave.d, parent), Bool(True))
    rng = _rng(n, seed, 2)
    u1 = rng.next_float32()
    bs, factor = indirect_sample(bsdf, u1, Array2f(rng.next_float32(), rng.next_float32()), settings.hemisphere)
    new_d, delta = bs.wo, has_flag(bs.sampled_type, DELTA)
    factor = dr.select(bsdf.smooth, factor * (1.0 / settings.indirect), factor)
    split = bsdf.kinds_where(lambda m: getattr(m, "SPLIT", 0))
    if any(split_count(code) for code in geo.materials.kinds):
        wo, weight = bsdf.split(slot, split)
        new_d, factor, delta = dr.select(split, wo, new_d), dr.select(split, weight, factor), delta | split
    inf = Float(float("inf"))
    out = Wavefront(surf.p, new_d, Float(0.0), inf, dr.gather(Array3f, wave.weight, parent) * factor,
                    dr.gather(UInt32, wave.sample, parent), surf.prim, delta)
    dr.eval(out.o, out.d, out.weight, out.sample, out.skip, out.sees_emitters)
    return out
