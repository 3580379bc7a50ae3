"""The bounding volume hierarchy's build: a binary tree over triangles, on the host (tracer.shapes.bvh
encodes it for the kernels and walks it).

The tree is built top-down with the surface area heuristic (SAH: MacDonald and Booth, "Heuristics for ray
tracing using space subdivision", The Visual Computer 6(3), 1990), binned as in Wald, "On fast construction
of SAH-based bounding volume hierarchies" (IEEE Symposium on Interactive Ray Tracing, 2007) and pbrt-v4:
each node's triangles are cut across one of the three axes, between BINS bins of equal counts along it,
where the expected cost of a ray's walk through the children is least over all three axes' candidates (as
in Embree's binned builder; pbrt-v4 bins along the axis of the centroids' largest extent alone, which took
4 to 7% more walk steps per ray on the bench's meshes), and a node of up to LEAF_SIZE triangles stays a
leaf where that is cheaper than splitting it. All the nodes of a level are split at once, by a few Dr.Jit
kernels over the triangles (on the host: the LLVM backend, whatever the tracer's), with NumPy for the sorts
and the per-level bookkeeping: in NumPy alone the levels' dozens of passes and temporaries took 3 to 5
times as long at 0.1 to 1 million triangles (below some 1,000 the kernel launches make the build slower,
by a few thousandths of a second). The kernels round as written (float32 boxes, float64 areas and costs,
no fused multiply-add, min/max keeping the second of equal values), so the tree is the same, bit for bit,
on every machine.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import cached_property

import drjit as dr
import numpy as np
# the build's kernels run on the host, on Dr.Jit's LLVM backend, whatever the tracer's: their rounding is
# checked against NumPy's there (a GPU's compiler may fuse a multiply and an add, or flush denormals)
from drjit.llvm import ArrayXf as _ArrayXf32, Float as _Float32, Float64 as _Float64, UInt8 as _UInt8, \
    UInt32 as _UInt32, UInt64 as _UInt64

from ..errors import BackendError
from ..jit import CORES, LLVM_FIX, segment_of

LEAF_SIZE = 7      # most triangles in a leaf (a leaf's link holds the count in 3 bits)
TRAVERSAL_COST = 2.0   # the SAH's cost of a walk's step through an inner node, in triangle tests (see _sah)
BINS = 16          # SAH candidate splits per node: between bins of equal triangle counts
SAMPLES = 256      # triangles whose boxes stand for a node's bins (all of a smaller node's)
BOX = 8            # values per triangle's box in the build's table: -lo, hi and two of padding (one packet load)


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
    surface area heuristic's cost is least over the three axes (_sah); a node becomes a leaf where that
    costs less than splitting it and it holds at most LEAF_SIZE triangles. The triangle ids are sorted by
    centroid once per axis (NumPy); each level then splits all its nodes at once, partitioning every axis's
    list stably into the children's parts (linear time, no sort per level), so that each list
    stays sorted within every node. The per-level work runs as host kernels (_sah, _split) with the lists
    kept there, and only the levels' nodes come back to NumPy: a level is then a few fused passes over the
    lists instead of dozens of NumPy temporaries. Boxes are reduced over the leaves' triangles (a kernel),
    then merged bottom-up."""
    vertices, faces = corners(vertices, faces)
    n = len(faces)
    lists, verts = _triangles(vertices, faces)
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
    leaf = np.flatnonzero(left < 0)    # indices, not masks: NumPy's masked writes to rows take longer
    leaf_lo, leaf_hi = _leaf_boxes(verts, lists.ids, first[leaf], count[leaf])
    lo, hi = np.empty((n_nodes, 3), leaf_lo.dtype), np.empty((n_nodes, 3), leaf_hi.dtype)
    lo[leaf], hi[leaf] = leaf_lo, leaf_hi
    for (b, e), (next_b, next_e) in zip(levels[-2::-1], levels[:0:-1]):   # bottom-up
        inner = b + np.flatnonzero(left[b:e] >= 0)    # their children, in pairs, are the next level's nodes
        lo[inner] = np.minimum(lo[next_b:next_e:2], lo[next_b + 1:next_e:2])
        hi[inner] = np.maximum(hi[next_b:next_e:2], hi[next_b + 1:next_e:2])
    return Tree(lo, hi, left, right, first, count, order, levels)


def corners(vertices: np.ndarray, faces: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (m, 3), faces (n, 3)) of triangles given as such, or, faces None, as (n, 3, 3) vertices."""
    if faces is None:
        return vertices.reshape(-1, 3), np.arange(vertices.shape[0] * 3).reshape(-1, 3)
    return vertices, faces


class _Corners:
    """Triangles on the host backend: their vertices' coordinates (3m, in `real`'s precision, float64
    unless given as float32) and faces (3n)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        real = np.float32 if vertices.dtype == np.float32 else np.float64
        self.real = _Float32 if real == np.float32 else _Float64
        self.coords, self.faces = host_array(self.real, vertices, real), host_array(_UInt32, faces, np.uint32)

    def coordinate(self, t: _UInt32, a: int, active=True) -> list:
        """Coordinate a of the three corners of triangles t."""
        return [dr.gather(self.real, self.coords, 3 * dr.gather(_UInt32, self.faces, 3 * t + j, active) + a, active)
                for j in range(3)]


def _triangles(vertices: np.ndarray, faces: np.ndarray) -> tuple[_Lists, _Corners]:
    """The build's lists of the triangles, and the triangles on the host backend. One kernel finds each
    triangle's box and centroid (min/max as NumPy's: of equal values, the second) and its sort keys; NumPy
    sorts the keys (one sort of 64-bit words per list: a centroid's bits mapped to an order-preserving
    unsigned integer, above the tie)."""
    if not dr.has_backend(dr.JitBackend.LLVM):
        raise BackendError(f"the BVH build runs on Dr.Jit's LLVM backend, which is unavailable: {LLVM_FIX}")
    verts, n = _Corners(vertices, faces), len(faces)
    t, stride = dr.arange(_UInt32, n), dr.opaque(_UInt32, n)
    boxes, bits = dr.zeros(_Float32, BOX * n), dr.empty(_UInt32, 3 * n)
    for a in range(3):
        x = verts.coordinate(t, a)
        lo, hi = select_min(select_min(x[0], x[1]), x[2]), select_max(select_max(x[0], x[1]), x[2])
        c = _Float32((lo + hi) / 2)
        key = dr.reinterpret_array(_UInt32, dr.select(c == 0, 0, c))     # -0.0 as 0.0
        dr.scatter(bits, dr.select(key >> 31 != 0, ~key, key | 0x80000000), a * stride + t)
        dr.scatter(boxes, _Float32(-lo), BOX * t + a)
        dr.scatter(boxes, _Float32(hi), BOX * t + a + 3)
    dr.eval(bits, boxes)
    bits = bits.numpy().reshape(3, n)
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
        ids = list(pool.map(lambda a: sort(a, by_index[(a + 1) % 3]), range(3)))   # ties by the next axis's order
    return _Lists(n, host_array(_UInt32, np.concatenate(ids, out=aligned_zeros(3 * n, np.uint32))), boxes), verts


def _leaf_boxes(verts: _Corners, ids: _UInt32, first: np.ndarray, count: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi), each (leaves, 3), of the leaves' triangles' boxes: those of slots [first, first + count)
    of the first list (count <= LEAF_SIZE)."""
    real, inf, m = verts.real, float("inf"), len(first)
    first, count = _opaque(first), _opaque(count)
    lo, hi = [dr.full(real, inf, m) for _ in range(3)], [dr.full(real, -inf, m) for _ in range(3)]
    for i in range(LEAF_SIZE):
        ok = i < count
        t = dr.gather(_UInt32, ids, first + i, ok)
        for a in range(3):
            x = verts.coordinate(t, a, ok)
            lo[a] = dr.select(ok, select_min(lo[a], select_min(select_min(x[0], x[1]), x[2])), lo[a])
            hi[a] = dr.select(ok, select_max(hi[a], select_max(select_max(x[0], x[1]), x[2])), hi[a])
    dr.eval(lo, hi)
    return np.stack([x.numpy() for x in lo], 1), np.stack([x.numpy() for x in hi], 1)


class _Lists:
    """The build's per-triangle state on the host backend: `ids` (3n) the triangle ids of every node's
    slots sorted along each axis, axis after axis, and `spare` another such buffer, which a level's
    partition fills (then the two swap); `boxes` (BOX n) per triangle its -lo and hi; `node` (n) each
    slot's node among its level's, NONE once in a leaf. Sizes enter the kernels as opaque values, so that a
    kernel compiled once serves every level and mesh."""
    NONE = 0xFFFFFFFF

    def __init__(self, n: int, ids: _UInt32, boxes):
        self.n, self.ids, self.boxes = n, ids, boxes
        self.spare, self.node = dr.empty(_UInt32, 3 * n), dr.zeros(_UInt32, n)
        self.stride = dr.opaque(_UInt32, n)
        dr.eval(self.ids, self.boxes, self.node)


def _sah(lists: _Lists, b: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The binned surface area heuristic's split of each node [b, b + s) of sorted slots (s >= 2), all at
    once: (axis, left triangles, cost). Along each axis the node's list sorted along it is cut into
    min(s, BINS) bins of equal counts, and a split lies between two bins; the split is the least costly of
    the three axes' (the first of equal costs: x, then y, then z). Its cost, in triangle tests, is
    C + (A_l n_l + A_r n_r) / A: the node's own step C (TRAVERSAL_COST), then each child's triangles
    weighted by the chance that a ray through the node's box enters the child's (surface areas A); a leaf
    costs its triangles. C = 2 was chosen from 1, 2 and 3, measured on the bench's meshes at 997,534
    triangles (batched closest hits 4.4, 5.2, 5.4 and shadow rays 6.7, 8.2, 7.9 M rays/s): against 1 it
    makes more nodes leaves, the walks faster, the build 20-30% faster and the node table 38% smaller.
    A bin's box is that of SAMPLES / BINS triangles evenly spread over it (all of them in a node of up to
    SAMPLES). Near-equal costs go to the more even split (so that equal triangles do not make a chain).
    Boxes are float32 (their maxima exact), areas and costs float64, each operation rounded as written (the
    LLVM backend fuses no multiply-add unasked).
    Each (axis, node) pair is a candidate set of bins. A kernel lane per bin gathers each bin's box once;
    then a lane per candidate set merges its bins' boxes, from the last bin to the second (the areas of the
    boxes of bins k and after), then from the first (the prefix boxes and the costs). Merged bin by bin, a
    box is the same as merged sample by sample in that order, bit for bit (select_max keeps the last of
    equal values either way)."""
    n, inf, nodes = lists.stride, float("inf"), len(b)
    b, s, axis = np.tile(b, 3), np.tile(s, 3), np.repeat(np.arange(3), nodes)   # candidate sets, axis by axis
    width, n_bins = len(b), np.minimum(s, BINS)
    total = int(n_bins.sum())     # the level's bins
    b, s, axis, first_bin = _opaque(b), _opaque(s), _opaque(axis), _opaque(np.cumsum(n_bins) - n_bins)

    def empty(lanes):   # the empty box: 6 values (-lo, hi)
        return [dr.full(_Float32, -inf, lanes) for _ in range(6)]

    # a lane per bin: bin k of candidate set j
    j = segment_of(first_bin, total)
    k = dr.arange(_UInt32, total) - dr.gather(_UInt32, first_bin, j)
    s_j = dr.gather(_UInt32, s, j)
    q, few, sampled = dr.minimum(s_j, SAMPLES), s_j < BINS, s_j > SAMPLES    # few: one triangle per bin
    base = dr.gather(_UInt32, axis, j) * n + dr.gather(_UInt32, b, j)

    def bin_start(k):    # a bin's first sample
        return dr.select(few, k, q * k // BINS)

    def add_sample(i, *merged):   # the box of sample i (slot i * s / q of the node) merged in
        slot = dr.select(sampled, _UInt32(_UInt64(i) * _UInt64(s_j) // SAMPLES), i)
        t = dr.gather(_UInt32, lists.ids, base + slot)
        box = dr.gather(_ArrayXf32, lists.boxes, t, shape=(BOX, dr.width(t)))
        return (i + 1, *(select_max(merged[c], box[c]) for c in range(6)))

    end = bin_start(k + 1)
    bin_box = dr.while_loop((bin_start(k), *empty(total)), lambda i, *_: i < end, add_sample)[1:]
    dr.eval(bin_box)

    # a lane per candidate set, loops over its bins (as many as it has)
    bins, few, s_float = dr.minimum(s, BINS), s < BINS, _Float64(s)
    suffix_area = dr.empty(_Float64, total)

    def with_bin(k, merged):   # merged with the box of bin k
        return [select_max(merged[c], dr.gather(_Float32, bin_box[c], first_bin + k)) for c in range(6)]

    def suffix(k, *merged):
        merged = with_bin(k, merged)
        dr.scatter(suffix_area, _box_area(merged), first_bin + k)
        return (k - 1, *merged)

    dr.while_loop((bins - 1, *empty(width)), lambda k, *_: k > 0, suffix)

    def split(k, best, half, *merged):   # between bins k - 1 and k: the first least cost, as np.argmin
        n_left = dr.select(few, k, _UInt32(_UInt64(s) * _UInt64(k) // BINS))
        c = _Float64(n_left) * _box_area(merged) + \
            _Float64(s - n_left) * dr.gather(_Float64, suffix_area, first_bin + k)
        c *= 1 + 1e-6 * _Float64(dr.select(2 * n_left > s, 2 * n_left - s, s - 2 * n_left)) / s_float
        better = (k == 1) | (c < best)
        return (k + 1, dr.select(better, c, best), dr.select(better, n_left, half), *with_bin(k, merged))

    state = (_UInt32(1), dr.full(_Float64, inf, width), dr.zeros(_UInt32, width),
             *with_bin(_UInt32(0), empty(width)))
    _, best, half, *merged = dr.while_loop(state, lambda k, *_: k < bins, split)
    whole = _box_area(merged)
    cost = dr.select(whole > 0, TRAVERSAL_COST + best / whole, inf)
    dr.eval(half, cost)
    cost, half = cost.numpy().reshape(3, nodes), half.numpy().reshape(3, nodes).astype(np.int64)
    axis, node = np.argmin(cost, axis=0), np.arange(nodes)      # the first least: x, then y, then z
    return axis, half[axis, node], cost[axis, node]


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
    out = host_array(_UInt32, np.asarray(x, np.uint32))
    dr.make_opaque(out)
    return out


def host_array(kind: type, a: np.ndarray, dtype=None):
    """`a`, flattened (in `dtype`, if given), as a host array of type `kind`, in memory starting on a cache
    line: Dr.Jit wraps a NumPy array's memory as it is, and a kernel reading it compiles anew for each
    alignment it finds. Copied only where needed."""
    a = np.asarray(a)
    if (dtype is not None and a.dtype != dtype) or not a.flags.c_contiguous or a.ctypes.data % 64:
        a = aligned(a, dtype)
    return kind(a.ravel())


def sah_cost(tree: Tree) -> float:
    """The tree's expected cost of a walk, in triangle tests, of a ray through its root box, by the surface
    area heuristic (MacDonald and Booth 1990; pbrt-v4's BVH cost): TRAVERSAL_COST per inner node and a
    leaf's triangles, each weighted by the chance that such a ray enters the node's box (its surface area
    over the root's). The measure of a tree's quality that _sah minimizes node by node; the root's box has
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


def aligned(a: np.ndarray, dtype=None) -> np.ndarray:
    """A copy of `a` (flattened; in `dtype`, if given) starting on a 64-byte boundary (as aligned_zeros)."""
    out = aligned_zeros(a.shape, dtype or a.dtype)
    out[...] = a
    return out.ravel()


def aligned_zeros(shape: int | tuple[int, ...], dtype, alignment: int = 64) -> np.ndarray:
    """A C-contiguous array of zeros starting on an `alignment`-byte boundary. Dr.Jit wraps a NumPy
    array's memory as it is, and gathers from memory it finds unaligned as separate loads instead of
    packet loads."""
    dtype = np.dtype(dtype)
    size = int(np.prod(shape)) * dtype.itemsize
    buffer = np.zeros(size + alignment, np.uint8)   # calloc: pages zeroed as first touched
    start = -buffer.ctypes.data % alignment
    return buffer[start:start + size].view(dtype).reshape(shape)
