"""A bounding volume hierarchy over triangles: built on the host, traversed in the kernel.

The tree is built top-down with the surface area heuristic (SAH: MacDonald and Booth, "Heuristics for ray
tracing using space subdivision", The Visual Computer 6(3), 1990), binned as in Wald, "On fast construction
of SAH-based bounding volume hierarchies" (IEEE Symposium on Interactive Ray Tracing, 2007) and pbrt-v4:
each node's triangles are cut across the axis of their centroids' largest extent, between BINS bins of
equal counts, where the expected cost of a ray's walk through the children is least, and a node of up to
LEAF_SIZE triangles stays a leaf where that is cheaper than splitting it. All the nodes of a level are
split at once, by a few Dr.Jit kernels over the triangles (on the host: the LLVM backend, whatever the
tracer's), with NumPy for the sorts and the per-level bookkeeping: in NumPy alone the levels' dozens of
passes and temporaries took 3 to 5 times as long at 0.1 to 1 million triangles (below some 1,000 the
kernel launches make the build slower, by a few thousandths of a second). The kernels round as the NumPy
build did (float32 boxes, float64 areas and costs, no fused multiply-add, min/max keeping the second of
equal values), so the tree is the same, bit for bit.

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
# the build's kernels run on the host, on Dr.Jit's LLVM backend, whatever the tracer's: their rounding is
# checked against NumPy's there (a GPU's compiler may fuse a multiply and an add, or flush denormals)
from drjit.llvm import Float as _Float32, Float64 as _Float64, UInt8 as _UInt8, UInt32 as _UInt32, \
    UInt64 as _UInt64

from .triangle import ray_triangle
from ..errors import BackendError
from ..jit import (BACKEND, INF, LLVM_FIX, PRECISION, Array3f, ArrayXf, ArrayXu, Bool, Float, UInt32,
                   UInt64)

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
    are sorted by centroid once per axis (NumPy); each level then splits all its nodes at once, partitioning
    every axis's list stably into the children's parts (linear time, no sort per level), so that each list
    stays sorted within every node. The per-level work runs as host kernels (_sah, _split) with the lists
    kept there, and only the levels' nodes come back to NumPy: a level is then a few fused passes over the
    lists instead of dozens of NumPy temporaries. Boxes are reduced over the leaves' triangles (a kernel),
    then merged bottom-up."""
    n = len(tri_vertices)
    lists, verts = _triangles(tri_vertices)
    left, right, first, count = [], [], [], []
    begin, size, n_nodes, levels = np.array([0]), np.array([n]), 1, []
    while len(begin):
        levels.append((n_nodes - len(begin), n_nodes))
        split = size > 1
        axis, half = np.zeros(len(begin), np.int64), size // 2
        if split.any():
            axis[split], half[split], split_cost = _sah(lists, begin[split], size[split])
            split[split] = (size[split] > LEAF_SIZE) | (split_cost < size[split])
        first.append(np.where(split, 0, begin))
        count.append(np.where(split, 0, size))
        child = np.full(len(begin), -1)
        child[split] = n_nodes + 2 * np.arange(split.sum())
        left.append(child)
        right.append(np.where(split, child + 1, -1))
        b, s, half = begin[split], size[split], half[split]
        if len(b):
            _split(lists, begin, size, split, axis[split], half)
        begin, size = np.empty(2 * len(b), np.int64), np.empty(2 * len(b), np.int64)   # the children
        begin[0::2], begin[1::2], size[0::2], size[1::2] = b, b + half, half, s - half
        n_nodes += len(begin)
    cat = np.concatenate
    left, right, first, count = cat(left), cat(right), cat(first), cat(count)
    order = lists.ids[:n].numpy().astype(np.int64)
    leaf = np.flatnonzero(left < 0)
    leaf_lo, leaf_hi = _leaf_boxes(verts, lists.ids, first[leaf], count[leaf])
    lo, hi = np.empty((n_nodes, 3), leaf_lo.dtype), np.empty((n_nodes, 3), leaf_hi.dtype)
    lo[leaf], hi[leaf] = leaf_lo, leaf_hi
    for lv_begin, lv_end in levels[::-1]:   # bottom-up
        node = lv_begin + np.flatnonzero(left[lv_begin:lv_end] >= 0)
        lo[node] = np.minimum(lo[left[node]], lo[right[node]])
        hi[node] = np.maximum(hi[left[node]], hi[right[node]])
    return Tree(lo, hi, left, right, first, count, order, levels)


def _triangles(tri_vertices: np.ndarray) -> tuple[_Lists, object]:
    """The build's lists of the triangles, and their vertices (9n, as given) on the host backend. One
    kernel finds each triangle's box and centroid (min/max as NumPy's: of equal values, the second) and
    its sort keys; NumPy sorts the keys (one sort of 64-bit words per list: a centroid's bits mapped to an
    order-preserving unsigned integer, above the tie)."""
    if not dr.has_backend(dr.JitBackend.LLVM):
        raise BackendError(f"the BVH build runs on Dr.Jit's LLVM backend, which is unavailable: {LLVM_FIX}")
    v = tri_vertices if tri_vertices.dtype in (np.float32, np.float64) else tri_vertices.astype(np.float64)
    n, real = len(v), _Float32 if v.dtype == np.float32 else _Float64
    verts = _host(real, v)
    t, stride = dr.arange(_UInt32, n), dr.opaque(_UInt32, n)
    centroid, boxes, bits = dr.empty(_Float32, 3 * n), dr.empty(_Float32, 6 * n), dr.empty(_UInt32, 3 * n)
    for a in range(3):
        x = [dr.gather(real, verts, 9 * t + 3 * j + a) for j in range(3)]
        lo, hi = _min(_min(x[0], x[1]), x[2]), _max(_max(x[0], x[1]), x[2])
        c = _Float32((lo + hi) / 2)
        key = dr.reinterpret_array(_UInt32, dr.select(c == 0, 0, c))     # -0.0 as 0.0
        dr.scatter(bits, dr.select(key >> 31 != 0, ~key, key | 0x80000000), a * stride + t)
        dr.scatter(centroid, c, a * stride + t)
        dr.scatter(boxes, _Float32(-lo), a * stride + t)
        dr.scatter(boxes, _Float32(hi), (a + 3) * stride + t)
    dr.eval(bits, centroid, boxes)
    bits = bits.numpy().reshape(3, n)
    position = np.arange(n, dtype=np.uint64)
    by_index = []      # per axis: the triangles sorted by centroid, ties by index
    for a in range(3):
        key = bits[a].astype(np.uint64)
        key <<= 32
        key |= position
        key.sort()
        by_index.append(key.astype(np.uint32))
    ids = []           # per axis: sorted by centroid, ties by the next axis's order
    for a in range(3):
        after = by_index[(a + 1) % 3]
        key = bits[a][after].astype(np.uint64)
        key <<= 32
        key |= position
        key.sort()
        ids.append(after[key.astype(np.uint32)])
    return _Lists(n, _host(_UInt32, np.concatenate(ids)), centroid, boxes), verts


def _leaf_boxes(verts, ids: _UInt32, first: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi), each (leaves, 3), of the leaves' triangles' boxes: those of slots [first, first + count)
    of the first list (count <= LEAF_SIZE)."""
    real, inf, m = type(verts), float("inf"), len(first)
    first, count = _opaque(first), _opaque(count)
    lo, hi = [dr.full(real, inf, m) for _ in range(3)], [dr.full(real, -inf, m) for _ in range(3)]
    for i in range(LEAF_SIZE):
        ok = i < count
        t = dr.gather(_UInt32, ids, first + i, ok)
        for a in range(3):
            x = [dr.gather(real, verts, 9 * t + 3 * j + a, ok) for j in range(3)]
            lo[a] = dr.select(ok, _min(lo[a], _min(_min(x[0], x[1]), x[2])), lo[a])
            hi[a] = dr.select(ok, _max(hi[a], _max(_max(x[0], x[1]), x[2])), hi[a])
    dr.eval(lo, hi)
    return np.stack([x.numpy() for x in lo], 1), np.stack([x.numpy() for x in hi], 1)


class _Lists:
    """The build's per-triangle state on the host backend: `ids` (3n) the triangle ids of every node's
    slots sorted along each axis, axis after axis, and `spare` another such buffer, which a level's
    partition fills (then the two swap); `centroid` (3n) and `boxes` (6n, as -lo then hi) per axis then
    triangle; `node` (n) each slot's node among its level's, NONE once in a leaf. Sizes enter the kernels
    as opaque values, so that a kernel compiled once serves every level and mesh."""
    NONE = 0xFFFFFFFF

    def __init__(self, n: int, ids: _UInt32, centroid, boxes):
        self.n, self.ids, self.centroid, self.boxes = n, ids, centroid, boxes
        self.spare, self.node = dr.empty(_UInt32, 3 * n), dr.zeros(_UInt32, n)
        self.stride = dr.opaque(_UInt32, n)
        dr.eval(self.ids, self.centroid, self.boxes, self.node)


def _sah(lists: _Lists, b: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The binned surface area heuristic's split of each node [b, b + s) of sorted slots (s >= 2), all at
    once, a kernel lane per node: (axis, left triangles, cost). The axis is that of the centroids' largest
    extent; the node's list sorted along it is cut into min(s, BINS) bins of equal counts, and a split lies
    between two bins. Its cost, in steps of the walk (an inner node or a triangle test each), is
    1 + (A_l n_l + A_r n_r) / A: the node's own step, then each child's triangles weighted by the chance
    that a ray through the node's box enters the child's (surface areas A). A bin's box is that of
    SAMPLES / BINS triangles evenly spread over it (all of them in a node of up to SAMPLES). Near-equal costs
    go to the more even split (so that equal triangles do not make a chain). Boxes are float32 (their
    maxima exact), areas and costs float64, each operation rounded as written (the LLVM backend fuses no
    multiply-add unasked): the splits are those of the NumPy build this replaced."""
    n, inf = lists.stride, float("inf")
    b, s = _opaque(b), _opaque(s)

    def centroid(a, slot):   # along axis a, of the triangle in a slot of the list along a
        return dr.gather(_Float32, lists.centroid, dr.gather(_UInt32, lists.ids, a * n + slot) + a * n)

    extent = [centroid(a, b + s - 1) - centroid(a, b) for a in range(3)]
    axis, longest = _UInt32(0), extent[0]
    for a in (1, 2):   # the first of equal extents, as np.argmax
        longer = extent[a] > longest
        axis, longest = dr.select(longer, a, axis), dr.select(longer, extent[a], longest)
    q, bins, base = dr.minimum(s, SAMPLES), dr.minimum(s, BINS), axis * n + b
    few = s < BINS      # one triangle per bin
    sampled = s > SAMPLES

    def bin_start(j):    # a bin's first sample
        return dr.select(few, j, q * j // BINS)

    def add_sample(i, *merged):   # the box of sample i (slot i * s / q of the node) merged in
        slot = dr.select(sampled, _UInt32(_UInt64(i) * _UInt64(s) // SAMPLES), i)
        t = dr.gather(_UInt32, lists.ids, base + slot)
        return (i + 1, *(_max(merged[c], dr.gather(_Float32, lists.boxes, c * n + t)) for c in range(6)))

    empty = [dr.full(_Float32, -inf, dr.width(b)) for _ in range(6)]

    def with_bin(k, merged):   # merged with the box of bin k: 6 values (-lo, hi)
        end = bin_start(k + 1)
        return dr.while_loop((bin_start(k), *merged), lambda i, *_: i < end, add_sample)[1:]

    # loops over a node's bins (as many as it has): the areas of the boxes of bins k and after, then
    # the prefix boxes and the costs
    node, s_float = dr.arange(_UInt32, dr.width(b)), _Float64(s)
    suffix_area = dr.empty(_Float64, BINS * dr.width(b))

    def suffix(k, *merged):
        merged = with_bin(k, merged)
        dr.scatter(suffix_area, _box_area(merged), node * BINS + k)
        return (k - 1, *merged)

    dr.while_loop((bins - 1, *empty), lambda k, *_: k > 0, suffix)

    def split(k, best, half, *merged):   # between bins k - 1 and k: the first least cost, as np.argmin
        n_left = dr.select(few, k, _UInt32(_UInt64(s) * _UInt64(k) // BINS))
        c = _Float64(n_left) * _box_area(merged) + \
            _Float64(s - n_left) * dr.gather(_Float64, suffix_area, node * BINS + k)
        c *= 1 + 1e-6 * _Float64(dr.select(2 * n_left > s, 2 * n_left - s, s - 2 * n_left)) / s_float
        better = (k == 1) | (c < best)
        return (k + 1, dr.select(better, c, best), dr.select(better, n_left, half), *with_bin(k, merged))

    state = (_UInt32(1), dr.full(_Float64, inf, dr.width(b)), dr.zeros(_UInt32, dr.width(b)),
             *with_bin(_UInt32(0), empty))
    _, best, half, *merged = dr.while_loop(state, lambda k, *_: k < bins, split)
    whole = _box_area(merged)
    cost = dr.select(whole > 0, 1 + best / whole, inf)
    dr.eval(axis, half, cost)
    return axis.numpy().astype(np.int64), half.numpy().astype(np.int64), cost.numpy()


def _box_area(box: list):
    """Surface area, in float64, of a box given as float32 (-lo, hi) (extents exact in float64)."""
    x, y, z = (_Float64(box[c]) + _Float64(box[c + 3]) for c in range(3))
    return 2 * (x * y + y * z + z * x)


def _split(lists: _Lists, begin: np.ndarray, size: np.ndarray, split: np.ndarray, axis: np.ndarray,
           half: np.ndarray) -> None:
    """Splits the level's nodes [begin, begin + size) where `split`: in each, the first half[i] triangles of
    its list along axis[i] (half, axis: of the splitting nodes) form the left child, and every axis's list
    is partitioned stably, left child first; `lists.node` becomes each slot's node on the next level (the
    children, in order). A pass over the level's slots finds each triangle's side (left, right, or
    staying: in a node that does not split), reading the lists along the nodes' axes; a pass over the
    three lists marks the left ones, as bits, 32 slots a word; a prefix sum over the words' counts and a
    last pass, counting the bits before each slot in its word, move every slot to its place in
    `lists.spare`.
    The slots of a level's leaves are copied on their own level, and may be left alone after (both
    buffers then hold them), so that the deep levels, most of whose slots are in leaves, cost less."""
    n, none = lists.stride, _Lists.NONE
    rank = _opaque(np.where(split, np.cumsum(split) - 1, none))    # a level node's index among the splitting ones
    b, half_j, axis_j = _opaque(begin[split]), _opaque(half), _opaque(axis)
    before = _opaque(np.cumsum(half) - half)      # the left-child triangles of the level's earlier nodes
    # the slots to visit: all (a counter: the passes then read the lists as packets), or, where most are
    # in leaves already, those of the level's nodes
    compact = 2 * int(size.sum()) < lists.n
    slots = dr.compress(lists.node != none) if compact else dr.arange(_UInt32, lists.n)
    all_left, width = dr.opaque(_UInt32, int(half.sum())), dr.opaque(_UInt32, dr.width(slots))

    node = dr.gather(_UInt32, lists.node, slots)
    k = dr.gather(_UInt32, rank, node, node != none)
    active = (node != none) & (k != none)
    b_k, half_k = dr.gather(_UInt32, b, k, active), dr.gather(_UInt32, half_j, k, active)
    before_k = dr.gather(_UInt32, before, k, active)
    goes_right = slots >= b_k + half_k
    side = dr.empty(_UInt8, lists.n)     # per triangle of the level: 0 left, 1 right, 2 staying
    dr.scatter(side, dr.select(active, dr.select(goes_right, _UInt8(1), 0), 2),
               dr.gather(_UInt32, lists.ids, dr.gather(_UInt32, axis_j, k, active) * n + slots))
    to_left = b_k - before_k - 1      # a left one's place: to_left + the left ones up to it from the level's
    to_right = half_k + before_k      # first slot; a right one's: its slot + to_right - those
    next_node = dr.full(_UInt32, none, lists.n)
    dr.scatter(next_node, dr.select(active, 2 * k + dr.select(goes_right, 1, 0), none), slots)
    dr.eval(side, to_left, to_right, next_node)

    def visit(i, inside=True):    # slot i of the three lists' visited ones: (axis, j, slot, triangle, side)
        a = dr.select(i >= 2 * width, 2, dr.select(i >= width, 1, 0))
        j = i - a * width
        slot = dr.gather(_UInt32, slots, j, inside) if compact else j
        moved = dr.gather(_UInt32, lists.ids, a * n + slot if compact else i, inside)
        return a, j, slot, moved, dr.gather(_UInt8, side, moved, inside)

    # the left ones as bits, 32 slots a word, and the left ones before each word: a prefix sum over
    # the words instead of over the slots
    total = 3 * dr.width(slots)
    word = dr.arange(_UInt32, (total + 31) // 32)

    def mark(bit, bits):   # eight bits a step: a loop small enough to compile fast, unrolled enough to run fast
        for b in range(8):
            i = 32 * word + bit + b
            inside = i < 3 * width
            bits |= dr.select(inside & (visit(i, inside)[4] == 0), _UInt32(1) << (bit + b), 0)
        return bit + 8, bits

    bits = dr.while_loop((_UInt32(0), dr.zeros(_UInt32, dr.width(word))), lambda bit, _: bit < 32, mark)[1]
    dr.eval(bits)
    before_word = dr.prefix_reduce(dr.ReduceOp.Add, dr.popcnt(bits))

    i = dr.arange(_UInt32, total)
    a, j, slot, moved, to = visit(i)
    word = i >> 5
    up_to = (2 << (i & 31)) - 1       # this slot's bit and those below it
    left = dr.gather(_UInt32, before_word, word) + dr.popcnt(dr.gather(_UInt32, bits, word) & up_to)
    left -= a * all_left     # the left ones of the list along this axis up to this slot, inclusive
    dest = dr.select(to == 0, dr.gather(_UInt32, to_left, j, to == 0) + left,
                     dr.select(to == 1, slot + dr.gather(_UInt32, to_right, j, to == 1) - left, slot))
    dr.scatter(lists.spare, moved, a * n + dest)
    lists.ids, lists.spare, lists.node = lists.spare, lists.ids, next_node
    dr.eval(lists.ids, lists.node)


def _opaque(x: np.ndarray) -> _UInt32:
    """x as a UInt32 array in memory: an array of one value would else enter the kernels as a literal,
    compiling them anew for every value."""
    out = _host(_UInt32, np.asarray(x, np.uint32))
    dr.make_opaque(out)
    return out


def _host(kind: type, a: np.ndarray):
    """`a`, flattened, as a host array of type `kind`, in memory starting on a cache line: Dr.Jit wraps a
    NumPy array's memory as it is, and a kernel reading it compiles anew for each alignment it finds."""
    a = np.ascontiguousarray(a).ravel()
    return kind(a if a.ctypes.data % 64 == 0 else _aligned(a))


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

    def quantize(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """(n, 3) uint32: the words of boxes (n, 3) as `coords` reads them, their grid corners a step beyond
        them on every side; decoded, they contain the boxes. One kernel, a lane per box, in float64
        rounded as `decode` (a step more where rounding left a corner inside the box): NumPy's passes
        over the tree's boxes took longer."""
        q, i = [], dr.arange(_UInt32, len(lo))
        for x, outwards, beyond in ((lo, dr.floor, -1), (hi, dr.ceil, 1)):
            x = _host(_Float64, np.asarray(x, np.float64))
            for a in range(3):
                step, origin = (dr.opaque(_Float64, float(v[a])) for v in (self.step, self.origin))
                corner = dr.gather(_Float64, x, 3 * i + a)

                def outside(k):    # decode(k) not beyond the corner
                    y = _Float64(k) * step + origin
                    y = _Float64(_Float32(y)) if _FLOAT is np.float32 else y
                    return y > corner if beyond < 0 else y < corner

                k = _UInt32(dr.clip(outwards((corner - origin) / step) + beyond, 0, GRID))
                q.append(dr.while_loop((k,), outside, lambda k: (k - 1 if beyond < 0 else k + 1,))[0])
        words = [q[0] | q[1] << 16, q[2] | q[3] << 16, q[4] | q[5] << 16]
        dr.eval(words)
        out = np.empty((len(lo), 3), np.uint32)
        for c, w in enumerate(words):
            out[:, c] = w.numpy()
        return out

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
    boxes = grid.quantize(tree.lo, tree.hi)
    depth = np.zeros(len(tree.left), np.int64)
    for level, (begin, end) in enumerate(tree.levels):
        depth[begin:end] = level
    in_order = np.full(len(tree.left), -1)      # the rows, in depth-first order (positions are unique)
    wide = np.flatnonzero(tree.inner & (depth % 2 == 0))
    in_order[depth_first(tree)[wide]] = wide
    wide = in_order[in_order >= 0]
    if len(wide):
        children = wide_children(tree, wide)
    else:                # a single leaf: a root row with it as its only child
        wide, children = np.array([0]), np.array([[0, -1, -1, -1]])
    full = children >= 0
    mask = (full << np.arange(WIDTH)).sum(1)
    index = np.zeros(len(tree.left), np.int64)
    index[wide] = np.arange(len(wide)) * (MASK + 1) + mask     # a row's link: its index and its full slots
    link = np.where(tree.inner, index, LEAF_BIT | (tree.first * 8 + tree.count))
    words = np.zeros((len(tree.left) + 1, 4), np.uint32)   # per node its box's words and its link; an
    words[:-1, :3], words[:-1, 3] = boxes, link              # empty slot (-1) reads the last, zeros
    nodes = words[children].reshape(len(wide), 4 * WIDTH)
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
        count = dr.opaque(UInt32, n)  # not a literal: one kernel serves every batch size
        empty = tuple(UInt32(none) for _ in range(self.stack_size))

        def fetch(r: UInt32, take: Bool) -> tuple:
            """A lane's state for ray rays[r] where `take`: (item, its ray's values, ray terms, payload)."""
            i = dr.gather(UInt32, rays, r, take)
            values = tuple(x if dr.width(x) == 1 else dr.gather(type(x), x, i, take) for x in ray)
            return (dr.select(take, UInt32(self.root), none), *values, *self.grid.ray_terms(values[0], values[1]),
                    *(dr.gather(type(x), x, i, take) for x in first))

        def cond(step, r, *lane):
            return r < count

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
                new = take & (r < count)
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
