"""What a shape kind provides to the scene's kernels; tracer.geometry assembles one ShapeSet per kind.

A scene's primitives are numbered kind after kind in the order of tracer.shapes.KINDS; a set holds the
shapes of one kind as primitives [base, base + count). The host side gives the rows of the scene's
per-primitive tables; the kernel side intersects rays, corrects normals and samples points on emitters.
Kernels are traced from the scene: a kind the scene lacks adds no instruction, and a shape tested one by one
adds its test. The shapes' numbers (their primitives, positions, sizes) enter the kernels as run-time
constants (jit.opaque_u32, opaque_vec3), not literals: a scene of the same kinds and the same shapes tested one
by one runs the kernels of another, from Dr.Jit's cache.
"""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import drjit as dr
import numpy as np

from ..jit import INF, Array3f, Bool, Float, UInt32, opaque_u32

if TYPE_CHECKING:
    from ..materials import BSDF


@dataclass
class ShapeArgs:
    """What every <shape> gives, read by the loader before the kind's own parameters (a kind's `from_xml`
    reads those and builds the shape)."""

    node: object                                   # the XML element, for errors
    kind: str                                      # the plugin name
    to_world: np.ndarray
    flip: bool                                     # flip_normals
    bsdf: BSDF
    radiance: tuple[float, float, float] | None    # an area emitter's
    name: str
    sampling_weight: float = 1.0                   # an area emitter's (tracer.lights.choice)


class ShapeSet:
    kind: type            # the host dataclass of the shapes it holds
    planar = False        # rectangles and triangles: hit points are kept inside by their frames (shapes.planar)
    bvh = None            # a shapes.bvh.BVHKernel over the primitives that `candidates` leaves out

    def __init__(self, shapes: list, base: int):
        self.shapes, self.base = list(shapes), base

    # ---- host side ---------------------------------------------------------------------------------
    @property
    def count(self) -> int:
        """The set's primitives."""
        return len(self.shapes)

    def shape_primitives(self) -> Iterator[tuple[object, int, int]]:
        """(shape, first primitive, primitive count) of each shape."""
        for i, s in enumerate(self.shapes):
            yield s, self.base + i, 1

    def prim_range(self, shape) -> tuple[int, int] | None:
        """The primitive indices [lo, hi) of `shape`, None if it is not in this set."""
        for s, lo, n in self.shape_primitives():
            if s is shape:
                return lo, lo + n
        return None

    def walked_by_shadow_rays(self, occluders: set[int]) -> bool:
        """Whether shadow rays walk the set's BVH, given the primitives that may block one (all BVHs but
        those whose primitives were all culled, geometry._possible_occluders)."""
        return self.bvh is not None

    def normals(self) -> np.ndarray:
        """(count, 3) geometric normals of flat primitives (zero where the kernel computes them)."""
        return np.zeros((self.count, 3))

    def frames(self) -> np.ndarray:
        """(count, 3, 3) origin and edge vectors of planar primitives."""
        raise NotImplementedError

    def culling_planes(self) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """(primitive, point, normal) of the primitives that shadow rays may leave out when the whole scene
        lies on one side of their plane (geometry._possible_occluders); curved shapes have none."""
        return []

    def sides(self, p0: np.ndarray, n: np.ndarray) -> np.ndarray:
        """Signed distances to the plane (p0, n) of points whose hull holds the set's shapes."""
        raise NotImplementedError

    def side_bounds(self, p0: np.ndarray, n: np.ndarray) -> tuple[float, float]:
        """A lower and an upper bound on sides(p0, n) (here its least and greatest value)."""
        side = self.sides(p0, n)
        return side.min(), side.max()

    def describe(self) -> str:
        raise NotImplementedError

    # ---- kernel side -------------------------------------------------------------------------------
    @cached_property
    def first(self) -> UInt32:
        """The set's first primitive (base) as a run-time constant: its primitive k is first + k."""
        return opaque_u32(self.base)

    @cached_property
    def size(self) -> UInt32:
        """The set's primitive count as a run-time constant."""
        return opaque_u32(self.count)

    def prim(self, k: int) -> UInt32:
        """The primitive number of the set's primitive k (an int), from the run-time constant `first`."""
        return self.first + k

    def local(self, prim: UInt32) -> UInt32:
        """prim's index in the set: k for its primitive k, a number not below count for any other (unsigned)."""
        return prim - self.first

    def owns(self, prim: UInt32) -> Bool:
        """Whether prim is one of the set's primitives."""
        return self.local(prim) < self.size

    def candidates(self, o: Array3f, d: Array3f, t_min, skip: UInt32, target: UInt32 | None,
                   only: set[int] | None) -> Iterator[tuple[int, Float, Float | None, Float | None]]:
        """Per primitive (of `only`, if given): (index, t, b1, b2) of its hit, t = inf on a miss or for the
        excluded primitives skip and target; the index a UInt32 (first + k); (b1, b2): local coordinates where
        the kind has them."""
        raise NotImplementedError

    def local_ends(self, skip: UInt32, target: UInt32 | None) -> tuple[UInt32, UInt32 | None]:
        """skip and target as the set's local indices (`local`), for `exclude`."""
        return self.local(skip), None if target is None else self.local(target)

    def normal(self, prim: UInt32, p: Array3f, n: Array3f) -> Array3f:
        """The geometric normal at p where prim is one of the set's (n elsewhere)."""
        return n

    def uv(self, prim: UInt32, valid, p: Array3f, b1: Float, b2: Float,
           uv: tuple[Float, Float]) -> tuple[Float, Float]:
        """Texture coordinates at the hit (p, local coordinates b1, b2) where prim is one of the set's, as
        Mitsuba's shape of the kind computes them (`uv` elsewhere); only traced in scenes with textures."""
        return uv

    def tangent(self, prim: UInt32, valid, p: Array3f, b1: Float, b2: Float, dpdu: Array3f) -> Array3f:
        """The direction of the surface's dp/du at the hit where prim is one of the set's (dpdu elsewhere), as
        Mitsuba's shape of the kind computes it (its length may differ): it orients the shading frame's first
        tangent (anisotropic roughness follows it). Only traced in scenes whose materials depend on it."""
        return dpdu

    def sample(self, shape, lo: int, u1: Float, u2: Float, geo) -> tuple[Array3f, Array3f, UInt32]:
        """A point uniform in area on an emitting `shape` (primitives from lo): (point, normal, primitive)."""
        raise NotImplementedError(f"{type(shape).__name__} shapes do not emit")


def exclude(t: Float, k: int, skip: UInt32, target: UInt32 | None) -> Float:
    """t, or inf for a set's primitive k when it is the one a ray leaves (skip) or the light it aims at
    (target); skip and target as the set's local indices (ShapeSet.local)."""
    out = skip == k
    if target is not None:
        out |= target == k
    return dr.select(out, INF, t)
