"""The bounding volume hierarchy's build: a binary tree over triangles, on the host (tracer.shapes.bvh
encodes it for the kernels and walks it).

The tree is built top-down with the surface area heuristic (SAH: MacDonald and Booth, "Heuristics for ray
tracing using space subdivision", The Visual Computer 6(3), 1990), binned as in Wald, "On fast construction
of SAH-based bounding volume hierarchies" (IEEE Symposium on Interactive Ray Tracing, 2007) and pbrt-v4:
each node's triangles are cut across one of the three axes, between BINS bins of equal counts along it,
where the expected cost of a ray's walk through the children is least over all three axes' candidates (as
in Embree's binned builder; pbrt-v4 bins along the axis of the centroids' largest extent alone, which took
4 to 7% more walk steps per ray on the bench's meshes), and a node of up to LEAF_SIZE triangles stays a
leaf where that is cheaper than splitting it. The phases over the triangles (their keys and boxes, the
levels' splits and list partitions, the leaves' boxes) are compiled (native/bvh_native.cpp, a C++ extension
built with nanobind and scikit-build-core; `pip install ./native`), with NumPy for the sorts and the
bottom-up boxes: at 997,534 triangles the first build in a fresh process took 0.19 times the CPU time of
the earlier Dr.Jit kernels, with the same tree. The extension rounds as written (float32 boxes, float64
areas and costs, no fused multiply-add, min/max keeping the second of equal values), so the tree is the
same, bit for bit, on every machine.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import cached_property

import drjit as dr
import numpy as np

from ..errors import BackendError
from ..jit import CORES

LEAF_SIZE = 7      # most triangles in a leaf (a leaf's link holds the count in 3 bits)
TRAVERSAL_COST = 1.0   # the SAH's cost of a walk's step through an inner node, in triangle tests (see _native)
BINS = 32          # SAH candidate splits per node: between bins of equal triangle counts
SAMPLES = 65536    # triangles whose boxes stand for a node's bins (all of a smaller node's)
# 32 bins of every triangle below 65,536 (from 16 bins of 256 sampled triangles, whose boxes understate
# the bins'): on the rays of a render of mitsuba-data's bsdf_conductor_gold (61,600 triangles) the SAH cost
# fell from 32.4 to 25.9 and the batched walks took 0.87 of the time (bunny of shape_ply_bunny: 0.80;
# the project's 250,000-triangle mesh scene: no change beyond noise), the build the same time (997,534
# triangles: 0.83 s either way; its SAH cost 71.9 to 69.1)


@dataclass
class Tree:
    """Nodes in creation order (parents before children); a leaf has left = right = -1."""
    lo: np.ndarray      # (nodes, 3) box min corner
    hi: np.ndarray      # (nodes, 3) box max corner
    left: np.ndarray    # (nodes,) first child
    right: np.ndarray   # (nodes,) second child
    first: np.ndarray   # (nodes,) a leaf's first triangle slot (in `order`)
    count: np.ndarray   # (nodes,) a leaf's triangles, 0 for an inner node
    order: np.ndarray   # (triangles,) original triangle index of each leaf slot
    levels: list        # node index ranges (begin, end) of each depth, root first

    @cached_property
    def inner(self) -> np.ndarray:
        return self.left >= 0

    @cached_property
    def subtree(self) -> np.ndarray:
        """(nodes,) nodes in each node's subtree, itself included."""
        size = np.ones(len(self.left), np.int64)
        for begin, end in self.levels[::-1]:   # bottom-up
            node = begin + np.flatnonzero(self.inner[begin:end])
            size[node] += size[self.left[node]] + size[self.right[node]]
        return size


def build(vertices: np.ndarray, faces: np.ndarray | None = None) -> Tree:
    """SAH BVH over the triangles `faces` (n, 3) of `vertices` (m, 3), or, without faces, over triangles
    given as (n, 3, 3) vertices.

    Each node's triangles are split by a plane across an axis (centroids rounded to float32), where the
    surface area heuristic's cost is least over the three axes (bvh_native.cpp's axis_split: the cost
    C + (A_l n_l + A_r n_r) / A, see _native below); a node becomes a leaf where that costs less than
    splitting it and it holds at most LEAF_SIZE triangles. The triangle ids are sorted by centroid once per
    axis (NumPy, _sorted_lists); each level then splits all its nodes, partitioning every axis's list
    stably into the children's parts (linear time, no sort per level), so that each list stays sorted
    within every node (build_nodes). Boxes are taken over the leaves' triangles (leaf_boxes), then merged
    bottom-up (NumPy)."""
    native = _native()
    vertices, faces = corners(vertices, faces)
    real = np.float32 if vertices.dtype == np.float32 else np.float64
    vertices, faces = np.ascontiguousarray(vertices, real), np.ascontiguousarray(faces, np.int64)
    n = len(faces)
    boxes, bits = np.empty((n, 6), np.float32), np.empty((3, n), np.uint32)
    native.triangle_keys(vertices, faces, boxes, bits)
    ids = _sorted_lists(bits)
    left, right, first, count, levels = native.build_nodes(ids, boxes, LEAF_SIZE, BINS, SAMPLES, TRAVERSAL_COST, CORES)
    levels = [(int(b), int(e)) for b, e in levels]
    order = ids[0].astype(np.int64)
    leaf = np.flatnonzero(left < 0)    # indices, not masks: NumPy's masked writes to rows take longer
    leaf_lo, leaf_hi = np.full((len(leaf), 3), np.inf, real), np.full((len(leaf), 3), -np.inf, real)
    native.leaf_boxes(vertices, faces, order, first[leaf], count[leaf], leaf_lo, leaf_hi)
    lo, hi = np.empty((len(left), 3), real), np.empty((len(left), 3), real)
    lo[leaf], hi[leaf] = leaf_lo, leaf_hi
    for (b, e), (next_b, next_e) in zip(levels[-2::-1], levels[:0:-1]):   # bottom-up
        inner = b + np.flatnonzero(left[b:e] >= 0)    # their children, in pairs, are the next level's nodes
        lo[inner] = np.minimum(lo[next_b:next_e:2], lo[next_b + 1:next_e:2])
        hi[inner] = np.maximum(hi[next_b:next_e:2], hi[next_b + 1:next_e:2])
    return Tree(lo, hi, left, right, first, count, order, levels)


def _native():
    """The compiled build phases (native/bvh_native.cpp, a nanobind extension; `pip install ./native`).

    triangle_keys: each triangle's box (float32 -lo, hi) and per axis its sort key, the bits of its
    centroid (lo + hi) / 2 rounded to float32, mapped to an order-preserving unsigned integer (-0.0 as 0.0).
    build_nodes: the tree level by level. A node [b, b + s) of sorted slots (s >= 2) is split by the binned
    surface area heuristic (MacDonald and Booth 1990; Wald 2007): along each axis its list is cut into
    min(s, BINS) bins of equal counts, a bin's box that of SAMPLES / BINS triangles evenly spread over it
    (all of them in a node of up to SAMPLES), and a split lies between two bins. Its cost, in triangle
    tests, is C + (A_l n_l + A_r n_r) / A: the node's own step C (TRAVERSAL_COST), then each child's
    triangles weighted by the chance that a ray through the node's box enters the child's (surface areas
    A); a leaf costs its triangles. The split is the least costly of the three axes' (the first of equal
    costs: x, then y, then z); near-equal costs go to the more even split (so that equal triangles do not
    make a chain). C = 1: the walk (shapes.bvh) takes a step per row, two binary levels, and a step per
    triangle of a leaf, so a binary node costs about half a triangle. Measured against C = 2 on the rays of
    1-spp renders replayed through both trees (batched walks, one thread, fastest of 5, interleaved):
    mitsuba-data's bsdf_conductor_gold 0.93 of the walks' time, shape_ply_bunny 0.93, matpreview 0.93; the
    bench's 997,534-triangle mesh scene (8 spp) 0.99, with 1.6 times the nodes (mean leaf 1.85 against
    2.94 triangles); C = 0.75 and 0.5 within 2% of C = 1; C = 3 took 1.08 times C = 2's time on gold.
    Every axis's list is then partitioned stably, left child first. Nodes of a level are spread over
    threads where the level is large.
    leaf_boxes: (lo, hi) of the leaves' triangles (slots [first, first + count) of the first list).
    Compiled without fused multiply-add or fast math: boxes float32 (their maxima exact), areas and costs
    float64, each operation rounded as written, min/max keeping the second of equal values, so the tree is
    the same, bit for bit, on every machine; the constants are passed from here."""
    try:
        import bvh_native
    except ImportError as e:
        raise BackendError(f"the BVH build needs its compiled extension, which is not installed ({e}): "
                           "run `pip install ./native` from the repository (scripts/setup.sh does)") from None
    return bvh_native


def _sorted_lists(bits: np.ndarray) -> np.ndarray:
    """(3, n) uint32: per axis, the triangles sorted by their keys `bits` (3, n); ties by the next axis's
    order. One sort of 64-bit words per list: the key above the tie."""
    n = bits.shape[1]
    position = np.arange(n, dtype=np.uint64)

    def sort(a, after=None):   # the triangles (in `after`'s order, or by index) sorted by centroid along a
        key = (bits[a] if after is None else bits[a][after]).astype(np.uint64)
        key <<= 32
        key |= position
        key.sort()
        order = key.astype(np.uint32)
        return order if after is None else after[order]

    # NumPy's sorts and element-wise passes leave the interpreter lock: an axis a thread
    with ThreadPoolExecutor(min(CORES, 3)) as pool:
        by_index = list(pool.map(sort, range(3)))   # per axis: sorted by centroid, ties by index
        return np.stack(list(pool.map(lambda a: sort(a, by_index[(a + 1) % 3]), range(3))))


def corners(vertices: np.ndarray, faces: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (m, 3), faces (n, 3)) of triangles given as such, or, faces None, as (n, 3, 3) vertices."""
    if faces is None:
        return vertices.reshape(-1, 3), np.arange(vertices.shape[0] * 3).reshape(-1, 3)
    return vertices, faces


def sah_cost(tree: Tree) -> float:
    """The tree's expected cost of a walk, in triangle tests, of a ray through its root box, by the surface
    area heuristic (MacDonald and Booth 1990; pbrt-v4's BVH cost): TRAVERSAL_COST per inner node and a
    leaf's triangles, each weighted by the chance that such a ray enters the node's box (its surface area
    over the root's). The measure of a tree's quality that the build minimizes node by node; the root's box has
    an area."""
    extent = tree.hi.astype(np.float64) - tree.lo
    area = 2 * (extent[:, 0] * extent[:, 1] + extent[:, 1] * extent[:, 2] + extent[:, 2] * extent[:, 0])
    return float(np.where(tree.inner, TRAVERSAL_COST, tree.count) @ area / area[0])


def depth_first(tree: Tree) -> np.ndarray:
    """Each node's position in a depth-first (left child first) order of the tree."""
    size = tree.subtree
    position = np.zeros(len(tree.left), np.int64)
    for begin, end in tree.levels:   # top-down
        node = begin + np.flatnonzero(tree.inner[begin:end])
        position[tree.left[node]] = position[node] + 1
        position[tree.right[node]] = position[node] + 1 + size[tree.left[node]]
    return position



def select_min(a, b):
    """min(a, b) for operands that are never NaN, as one instruction (dr.minimum also orders NaNs and
    signed zeros, in several)."""
    return dr.select(a < b, a, b)


def select_max(a, b):
    """max(a, b) for operands that are never NaN, as one instruction."""
    return dr.select(a > b, a, b)
