"""A bounding volume hierarchy over triangles: built on the host, traversed in the kernel.

The tree is built top-down with the surface area heuristic (SAH: MacDonald and Booth, "Heuristics for ray
tracing using space subdivision", The Visual Computer 6(3), 1990), binned as in Wald, "On fast construction
of SAH-based bounding volume hierarchies" (IEEE Symposium on Interactive Ray Tracing, 2007) and pbrt-v4:
each node's triangles are cut across the axis of their centroids' largest extent, between BINS bins of
equal counts, where the expected cost of a ray's walk through the children is least, and a node of up to
LEAF_SIZE triangles stays a leaf where that is cheaper than splitting it. All the nodes of a level are
split at once, vectorised with NumPy.

The kernel walks a 4-wide tree (as Embree's and pbrt's wide BVHs, collapsed from the binary one): a row
holds the boxes of an inner node's grandchildren, or of a child that is a leaf, so its children are 2 to
4 and the tree half as deep. It walks it depth first, nearest child first: each step a lane either tests
the boxes of a row's child slots still to visit or one triangle of a leaf (the triangle test in a branch
that a packet of lanes skips when none of them is at a leaf; testing a node's child leaves whole within
its step cost a packet every triangle test of any lane's leaves in most steps). From a row it goes on to
the nearest child whose box it enters; if it entered one other, it pushes that child, and if several, it
pushes the row back with those slots left in its link's mask, to be tested again, against the then
closest hit, when popped. So each row has at most one entry on the per-lane stack: its size is the wide
tree's depth. The shrinking closest hit culls the far boxes. The stack lives in registers, one loop
variable per level (a push shifts them down, a pop up), since Dr.Jit 1.5's local memory
(dr.alloc_local) lost pushed entries on the LLVM backend.

A row is sixteen 32-bit words (64 bytes, one cache line), gathered in one packet load: per child slot,
its box's corners as 16-bit coordinates on a grid over the root box, rounded outwards by a further grid
step (a margin far above the slab test's rounding; the test turns each coordinate into a ray parameter
with one fma), and a link: a row's index * 16 + the mask of its full slots, or for a leaf its first
triangle * 8 + count with the top bit set; an empty slot is all zeros. A triangle is twelve values: v0,
its primitive id, e1, 0, e2, 0 (the id stored as the bits of a float). Both tables start on a cache
line: from memory it finds unaligned, Dr.Jit gathers value by value instead of in packets.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import drjit as dr
import numpy as np

from .triangle import ray_triangle
from ..jit import BACKEND, INF, PRECISION, Array3f, ArrayXf, ArrayXu, Bool, Float, UInt32, UInt64

LEAF_SIZE = 4      # most triangles in a leaf (at most 7: a leaf's link holds the count in 3 bits)
BINS = 16          # SAH candidate splits per node: between bins of equal triangle counts
SAMPLES = 256      # triangles whose boxes stand for a node's bins (all of a smaller node's)
GRID = 0xFFFF          # largest grid coordinate of a node's box corner
LEAF_BIT = 1 << 31     # marks a leaf's link word
WIDTH = 4              # children per node of the kernel's table
MASK = (1 << WIDTH) - 1    # an inner link's low bits: the row's child slots still to visit
BATCH_LANES = 4096     # persistent lanes of a batched walk (_walk_batch)
REFILL_PERIOD = 2      # a batched walk's done lanes take new rays every this many steps
BATCHED_WALKS = BACKEND == "llvm"   # persistent lanes measured on the CPU's SIMD packets; a GPU keeps the walk in-kernel
_FLOAT, _UINT = (np.float64, np.uint64) if PRECISION == "double" else (np.float32, np.uint32)
_UINT_JIT = UInt64 if PRECISION == "double" else UInt32


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


def build(tri_vertices: np.ndarray) -> Tree:
    """SAH BVH over triangles given as (n, 3, 3) vertices.

    Each node's triangles are split by a plane across the axis of their centroids' largest extent
    (centroids rounded to float32), where the surface area heuristic's cost is least (_sah); a node becomes
    a leaf where that costs less than splitting it and it holds at most LEAF_SIZE triangles. The triangle ids
    are sorted by centroid once per axis; each level then splits all its nodes at once, partitioning every
    axis's list stably into the children's parts (linear time, no sort per level), so that each list stays
    sorted within every node. Boxes are reduced over the leaves' triangles, then merged bottom-up."""
    v = tri_vertices
    lo_t, hi_t = np.minimum(np.minimum(v[:, 0], v[:, 1]), v[:, 2]), np.maximum(np.maximum(v[:, 0], v[:, 1]), v[:, 2])
    centroid = ((lo_t + hi_t) / 2).astype(np.float32)
    by_index = [_argsort(centroid[:, a], np.arange(len(v), dtype=np.uint32)) for a in range(3)]
    rank = np.empty((3, len(v)), np.uint32)
    for a in range(3):
        rank[a, by_index[a]] = np.arange(len(v), dtype=np.uint32)
    # (3, n): triangle ids sorted by centroid along each axis, ties in it by the next axis
    ids = np.stack([by_index[(a + 1) % 3][_argsort(centroid[:, a], rank[(a + 1) % 3])] for a in range(3)])
    boxes = np.concatenate([-lo_t, hi_t], 1).astype(np.float32)   # (n, 6): the triangles' boxes as -lo, hi
    right_side = np.zeros(len(v), bool)
    left, right, first, count = [], [], [], []
    begin, size, n_nodes, levels = np.array([0]), np.array([len(v)]), 1, []
    while len(begin):
        levels.append((n_nodes - len(begin), n_nodes))
        split = size > 1
        axis, half = np.zeros(len(begin), np.int64), size // 2
        if split.any():
            axis[split], half[split], split_cost = _sah(ids, centroid, boxes, begin[split], size[split])
            split[split] = (size[split] > LEAF_SIZE) | (split_cost < size[split])
        first.append(np.where(split, 0, begin))
        count.append(np.where(split, 0, size))
        child = np.full(len(begin), -1)
        child[split] = n_nodes + 2 * np.arange(split.sum())
        left.append(child)
        right.append(np.where(split, child + 1, -1))
        b, s, half = begin[split], size[split], half[split]
        if len(b):
            _split(ids, right_side, b, s, axis[split], half)
        begin = np.stack([b, b + half], 1).ravel()
        size = np.stack([half, s - half], 1).ravel()
        n_nodes += len(begin)
    cat = np.concatenate
    left, right, first, count = cat(left), cat(right), cat(first), cat(count)
    order = ids[0].astype(np.int64)
    lo, hi = np.empty((n_nodes, 3), lo_t.dtype), np.empty((n_nodes, 3), hi_t.dtype)
    leaf = np.flatnonzero(left < 0)
    leaf = leaf[np.argsort(first[leaf])]     # reduceat wants ascending starts
    lo[leaf], hi[leaf] = np.minimum.reduceat(lo_t[order], first[leaf]), np.maximum.reduceat(hi_t[order], first[leaf])
    for lv_begin, lv_end in levels[::-1]:   # bottom-up
        node = lv_begin + np.flatnonzero(left[lv_begin:lv_end] >= 0)
        lo[node] = np.minimum(lo[left[node]], lo[right[node]])
        hi[node] = np.maximum(hi[left[node]], hi[right[node]])
    return Tree(lo, hi, left, right, first, count, order, levels)


def _sah(ids: np.ndarray, centroid: np.ndarray, boxes: np.ndarray, b: np.ndarray,
         s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The binned surface area heuristic's split of each node [b, b + s) of sorted slots (s >= 2), all at
    once: (axis, left triangles, cost). The axis is that of the centroids' largest extent; the node's list
    sorted along it is cut into min(s, BINS) bins of equal counts, and a split lies between two bins. Its
    cost, in steps of the walk (an inner node or a triangle test each), is 1 + (A_l n_l + A_r n_r) / A:
    the node's own step, then each child's triangles weighted by the chance that a ray through the node's
    box enters the child's (surface areas A). A bin's box is that of SAMPLES / BINS triangles evenly spread
    over it (all of them in a node of up to SAMPLES). Near-equal costs go to the more even split (so that
    equal triangles do not make a chain). `boxes`: (n, 6) the triangles' boxes as -lo, hi."""
    n = len(b)
    axes = np.arange(3)[:, None]
    c_lo, c_hi = centroid[ids[:, b], axes], centroid[ids[:, b + s - 1], axes]   # (3, nodes): sorted lists' ends
    axis = np.argmax(c_hi - c_lo, axis=0)
    q, bins = np.minimum(s, SAMPLES), np.minimum(s, BINS)
    sample_node = np.repeat(np.arange(n), q)
    first_sample = np.cumsum(q) - q
    i = np.arange(len(sample_node)) - first_sample[sample_node]
    slot = axis[sample_node] * ids.shape[1] + b[sample_node] + i * s[sample_node] // q[sample_node]
    box = np.take(boxes, np.take(ids, slot), axis=0)   # (samples, 6); np.take: faster than indexing
    node = np.repeat(np.arange(n), bins)   # of each bin
    node_bins = np.cumsum(bins) - bins
    j = np.arange(len(node)) - node_bins[node]
    binned = box if len(box) == len(node) else \
        np.maximum.reduceat(box, first_sample[node] + q[node] * j // bins[node], axis=0)   # (bins, 6)
    half, cost = np.empty(n, np.int64), np.empty(n)
    for count in np.unique(bins):          # nodes of `count` bins: one (count, nodes, 6) array
        sel = np.flatnonzero(bins == count)
        x = binned[node_bins[sel] + np.arange(count)[:, None]]
        prefix = np.maximum.accumulate(x, axis=0)
        suffix = np.maximum.accumulate(x[::-1], axis=0)[::-1]
        s_sel, q_sel = s[sel], q[sel]
        n_left = (q_sel * np.arange(1, count)[:, None] // count) * s_sel // q_sel   # triangles in bins before k
        c = n_left * _area(_extent(prefix[:-1])) + (s_sel - n_left) * _area(_extent(suffix[1:]))
        c *= 1 + 1e-6 * np.abs(2 * n_left - s_sel) / s_sel
        best = np.argmin(c, axis=0)
        whole = _area(_extent(prefix[-1]))
        half[sel] = n_left[best, np.arange(len(sel))]
        with np.errstate(divide="ignore", invalid="ignore"):
            cost[sel] = np.where(whole > 0, 1 + c[best, np.arange(len(sel))] / whole, np.inf)
    return axis, half, cost


def _extent(box: np.ndarray) -> np.ndarray:
    """Extents (..., 3) of boxes (..., 6) held as -lo, hi, in float64 (their maxima were exact in float32)."""
    return box[..., :3].astype(np.float64) + box[..., 3:]


def _area(extent: np.ndarray) -> np.ndarray:
    """Surface areas of boxes of extents (..., 3)."""
    x, y, z = extent[..., 0], extent[..., 1], extent[..., 2]
    return 2 * (x * y + y * z + z * x)


def _argsort(key: np.ndarray, tie: np.ndarray) -> np.ndarray:
    """The tie values (unique uint32) of float32 keys sorted by (key, tie), in one sort of 64-bit words:
    the key's bits mapped to an order-preserving unsigned integer above the tie (faster than NumPy's
    stable argsort)."""
    bits = (key + np.float32(0)).view(np.uint32).astype(np.uint64)   # + 0: -0.0 becomes 0.0
    bits = np.where(bits >> 31, bits ^ 0xFFFFFFFF, bits | 0x80000000)
    return (np.sort(bits << 32 | tie.astype(np.uint64)) & 0xFFFFFFFF).astype(np.int32)


def _split(ids: np.ndarray, right_side: np.ndarray, b: np.ndarray, s: np.ndarray, axis: np.ndarray,
           half: np.ndarray) -> None:
    """Splits nodes [b, b + s) of sorted slots in place: in each, the first half[i] triangles of its list
    along axis[i] form the left child, and every axis's list is partitioned stably, left child first."""
    b, s, half = b.astype(np.int32), s.astype(np.int32), half.astype(np.int32)   # int32: less memory traffic
    whole = s.sum() == ids.shape[1]          # the level's nodes cover every slot (no leaves yet)
    slots = np.arange(ids.shape[1], dtype=np.int32) if whole else _ranges(b, s).astype(np.int32)
    node = np.repeat(np.arange(len(b), dtype=np.int32), s)
    right_side[np.take(ids, axis[node] * ids.shape[1] + slots)] = slots >= (b + half)[node]   # np.take: faster than indexing
    # A slot's destination, given `left`, the left-child triangles up to it (inclusive) counted from the
    # level's first slot: a left one goes to b - before - 1 + left, after the left ones before it in its
    # node; a right one to slot + half - (left - before), after its node's left half and the right ones
    # before it (`before`: the left-child triangles of the level's earlier nodes).
    before = (np.cumsum(half, dtype=np.int32) - half)[node]
    to_left = b[node] - before - 1
    gap = slots + half[node] + before - to_left   # to_right - to_left: dest = to_left + left + is_right * (gap - 2 left)
    for a in range(3):
        moved = ids[a].copy() if whole else np.take(ids[a], slots)
        is_right = np.take(right_side, moved)
        left = np.cumsum(~is_right, dtype=np.int32)
        ids[a, to_left + left + is_right * (gap - 2 * left)] = moved


def _ranges(begin: np.ndarray, size: np.ndarray) -> np.ndarray:
    """The concatenated integer ranges [begin, begin + size)."""
    offset = np.repeat(begin - (np.cumsum(size) - size), size)
    return offset + np.arange(size.sum())


def depth_first(tree: Tree) -> np.ndarray:
    """Each node's position in a depth-first (left child first) order of the tree."""
    size = tree.subtree
    position = np.zeros(len(tree.left), np.int64)
    for begin, end in tree.levels:   # top-down
        node = begin + np.flatnonzero(tree.inner[begin:end])
        position[tree.left[node]] = position[node] + 1
        position[tree.right[node]] = position[node] + 1 + size[tree.left[node]]
    return position


class BoxGrid:
    """A 16-bit grid over the root box [lo, hi]: corner q of a node lies at origin + q * step, both
    float32, so that q * step is exact in either precision and `decode` rounds once."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray):
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        reach = np.maximum(np.abs(lo), np.abs(hi))
        pad = np.maximum(np.maximum(hi - lo, reach) * 2.0 ** -20, 1e-30)   # many float32 ulps
        self.origin = (lo - pad).astype(np.float32)
        self.step = ((hi + pad - self.origin) / GRID).astype(np.float32)

    def decode(self, q: np.ndarray) -> np.ndarray:
        """Corners (n, 3) as the kernel computes them: the exact origin + q * step, rounded once."""
        return (q * self.step.astype(np.float64) + self.origin).astype(_FLOAT)

    def quantize(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Grid corners (q_lo, q_hi) of boxes (n, 3), a step beyond them on every side; decoded, they
        contain the boxes."""
        step, origin = self.step.astype(np.float64), self.origin.astype(np.float64)
        q_lo = np.clip(np.floor((lo - origin) / step) - 1, 0, GRID).astype(np.int64)
        q_hi = np.clip(np.ceil((hi - origin) / step) + 1, 0, GRID).astype(np.int64)
        while (low := self.decode(q_lo) > lo).any():     # rounding: at most a step more (decode(0) < lo)
            q_lo -= low
        while (high := self.decode(q_hi) < hi).any():    # decode(GRID) > hi
            q_hi += high
        return q_lo, q_hi

    @staticmethod
    def coords(x: list[UInt32]) -> tuple[Array3f, Array3f]:
        """A box's (min, max) grid corners from its three words."""
        return (Array3f(Float(x[0] & GRID), Float(x[0] >> 16), Float(x[1] & GRID)),
                Array3f(Float(x[1] >> 16), Float(x[2] & GRID), Float(x[2] >> 16)))

    def ray_terms(self, o: Array3f, d: Array3f) -> tuple[Array3f, Array3f]:
        """(slope, offset) with q * slope + offset, per axis, the ray parameter t at which o + t d crosses
        grid plane q: the slab test then takes one fma per plane. Direction components below 1e-20 in
        magnitude count as +-1e-20, so that the terms stay finite (no 0 * inf = NaN)."""
        origin, step = Array3f(*(float(v) for v in self.origin)), Array3f(*(float(v) for v in self.step))
        inv_d = dr.rcp(dr.select(dr.abs(d) < 1e-20, dr.select(d < 0, -1e-20, 1e-20), d))
        return step * inv_d, (origin - o) * inv_d


@dataclass
class Layout:
    """The BVH as the kernel reads it, without the triangles' data (what shapes.bvh_cache stores)."""
    nodes: np.ndarray      # (rows, 16) uint32: per row its four child slots' box words and links
    order: np.ndarray      # (triangles,) original triangle index of each leaf slot
    rows: np.ndarray       # (rows,) the tree node of each table row (for the tests)
    root: np.ndarray       # (2, 3) float64 root box, from which the BoxGrid is made
    stack_size: int        # 4-wide levels: one pending row per level at most


def wide_children(tree: Tree, node: np.ndarray) -> np.ndarray:
    """(len(node), WIDTH) the tree nodes that are the 4-wide children of inner nodes `node`: each binary
    child's own two children if it is inner, else the child itself (a leaf) and -1 (an empty slot)."""
    out = np.full((len(node), WIDTH), -1, np.int64)
    for slot, child in ((0, tree.left[node]), (2, tree.right[node])):
        inner = tree.inner[child]
        out[:, slot] = np.where(inner, tree.left[child], child)
        out[:, slot + 1] = np.where(inner, tree.right[child], -1)
    return out


def layout(tri_vertices: np.ndarray) -> Layout:
    """Builds the tree over (n, 3, 3) triangle vertices and encodes its 4-wide node table: the rows are
    the tree's inner nodes at even depths (the root's, its grandchildren's...), in depth-first order."""
    tree = build(tri_vertices)
    grid = BoxGrid(tree.lo[0], tree.hi[0])
    q_lo, q_hi = grid.quantize(tree.lo, tree.hi)
    boxes = np.stack([q_lo[:, 0] | q_lo[:, 1] << 16, q_lo[:, 2] | q_hi[:, 0] << 16,
                      q_hi[:, 1] | q_hi[:, 2] << 16], 1).astype(np.uint32)
    depth = np.zeros(len(tree.left), np.int64)
    for level, (begin, end) in enumerate(tree.levels):
        depth[begin:end] = level
    wide = np.flatnonzero(tree.inner & (depth % 2 == 0))
    wide = wide[np.argsort(depth_first(tree)[wide])]
    if len(wide):
        children = wide_children(tree, wide)
    else:                # a single leaf: a root row with it as its only child
        wide, children = np.array([0]), np.array([[0, -1, -1, -1]])
    full = children >= 0
    mask = (full << np.arange(WIDTH)).sum(1)
    index = np.zeros(len(tree.left), np.int64)
    index[wide] = np.arange(len(wide)) * (MASK + 1) + mask     # a row's link: its index and its full slots
    link = np.where(tree.inner, index, LEAF_BIT | (tree.first * 8 + tree.count))
    nodes = np.zeros((len(wide), 4 * WIDTH), np.uint32)
    for k in range(WIDTH):
        child = children[:, k]
        nodes[:, 4 * k:4 * k + 3] = np.where(full[:, k, None], boxes[child], 0)
        nodes[:, 4 * k + 3] = np.where(full[:, k], link[child], 0)
    stack_size = max(1, len(tree.levels) // 2)   # a leaf at depth d has ceil(d / 2) rows above it
    return Layout(nodes, tree.order, wide, np.array([tree.lo[0], tree.hi[0]], np.float64), stack_size)


def triangle_frames(v0: np.ndarray, e1: np.ndarray, e2: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rows v0, e1 = v1 - v0, e2 = v2 - v0 of triangles in Float's type, from their (3, n) float64
    coordinate rows (so each difference is rounded once)."""
    out = np.empty((v0.shape[1], 3, 3), _FLOAT)
    for row, a in zip(out.transpose(1, 2, 0), (v0, e1, e2)):   # written in place, not stacked then converted
        row[...] = a
    return out


class BVHKernel:
    """The BVH's inner nodes and triangles on the device, and their traversal; triangle ids are offset by
    `prim_base`. `tables`: the triangles' Layout if already built (shapes.bvh_cache), else built here;
    `frames`: their triangle_frames if already computed."""

    def __init__(self, tri_vertices: np.ndarray, prim_base: int, tables: Layout | None = None,
                 frames: np.ndarray | None = None):
        tables = layout(tri_vertices) if tables is None else tables
        if frames is None:
            v = tri_vertices.transpose(1, 2, 0)
            frames = triangle_frames(v[0], v[1] - v[0], v[2] - v[0])
        self.grid = BoxGrid(*tables.root)
        self.rows = tables.rows
        self.nodes = UInt32(_aligned(tables.nodes))
        self.root = int((tables.nodes[0, 3::4] != 0) @ (1 << np.arange(WIDTH)))   # the root row's link (full slots: links > 0)
        self.stack_size = tables.stack_size
        tris = _aligned_zeros((len(frames), 12), _FLOAT)   # rows (v0, prim, v1 - v0, 0, v2 - v0, 0)
        tris.reshape(-1, 3, 4)[:, :, :3] = np.take(frames, tables.order, axis=0)
        tris[:, 3] = (tables.order + prim_base).astype(_UINT).view(_FLOAT)
        self.tris = Float(tris.ravel())

    def _child(self, x: ArrayXu, k: int, slope: Array3f, offset: Array3f,
               t_max: Float) -> tuple[Bool, Float, UInt32]:
        """Child slot k of a row's words x: whether the ray segment [0, t_max] enters its box, where, and
        its link; (slope, offset): the ray's BoxGrid.ray_terms."""
        q0, q1 = self.grid.coords([x[4 * k + i] for i in range(3)])
        t0, t1 = dr.fma(q0, slope, offset), dr.fma(q1, slope, offset)
        near, far = _min(t0, t1), _max(t0, t1)
        t_near, t_far = _max(_max(near.x, near.y), near.z), _min(_min(far.x, far.y), far.z)
        return (t_near <= t_far) & (t_far >= 0) & (t_near <= t_max), t_near, x[4 * k + 3]

    def _step(self, item: UInt32, stack: tuple, payload: tuple, slope: Array3f, offset: Array3f,
              t_end, visit_triangle) -> tuple[UInt32, tuple, tuple]:
        """One step of the walk (see _walk) for every lane: the next item, the stack and the payload."""
        none = UInt32(0xFFFFFFFF)
        at_leaf = (item >= LEAF_BIT) & (item != none)   # else a row, or nothing left (a lane in the loop's tail)
        inner = ~at_leaf & (item != none)
        payload = dr.if_stmt((item, *payload), at_leaf,
                             lambda i, *p: visit_triangle((i & (LEAF_BIT - 1)) >> 3, *p), lambda i, *p: p)
        x = dr.gather(ArrayXu, self.nodes, item >> WIDTH, inner, shape=(4 * WIDTH, dr.width(item)))
        t_end = t_end(*payload)
        t_best, near, other, near_bit, hits = Float(INF), UInt32(0), UInt32(0), UInt32(0), UInt32(0)
        for k in range(WIDTH):   # `other`: with two slots entered, the farther one's link
            hit, t, link = self._child(x, k, slope, offset, t_end)
            hit &= inner & ((item & (1 << k)) != 0)
            hits |= dr.select(hit, 1 << k, 0)
            closer = hit & (t < t_best)
            other = dr.select(closer, near, dr.select(hit, link, other))
            t_best, near, near_bit = (dr.select(closer, t, t_best), dr.select(closer, link, near),
                                      dr.select(closer, 1 << k, near_bit))
        rest_bits = hits & ~near_bit
        more = at_leaf & ((item & 7) > 1)   # the leaf's next triangle: first + 1, count - 1
        push, pop = rest_bits != 0, ~((hits != 0) | more)
        one = (rest_bits & (rest_bits - 1)) == 0   # one other slot entered: pushed itself, else the row
        pushed = (dr.select(one, other, (item & (0xFFFFFFFF ^ MASK)) | rest_bits), *stack[:-1])
        popped = (*stack[1:], none)
        item = dr.select(pop, stack[0], dr.select(more, item + 7, near))
        stack = tuple(dr.select(push, p, dr.select(pop, q, s)) for p, q, s in zip(pushed, popped, stack))
        return item, stack, payload

    def _walk(self, ray: tuple, active: Bool, t_max, visit_triangle, finished, payload: tuple,
              count_work: bool = False) -> tuple:
        """Depth-first traversal, nearest child first, of the boxes that o + t d, 0 <= t <= t_max(ray,
        *payload), enters, ray = (o, d, ...): payload = visit_triangle(triangle slot, ray, *payload) for each
        triangle of each such leaf; a lane stops at the end or once finished(*payload). Each step a lane
        either tests the boxes of a row's child slots still to visit (its item's mask) or one triangle of a
        leaf. From a row it goes to the nearest child it enters; it pushes the other one it enters, or, if
        several, the row back with those slots (tested again, against the then closest hit, when popped).
        Each lane walks its own ray, in one loop that a packet of lanes leaves when its last lane is done.
        With count_work (diagnostics only), the payload is followed by the number of row steps each lane
        took and of triangles it tested."""
        (slope, offset), none, n = self.grid.ray_terms(ray[0], ray[1]), UInt32(0xFFFFFFFF), len(payload)
        counter = (UInt32(0), UInt32(0)) if count_work else ()
        c = len(counter)
        visit = lambda slot, *p: visit_triangle(slot, ray, *p)   # noqa: E731
        t_end = lambda *p: t_max(ray, *p)                        # noqa: E731

        def cond(item, *rest):
            return (item != none) & ~finished(*rest[c:c + n])

        def body(item, *rest):
            payload, stack = rest[c:c + n], rest[c + n:]
            at_leaf = item >= LEAF_BIT
            counted = (rest[0] + dr.select(~at_leaf, 1, 0), rest[1] + dr.select(at_leaf, 1, 0)) if c else ()
            item, stack, payload = self._step(item, stack, payload, slope, offset, t_end, visit)
            return (item, *counted, *payload, *stack)

        start = dr.select(active, UInt32(self.root), none)
        state = (start, *counter, *payload, *(UInt32(none) for _ in range(self.stack_size)))
        out = dr.while_loop(state, cond, body)
        return (*out[1 + c:1 + c + n], *out[1:1 + c])

    def _walk_batch(self, ray: tuple, active: Bool, t_max, visit_triangle, finished, payload: tuple) -> tuple:
        """The walk of _walk over a batch of rays held in memory, by persistent lanes (Aila and Laine,
        "Understanding the efficiency of ray traversal on GPUs", 2009): BATCH_LANES lanes each take the
        next untraced ray from a shared counter when theirs is done, so that a packet of lanes keeps
        working until the batch is done instead of waiting for its slowest ray (with incoherent rays most of
        a packet's lanes are idle in _walk). A done lane takes its next ray every REFILL_PERIOD steps, so the
        fetch runs for several lanes at once. Each ray's walk, and so its result, is that of _walk.
        `ray` and `payload`: arrays of one value per ray (or one for all); returns the payload per ray,
        unchanged where not active."""
        width = max(dr.width(x) for x in (*ray, *payload, active))
        first = tuple(_batch_array(x, width) for x in payload)   # each ray's payload at its start
        out = tuple(_batch_array(x, width) for x in payload)
        rays = dr.compress(_batch_array(Bool(active), width))   # the rays to walk, by index
        n = dr.width(rays)
        if n == 0:
            return out
        dr.eval(*ray, *first, *out)
        lanes, none, k, m = min(BATCH_LANES, n), UInt32(0xFFFFFFFF), len(ray), len(payload)
        counter = UInt32(lanes)       # the next ray to take
        empty = tuple(UInt32(none) for _ in range(self.stack_size))

        def fetch(r: UInt32, take: Bool) -> tuple:
            """A lane's state for ray rays[r] where `take`: (item, its ray's values, ray terms, payload)."""
            i = dr.gather(UInt32, rays, r, take)
            values = tuple(x if dr.width(x) == 1 else dr.gather(type(x), x, i, take) for x in ray)
            return (dr.select(take, UInt32(self.root), none), *values, *self.grid.ray_terms(values[0], values[1]),
                    *(dr.gather(type(x), x, i, take) for x in first))

        def cond(step, r, *lane):
            return r < n

        def body(step, r, item, *rest):
            values, (slope, offset), payload, stack = rest[:k], rest[k:k + 2], rest[k + 2:k + 2 + m], rest[k + 2 + m:]
            item, stack, payload = self._step(item, stack, payload, slope, offset, lambda *p: t_max(values, *p),
                                              lambda slot, *p: visit_triangle(slot, values, *p))
            step += 1
            take = ((item == none) | finished(*payload)) & ((step % REFILL_PERIOD) == 0)

            def refill(r, *lane):
                i = dr.gather(UInt32, rays, r, take)
                for target, value in zip(out, lane[k + 3:k + 3 + m]):
                    dr.scatter(target, value, i, take)
                r = dr.select(take, dr.scatter_inc(counter, UInt32(0), take), r)
                new = take & (r < n)
                fresh = (*fetch(r, new), *empty)
                return (r, *(dr.select(take, a, b) for a, b in zip(fresh, lane)))

            lane = dr.if_stmt((r, item, *values, slope, offset, *payload, *stack), take, refill, lambda *lane: lane)
            return (step, *lane)

        dr.while_loop((UInt32(0), dr.arange(UInt32, lanes), *fetch(dr.arange(UInt32, lanes), Bool(True)), *empty),
                      cond, body)
        return out

    def _triangle(self, slot, o, d, t_min, t_max, skip, target):
        """The triangle in `slot`: (t, prim, b1, b2), t = inf if o + t d misses it in (t_min, t_max) or it is
        `skip` or `target`."""
        x = dr.gather(ArrayXf, self.tris, slot, shape=(12, dr.width(slot)))
        prim = UInt32(dr.reinterpret_array(_UINT_JIT, x[3]))
        ok = prim != skip
        if target is not None:
            ok &= prim != target
        t, b1, b2 = ray_triangle(o, d, Array3f(x[0], x[1], x[2]), Array3f(x[4], x[5], x[6]),
                                 Array3f(x[8], x[9], x[10]), t_min, t_max)
        return dr.select(ok, t, INF), prim, b1, b2

    def closest_hit(self, o: Array3f, d: Array3f, t_min, t_best: Float, prim: UInt32, b1: Float, b2: Float,
                    skip: UInt32, batch: bool = False):
        """Improves (t_best, prim, b1, b2) with the BVH's triangles; `batch`: by _walk_batch (the
        arguments are then evaluated first), else in the caller's kernel (_walk)."""
        def visit_triangle(slot, ray, t_best, prim, b1, b2):
            o, d, t_min, skip = ray
            t, tri_prim, u, v = self._triangle(slot, o, d, t_min, t_best, skip, None)
            closer = t < t_best
            return (dr.select(closer, t, t_best), dr.select(closer, tri_prim, prim),
                    dr.select(closer, u, b1), dr.select(closer, v, b2))

        walk = self._walk_batch if batch else self._walk
        return walk((o, d, Float(t_min), UInt32(skip)), Bool(True), lambda ray, t_best, *_: t_best,
                    visit_triangle, lambda *_: Bool(False), (Float(t_best), UInt32(prim), Float(b1), Float(b2)))

    def occluded(self, o: Array3f, d: Array3f, dist: Float, skip: UInt32, target: UInt32,
                 active: Bool = True, batch: bool = False) -> Bool:
        """Whether a BVH triangle other than skip and target lies on o + t d, 0 < t < dist; False where
        not active (such lanes skip the traversal). `batch`: as in closest_hit."""
        def visit_triangle(slot, ray, blocked):
            o, d, dist, skip, target = ray
            return (blocked | (self._triangle(slot, o, d, 0.0, dist, skip, target)[0] < dist),)

        walk = self._walk_batch if batch else self._walk
        return walk((o, d, Float(dist), UInt32(skip), UInt32(target)), Bool(active), lambda ray, _: ray[2],
                    visit_triangle, lambda blocked: blocked, (Bool(False),))[0]

    def closest_hit_work(self, o: Array3f, d: Array3f) -> tuple[UInt32, UInt32]:
        """Diagnostics: the row steps (a row popped back counts again) and the triangles tested by each ray's
        closest-hit traversal (the same walk as closest_hit, counting)."""
        def visit_triangle(slot, ray, t_best):
            return (dr.minimum(self._triangle(slot, ray[0], ray[1], 0.0, t_best, UInt32(0xFFFFFFFF), None)[0],
                               t_best),)

        _, steps, tests = self._walk((o, d), Bool(True), lambda ray, t_best: t_best, visit_triangle,
                                     lambda *_: Bool(False), (Float(INF),), count_work=True)
        return steps, tests


def _batch_array(x, width: int):
    """A fresh array of `width` values: x's, or x repeated if it holds one (a target for dr.scatter)."""
    return dr.tile(x, width) if dr.width(x) == 1 else dr.copy(x)


def _min(a, b):
    """min(a, b) for operands that are never NaN, as one instruction (dr.minimum also orders NaNs and
    signed zeros, in several)."""
    return dr.select(a < b, a, b)


def _max(a, b):
    """max(a, b) for operands that are never NaN, as one instruction."""
    return dr.select(a > b, a, b)


def _aligned(a: np.ndarray) -> np.ndarray:
    """A copy of `a` (flattened) starting on a 64-byte boundary (as _aligned_zeros)."""
    out = _aligned_zeros(a.size, a.dtype)
    out[:] = a.ravel()
    return out


def _aligned_zeros(shape: int | tuple[int, ...], dtype, alignment: int = 64) -> np.ndarray:
    """A C-contiguous array of zeros starting on an `alignment`-byte boundary. Dr.Jit wraps a NumPy
    array's memory as it is, and gathers from memory it finds unaligned as separate loads instead of
    packet loads."""
    dtype = np.dtype(dtype)
    size = int(np.prod(shape)) * dtype.itemsize
    buffer = np.zeros(size + alignment, np.uint8)   # calloc: pages zeroed as first touched
    start = -buffer.ctypes.data % alignment
    return buffer[start:start + size].view(dtype).reshape(shape)
