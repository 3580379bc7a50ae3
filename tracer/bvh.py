"""A bounding volume hierarchy over triangles: built on the host, traversed in the kernel.

Nodes are stored in depth-first order with a "miss" link to the node that follows their subtree, so
the kernel walks the tree without a stack (a threaded BVH): a hit box descends to node + 1, a missed
box or a finished leaf jumps to its miss link; a leaf's triangles are tested in a branch that a packet of
lanes skips when none of them is at a leaf (without it, every step paid for a leaf test). Splits are at the median centroid along the longest
axis; leaves hold up to LEAF_SIZE triangles. (An ordered traversal with a per-lane stack in Dr.Jit's
local memory read unwritten stack slots on the LLVM backend; the stackless walk needs no stack.)
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from . import intersect
from .jit import INF, Array3f, Bool, Float, UInt32

LEAF_SIZE = 2


@dataclass
class FlatBVH:
    bounds: np.ndarray   # (nodes, 2, 3): min and max corner
    miss: np.ndarray     # (nodes,) index of the node after this subtree
    first: np.ndarray    # (nodes,) first triangle of a leaf (in `order`)
    count: np.ndarray    # (nodes,) triangles in a leaf, 0 for an inner node
    order: np.ndarray    # (triangles,) original triangle index of each leaf slot


def build(tri_vertices: np.ndarray) -> FlatBVH:
    """Median-split BVH over triangles given as (n, 3, 3) vertices."""
    lo, hi = tri_vertices.min(axis=1), tri_vertices.max(axis=1)
    centroid = (lo + hi) / 2
    order = np.arange(len(tri_vertices))
    bounds, miss, first, count = [], [], [], []

    def node(begin: int, end: int) -> None:
        ids = order[begin:end]
        index = len(bounds)
        bounds.append(np.stack([lo[ids].min(0), hi[ids].max(0)]))
        miss.append(0)
        if end - begin <= LEAF_SIZE:
            first.append(begin)
            count.append(end - begin)
        else:
            first.append(0)
            count.append(0)
            c = centroid[ids]
            axis = int(np.argmax(c.max(0) - c.min(0)))
            mid = (end - begin) // 2
            order[begin:end] = ids[np.argpartition(c[:, axis], mid)]
            node(begin, begin + mid)
            node(begin + mid, end)
        miss[index] = len(bounds)

    node(0, len(tri_vertices))
    return FlatBVH(np.asarray(bounds), np.asarray(miss, np.uint32), np.asarray(first, np.uint32),
                   np.asarray(count, np.uint32), order)


class BVHKernel:
    """The BVH's arrays on the device and its traversal; triangle ids are offset by `prim_base`."""

    def __init__(self, tri_vertices: np.ndarray, prim_base: int):
        flat = build(tri_vertices)
        v = tri_vertices[flat.order]
        self.n_nodes = len(flat.miss)
        self.bounds = Float(flat.bounds.ravel())
        self.miss, self.first, self.count = UInt32(flat.miss), UInt32(flat.first), UInt32(flat.count)
        self.v0 = Float(v[:, 0].ravel())
        self.e1 = Float((v[:, 1] - v[:, 0]).ravel())
        self.e2 = Float((v[:, 2] - v[:, 0]).ravel())
        self.prim = UInt32(flat.order.astype(np.uint32) + prim_base)

    def _box(self, node: UInt32, o: Array3f, inv_d: Array3f, t_max: Float) -> Bool:
        """Slab test of the node's box against the ray segment [0, t_max]."""
        b0 = dr.gather(Array3f, self.bounds, node * 2)
        b1 = dr.gather(Array3f, self.bounds, node * 2 + 1)
        t0, t1 = (b0 - o) * inv_d, (b1 - o) * inv_d
        t_near = dr.max(dr.minimum(t0, t1))
        t_far = dr.min(dr.maximum(t0, t1))
        return (t_near <= t_far) & (t_far >= 0) & (t_near <= t_max)

    def _leaf(self, node, count, o, d, t_min, t_best, skip, target):
        """The nearest hit among a leaf's triangles: (t, slot, b1, b2), t = inf if none."""
        first = dr.gather(UInt32, self.first, node)
        t_hit, slot, u_hit, v_hit = Float(INF), UInt32(0), Float(0), Float(0)
        for k in range(LEAF_SIZE):
            active = k < count
            s = first + k
            prim = dr.gather(UInt32, self.prim, s, active)
            active &= prim != skip
            if target is not None:
                active &= prim != target
            t, b1, b2 = intersect.ray_triangle(
                o, d, dr.gather(Array3f, self.v0, s, active), dr.gather(Array3f, self.e1, s, active),
                dr.gather(Array3f, self.e2, s, active), t_min, t_best)
            closer = active & (t < t_hit)
            t_hit, slot = dr.select(closer, t, t_hit), dr.select(closer, s, slot)
            u_hit, v_hit = dr.select(closer, b1, u_hit), dr.select(closer, b2, v_hit)
        return t_hit, slot, u_hit, v_hit

    @dr.syntax
    def closest_hit(self, o: Array3f, d: Array3f, t_min, t_best: Float, prim: UInt32, b1: Float, b2: Float,
                    skip: UInt32):
        """Improves (t_best, prim, b1, b2) with the BVH's triangles."""
        inv_d = dr.rcp(d)
        node = UInt32(0)
        while node < self.n_nodes:
            box = self._box(node, o, inv_d, t_best)
            count = dr.gather(UInt32, self.count, node)
            leaf = count > 0
            if box & leaf:   # a symbolic branch: skipped when no lane of a packet is at a leaf
                t, slot, u, v = self._leaf(node, count, o, d, t_min, t_best, skip, None)
                closer = t < t_best
                t_best = dr.select(closer, t, t_best)
                prim = dr.select(closer, dr.gather(UInt32, self.prim, slot, closer), prim)
                b1, b2 = dr.select(closer, u, b1), dr.select(closer, v, b2)
            node = dr.select(box & ~leaf, node + 1, dr.gather(UInt32, self.miss, node))
        return t_best, prim, b1, b2

    @dr.syntax
    def occluded(self, o: Array3f, d: Array3f, dist: Float, skip: UInt32, target: UInt32) -> Bool:
        """Whether a BVH triangle other than skip and target lies on o + t d, 0 < t < dist."""
        inv_d = dr.rcp(d)
        node, blocked = UInt32(0), Bool(False)
        while (node < self.n_nodes) & ~blocked:
            box = self._box(node, o, inv_d, dist)
            count = dr.gather(UInt32, self.count, node)
            leaf = count > 0
            if box & leaf:
                t, slot, u, v = self._leaf(node, count, o, d, 0.0, dist, skip, target)
                blocked = t < dist
            node = dr.select(box & ~leaf, node + 1, dr.gather(UInt32, self.miss, node))
        return blocked
