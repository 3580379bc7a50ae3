"""A bounding volume hierarchy over triangles, as the kernels read and walk it: the binary tree of
tracer.shapes.bvh_build, collapsed into 4-wide rows.

The kernel walks a 4-wide tree (as Embree's and pbrt's wide BVHs, collapsed from the binary one): a row
holds the boxes of an inner node's grandchildren, or of a child that is a leaf, so its children are 2 to 4
and the tree half as deep. It walks it depth first, nearest child first: each step a lane at a row tests the
boxes of the row's child slots still to visit, and a lane then at a leaf, there from the last step or just
entered from its row, tests one of its triangles (in a branch that a packet of lanes skips when none of them
is at a leaf; testing a node's child leaves whole within its step cost a packet every triangle test of any
lane's leaves in most steps); a lane that entered no box or tested its leaf's last triangle pops, once a
step (after Aila and Laine, "Understanding the efficiency of ray traversal on GPUs", 2009: a ray takes about
as many steps as rows it visits). Testing the triangle first, then the row popped to after a leaf, took the
same hits 1.7% (closest hit) and 2.3% (shadow) more steps on matpreview's rays (below), and a second pop a
step. From a row it goes on to the nearest child whose box it enters; if it entered one other, it pushes
that child, and if several, it pushes the row back with those slots left in its link's mask, to be tested
again, against the then closest hit, when popped. So each row has at most one entry on the per-lane stack:
its size is the wide tree's depth. The shrinking closest hit culls the far boxes. The stack lives in
registers, one loop variable per level (a push shifts them down, a pop up), since Dr.Jit 1.5's local memory
(dr.alloc_local) lost pushed entries on the LLVM backend (still so: a stack there gave wrong hits). Measured
on the rays of a render of mitsuba-renderer/mitsuba-data's matpreview scene (342 x 256, 16 spp, replayed;
CPU seconds against this walk, interleaved, under load): such a ray walked unbounded tests 16.5 rows (1.4 of
them rows pushed back) and 6.0 triangles, so row steps dominate; yet 8-wide rows (three binary levels a row,
two cache lines) took 1.08x the closest-hit and 1.21x the shadow walks' time for the same hits, starting the
batched walk after the root row's step (taken in the kernel that evaluates the rays) 1.03x and 0.98x, and
16-lane packets on 8-lane AVX2 1.2-1.5x; BATCH_LANES (4096 to 32768) and REFILL_PERIOD (1 to 4) made no
difference beyond the machine's noise.

A row is sixteen 32-bit words (64 bytes, one cache line), gathered in one packet load: per child slot,
its box's corners as 16-bit coordinates on a grid over the root box, rounded outwards by a further grid
step (a margin far above the slab test's rounding; the test turns each coordinate into a ray parameter
with one fma), and a link: a row's index * 16 + the mask of its full slots, or for a leaf its first
triangle * 8 + count with the top bit set; an empty slot is all zeros. A triangle is twelve values: v0,
its primitive id, e1, 0, e2, 0 (the id stored as the bits of a float). Both tables start on a cache
line: from memory it finds unaligned, Dr.Jit gathers value by value instead of in packets.
"""
from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass
from functools import cached_property, partial

import drjit as dr
import numpy as np
from drjit.llvm import Float as _Float32, Float64 as _Float64, UInt32 as _UInt32

from .bvh_build import Tree, build, depth_first, select_max, select_min
from .triangle import ray_triangle
from ..jit import BACKEND, HOST_FLOAT, INF, PRECISION, Array3f, ArrayXf, ArrayXu, Bool, Float, UInt32, UInt64, \
    aligned_zeros, host_array, opaque_u32

GRID = 0xFFFF          # largest grid coordinate of a node's box corner
LEAF_BIT = 1 << 31     # marks a leaf's link word
WIDTH = 4              # children per node of the kernel's table
MASK = (1 << WIDTH) - 1    # an inner link's low bits: the row's child slots still to visit
BATCH_LANES = 4096     # persistent lanes of a batched walk (_walk_batch)
REFILL_PERIOD = 2      # a batched walk's done lanes take new rays every this many steps
BATCHED_WALKS = BACKEND == "llvm"   # measured on the CPU's SIMD packets; a GPU keeps the walk in the kernel
_UINT = np.uint64 if PRECISION == "double" else np.uint32   # a prim id stored in a HOST_FLOAT's bits
_walk_seconds: dict[str, float] | None = None    # see timed_walks
_UINT_JIT = UInt64 if PRECISION == "double" else UInt32


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
        return (q * self.step.astype(np.float64) + self.origin).astype(HOST_FLOAT)

    def quantize(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """(n, 3) uint32: the words of boxes (n, 3) as `coords` reads them, their grid corners a step beyond
        them on every side; decoded, they contain the boxes. One kernel, a lane per box, in float64
        rounded as `decode` (a step more where rounding left a corner inside the box): NumPy's passes
        over the tree's boxes took longer."""
        q, i = [], dr.arange(_UInt32, len(lo))
        for x, outwards, beyond in ((lo, dr.floor, -1), (hi, dr.ceil, 1)):
            x = host_array(_Float64, np.asarray(x, np.float64))
            for a in range(3):
                step, origin = (dr.opaque(_Float64, float(v[a])) for v in (self.step, self.origin))
                corner = dr.gather(_Float64, x, 3 * i + a)

                def outside(k):    # decode(k) not beyond the corner
                    y = _Float64(k) * step + origin
                    y = _Float64(_Float32(y)) if HOST_FLOAT is np.float32 else y
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

    @cached_property
    def _jit_terms(self) -> tuple[Array3f, Array3f]:
        """origin and step as run-time constants (see jit.opaque_u32)."""
        return tuple(Array3f(*(dr.opaque(Float, float(x)) for x in v)) for v in (self.origin, self.step))

    def ray_terms(self, o: Array3f, d: Array3f) -> tuple[Array3f, Array3f]:
        """(slope, offset) with q * slope + offset, per axis, the ray parameter t at which o + t d crosses
        grid plane q: the slab test then takes one fma per plane. Direction components below 1e-20 in
        magnitude count as +-1e-20, so that the terms stay finite (no 0 * inf = NaN)."""
        origin, step = self._jit_terms
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


def layout(vertices: np.ndarray, faces: np.ndarray | None = None) -> Layout:
    """Builds the tree over triangles (as bvh_build.build takes them) and encodes its 4-wide node table: the
    rows are the tree's inner nodes at even depths (the root's, its grandchildren's...), in depth-first
    order."""
    tree = build(vertices, faces)
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
    mask = full @ (1 << np.arange(WIDTH))
    index = np.zeros(len(tree.left), np.int64)
    index[wide] = np.arange(len(wide)) * (MASK + 1) + mask     # a row's link: its index and its full slots
    link = np.where(tree.inner, index, LEAF_BIT | (tree.first * 8 + tree.count))
    words = np.zeros((len(tree.left) + 1, 4), np.uint32)   # per node its box's words and its link; an
    words[:-1, :3], words[:-1, 3] = boxes, link              # empty slot (-1) reads the last, zeros
    nodes = np.take(words, children, axis=0, mode="wrap",   # (a fifth of indexing's time; wrap: unbuffered)
                    out=aligned_zeros((*children.shape, 4), np.uint32)).reshape(len(wide), 4 * WIDTH)
    stack_size = max(1, len(tree.levels) // 2)   # a leaf at depth d has ceil(d / 2) rows above it
    return Layout(nodes, tree.order, wide, np.array([tree.lo[0], tree.hi[0]], np.float64), stack_size)


def triangle_frames(v0: np.ndarray, e1: np.ndarray, e2: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rows v0, e1 = v1 - v0, e2 = v2 - v0 of triangles in Float's type, from their (3, n) float64
    coordinate rows (so each difference is rounded once)."""
    out = np.empty((v0.shape[1], 3, 3), HOST_FLOAT)
    for row, a in zip(out.transpose(1, 2, 0), (v0, e1, e2)):   # written in place, not stacked then converted
        row[...] = a
    return out


class BVHKernel:
    """The BVH's inner nodes and triangles on the device, and their traversal: the triangles' Layout
    (built, or from shapes.bvh_cache) and triangle_frames; triangle ids are offset by `prim_base`. A BVH
    over another kind of primitive is a subclass with its own leaf rows (`prims`) and their ray test
    (`_primitive`)."""

    def __init__(self, tables: Layout, frames: np.ndarray, prim_base: int):
        self._set_nodes(tables)
        tris = leaf_rows(tables.order, prim_base, 12)    # rows (v0, prim, v1 - v0, 0, v2 - v0, 0)
        tris.reshape(-1, 3, 4)[:, :, :3] = np.take(frames, tables.order, axis=0)
        self.prims = Float(tris.ravel())

    def _set_nodes(self, tables: Layout) -> None:
        self.grid = BoxGrid(*tables.root)
        self.rows = tables.rows
        self.nodes = host_array(UInt32, tables.nodes)
        # the root row's link (its full slots: those with a link) and words, as run-time constants
        self.root = opaque_u32(int((tables.nodes[0, 3::4] != 0) @ (1 << np.arange(WIDTH))))
        self.root_words = [opaque_u32(int(w)) for w in tables.nodes[0]]
        self.stack_size = tables.stack_size

    @classmethod
    def over(cls, tri_vertices: np.ndarray, prim_base: int) -> BVHKernel:
        """The BVH of triangles given as (n, 3, 3) vertices, built here."""
        v = tri_vertices.transpose(1, 2, 0)
        return cls(layout(tri_vertices), triangle_frames(v[0], v[1] - v[0], v[2] - v[0]), prim_base)

    def _child(self, x: ArrayXu, k: int, slope: Array3f, offset: Array3f,
               t_max: Float) -> tuple[Bool, Float, UInt32]:
        """Child slot k of a row's words x: whether the ray segment [0, t_max] enters its box, where, and
        its link; (slope, offset): the ray's BoxGrid.ray_terms."""
        q0, q1 = self.grid.coords([x[4 * k + i] for i in range(3)])
        t0, t1 = dr.fma(q0, slope, offset), dr.fma(q1, slope, offset)
        near, far = select_min(t0, t1), select_max(t0, t1)
        t_near = select_max(select_max(near.x, near.y), near.z)
        t_far = select_min(select_min(far.x, far.y), far.z)
        return (t_near <= t_far) & (t_far >= 0) & (t_near <= t_max), t_near, x[4 * k + 3]

    def _enters_root(self, o: Array3f, d: Array3f, t_max: Float) -> Bool:
        """Whether o + t d, 0 <= t <= t_max, enters a box of the root row's children: the walk's first step,
        in the kernel that evaluates a batch's rays (_walk_batch), so that the rays that enter none of them
        (most of a render's, which end on the walls and lights around the meshes) stay out of the walk."""
        slope, offset = self.grid.ray_terms(o, d)
        return self._row(self.root_words, self.root, Bool(True), slope, offset, t_max)[0]

    def _step(self, item: UInt32, stack: tuple, payload: tuple, slope: Array3f, offset: Array3f,
              t_end, visit_triangle, finished, farthest: bool) -> tuple[UInt32, tuple, tuple, Bool, Bool]:
        """One step of the walk (see _walk) for every lane: a lane at a row tests the row's boxes and goes
        on to the nearest child it enters; a lane then at a leaf (there from the last step, or just entered)
        tests its triangle and goes on to the leaf's next one; a lane that entered nothing or tested its
        leaf's last one pops (`farthest`: see _row). The next item, the stack, the payload, and which lanes
        tested a triangle and which a row."""
        none = UInt32(0xFFFFFFFF)
        inner = (item < LEAF_BIT) & ~finished(*payload)
        x = dr.gather(ArrayXu, self.nodes, item >> WIDTH, inner, shape=(4 * WIDTH, dr.width(item)))
        entered, near, push, pushed = self._row(x, item, inner, slope, offset, t_end(*payload), farthest)
        item = dr.select(entered, near, item)
        stack = tuple(dr.select(push, p, s) for p, s in zip((pushed, *stack[:-1]), stack))
        at_leaf = (item >= LEAF_BIT) & (item != none)   # else a row, or nothing left (a lane in the loop's tail)
        payload = dr.if_stmt((item, *payload), at_leaf,
                             lambda i, *p: visit_triangle((i & (LEAF_BIT - 1)) >> 3, *p), lambda i, *p: p)
        more = at_leaf & ((item & 7) > 1)   # the leaf's next triangle: first + 1, count - 1
        item, stack = self._pop((inner & ~entered) | (at_leaf & ~more), item, stack)
        item = dr.select(more, item + 7, item)
        return item, stack, payload, at_leaf, inner

    def _row(self, x: list[UInt32], item: UInt32, inner: Bool, slope: Array3f, offset: Array3f,
             t_end: Float, farthest: bool = False) -> tuple[Bool, UInt32, Bool, UInt32]:
        """The test of a row's words x, reached by link `item`, of its child slots still to visit (the link's
        mask), where `inner`: (whether the ray enters one, the nearest one's link, whether it enters
        others, and what then goes on the stack: the one other, or the row with those slots left).
        `farthest`: the child whose box the ray enters last comes first instead of the nearest (for an
        any-hit query: see occluded)."""
        t_best, near, other, near_bit, hits = Float(-INF if farthest else INF), UInt32(0), UInt32(0), \
            UInt32(0), UInt32(0)
        for k in range(WIDTH):   # `other`: with two slots entered, the later one's link
            hit, t, link = self._child(x, k, slope, offset, t_end)
            hit &= inner & ((item & (1 << k)) != 0)
            hits |= dr.select(hit, 1 << k, 0)
            closer = hit & ((t > t_best) if farthest else (t < t_best))
            other = dr.select(closer, near, dr.select(hit, link, other))
            t_best, near, near_bit = (dr.select(closer, t, t_best), dr.select(closer, link, near),
                                      dr.select(closer, 1 << k, near_bit))
        rest_bits = hits & ~near_bit
        one = (rest_bits & (rest_bits - 1)) == 0   # one other slot entered: pushed itself, else the row
        return hits != 0, near, rest_bits != 0, dr.select(one, other, (item & (0xFFFFFFFF ^ MASK)) | rest_bits)

    @staticmethod
    def _pop(pop: Bool, item: UInt32, stack: tuple) -> tuple[UInt32, tuple]:
        """(item, stack) with the top of the stack popped into item where `pop`."""
        popped = (*stack[1:], UInt32(0xFFFFFFFF))
        return dr.select(pop, stack[0], item), tuple(dr.select(pop, q, s) for q, s in zip(popped, stack))

    def _walk(self, ray: tuple, active: Bool, t_max, visit_triangle, finished, payload: tuple,
              count_work: bool = False, farthest: bool = False) -> tuple:
        """Depth-first traversal, nearest child first (farthest first with `farthest`), of the boxes that
        o + t d, 0 <= t <= t_max(ray, *payload), enters, ray = (o, d, ...): payload = visit_triangle(triangle
        slot, ray, *payload) for each triangle of each such leaf; a lane stops at the end or once
        finished(*payload). Each step a lane at a row tests the boxes of the row's child slots still to visit (its item's mask), and a lane then at a
        leaf tests one of its triangles (_step). From a row it goes to the nearest child it enters; it
        pushes the other one it enters, or, if several, the row back with those slots (tested again, against
        the then closest hit, when popped).
        Each lane walks its own ray, in one loop that a packet of lanes leaves when its last lane is done.
        With count_work (diagnostics only), the payload is followed by the number of rows each lane
        tested (a row popped back counts again) and of triangles it tested."""
        (slope, offset), none, n = self.grid.ray_terms(ray[0], ray[1]), UInt32(0xFFFFFFFF), len(payload)
        counter = (UInt32(0), UInt32(0)) if count_work else ()
        c = len(counter)
        visit = lambda slot, *p: visit_triangle(slot, ray, *p)   # noqa: E731
        t_end = lambda *p: t_max(ray, *p)                        # noqa: E731

        def cond(item, *rest):
            return (item != none) & ~finished(*rest[c:c + n])

        def body(item, *rest):
            payload, stack = rest[c:c + n], rest[c + n:]
            item, stack, payload, tested, row = self._step(item, stack, payload, slope, offset, t_end, visit,
                                                           finished, farthest)
            counted = (rest[0] + dr.select(row, 1, 0), rest[1] + dr.select(tested, 1, 0)) if c else ()
            return (item, *counted, *payload, *stack)

        start = dr.select(active, self.root, none)
        state = (start, *counter, *payload, *(UInt32(none) for _ in range(self.stack_size)))
        out = dr.while_loop(state, cond, body)
        return (*out[1 + c:1 + c + n], *out[1:1 + c])

    def _walk_batch(self, ray: tuple, active: Bool, t_max, visit_triangle, finished, payload: tuple,
                    kind: str = "", farthest: bool = False) -> tuple:
        """The walk of _walk over a batch of rays held in memory, by persistent lanes (Aila and Laine,
        "Understanding the efficiency of ray traversal on GPUs", 2009): BATCH_LANES lanes each take the
        next untraced ray from a shared counter when theirs is done, so that a packet of lanes keeps
        working until the batch is done instead of waiting for its slowest ray (with incoherent rays most of
        a packet's lanes are idle in _walk). A done lane takes its next ray every REFILL_PERIOD steps, so the
        fetch runs for several lanes at once. Each ray's walk, and so its result, is that of _walk.
        `ray`, `payload` (arrays of one value per ray, or one for all) and `farthest` as in _walk; returns
        the payload per ray, unchanged where not active or where the ray enters no box of the root row
        (_enters_root, tested here in the kernel that evaluates the rays; the walked rays' results are
        selected against the start values where they are read next, not copied). `kind`: the query, for
        timed_walks."""
        width = max(dr.width(x) for x in (*ray, *payload, active))
        out = tuple(dr.empty(type(x), width) for x in payload)   # written where walked
        walked = _batch_array(active & self._enters_root(ray[0], ray[1], t_max(ray, *payload)), width)
        rays = dr.compress(walked)             # the rays to walk, by index (`walked` is evaluated once)
        n = dr.width(rays)
        if _walk_seconds is not None:
            for key, count in ((f"{kind}: rays", width), (f"{kind}: walked", n)):
                _walk_seconds[key] = _walk_seconds.get(key, 0) + count
        if n == 0:
            return tuple(_batch_array(x, width) for x in payload)
        first = payload               # each ray's payload at its start: read, never written (no copy)
        dr.eval(*ray, *first, *out)
        lanes, none, k, m = min(BATCH_LANES, n), UInt32(0xFFFFFFFF), len(ray), len(payload)
        counter = UInt32(lanes)       # the next ray to take
        count = dr.opaque(UInt32, n)  # not a literal: one kernel serves every batch size
        empty = tuple(UInt32(none) for _ in range(self.stack_size))

        def fetch(r: UInt32, take: Bool) -> tuple:
            """A lane's state for ray rays[r] where `take`: (item, its ray's values, ray terms, payload)."""
            i = dr.gather(UInt32, rays, r, take)
            values = tuple(x if dr.width(x) == 1 else dr.gather(type(x), x, i, take) for x in ray)
            return (dr.select(take, self.root, none), *values, *self.grid.ray_terms(values[0], values[1]),
                    *(x if dr.width(x) == 1 else dr.gather(type(x), x, i, take) for x in first))

        def cond(step, r, *lane):
            return r < count

        def body(step, r, item, *rest):
            values, (slope, offset) = rest[:k], rest[k:k + 2]
            payload, stack = rest[k + 2:k + 2 + m], rest[k + 2 + m:]
            item, stack, payload, _, _ = self._step(item, stack, payload, slope, offset,
                                                    lambda *p: t_max(values, *p),
                                                    lambda slot, *p: visit_triangle(slot, values, *p), finished,
                                                    farthest)
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

            lane = dr.if_stmt((r, item, *values, slope, offset, *payload, *stack), take, refill,
                              lambda *lane: lane)
            return (step, *lane)

        timed = _walk_seconds is not None
        if timed:
            dr.sync_thread()
            start = time.perf_counter()
        dr.while_loop((UInt32(0), dr.arange(UInt32, lanes), *fetch(dr.arange(UInt32, lanes), Bool(True)), *empty),
                      cond, body)
        if timed:
            dr.eval(*out)
            dr.sync_thread()
            _walk_seconds[kind] = _walk_seconds.get(kind, 0.0) + time.perf_counter() - start
        return tuple(dr.select(walked, x, y) for x, y in zip(out, first))

    def _primitive(self, slot, o, d, t_min, t_max, skip, target):
        """The triangle in leaf slot `slot`: (t, prim, b1, b2), t = inf if o + t d misses it in (t_min,
        t_max) or it is `skip` or `target`."""
        x = dr.gather(ArrayXf, self.prims, slot, shape=(12, dr.width(slot)))
        prim = leaf_prim(x)
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
            t, tri_prim, u, v = self._primitive(slot, o, d, t_min, t_best, skip, None)
            closer = t < t_best
            return (dr.select(closer, t, t_best), dr.select(closer, tri_prim, prim),
                    dr.select(closer, u, b1), dr.select(closer, v, b2))

        walk = partial(self._walk_batch, kind="closest hit") if batch else self._walk
        return walk((o, d, Float(t_min), UInt32(skip)), Bool(True), lambda ray, t_best, *_: t_best,
                    visit_triangle, lambda *_: Bool(False), (Float(t_best), UInt32(prim), Float(b1), Float(b2)))

    def occluded(self, o: Array3f, d: Array3f, dist: Float, skip: UInt32, target: UInt32,
                 active: Bool = True, batch: bool = False) -> Bool:
        """Whether a BVH triangle other than skip and target lies on o + t d, 0 < t < dist; False where
        not active (such lanes skip the traversal). `batch`: as in closest_hit. Any hit answers, so the walk
        takes a row's children farthest first: a shadow ray leaves a surface through the boxes of that
        surface's own leaves, which seldom block it (on matpreview's shadow rays, below, 16.6 steps a ray
        against 21.9 nearest first, 17.9 in the rows' order; on the bunny of shape_ply_bunny, 16.4, 20.4
        and 17.5)."""
        def visit_triangle(slot, ray, blocked):
            o, d, dist, skip, target = ray
            return (blocked | (self._primitive(slot, o, d, 0.0, dist, skip, target)[0] < dist),)

        walk = partial(self._walk_batch, kind="shadow") if batch else self._walk
        return walk((o, d, Float(dist), UInt32(skip), UInt32(target)), Bool(active), lambda ray, _: ray[2],
                    visit_triangle, lambda blocked: blocked, (Bool(False),), farthest=True)[0]

    def closest_hit_work(self, o: Array3f, d: Array3f) -> tuple[UInt32, UInt32]:
        """Diagnostics: the rows tested (a row popped back counts again) and the triangles tested by each ray's
        closest-hit traversal (the same walk as closest_hit, counting)."""
        def visit_triangle(slot, ray, t_best):
            return (dr.minimum(self._primitive(slot, ray[0], ray[1], 0.0, t_best, UInt32(0xFFFFFFFF), None)[0],
                               t_best),)

        _, steps, tests = self._walk((o, d), Bool(True), lambda ray, t_best: t_best, visit_triangle,
                                     lambda *_: Bool(False), (Float(INF),), count_work=True)
        return steps, tests


def leaf_rows(order: np.ndarray, prim_base: int, width: int) -> np.ndarray:
    """(len(order), width) zeros on a cache line, for a BVH's leaf slots, with each slot's primitive id (its
    `order` + prim_base) stored as the bits of the fourth value (leaf_prim reads it)."""
    rows = aligned_zeros((len(order), width), HOST_FLOAT)
    rows[:, 3] = (order + prim_base).astype(_UINT).view(HOST_FLOAT)
    return rows


def leaf_prim(x: list) -> UInt32:
    """The primitive id of a leaf row gathered as values x (leaf_rows)."""
    return UInt32(dr.reinterpret_array(_UINT_JIT, x[3]))


@contextmanager
def timed_walks():
    """Within: each batched walk waits for its inputs, then for its own end, and adds its seconds to the dict
    yielded, by query ("closest hit", "shadow"), and the rays it was asked about and those it walked
    ("closest hit: rays", "closest hit: walked", ...). For validate bench's account of a render's time; the
    waits keep the next kernels from overlapping a walk, so a timed render takes a little longer."""
    global _walk_seconds
    _walk_seconds = {}
    try:
        yield _walk_seconds
    finally:
        _walk_seconds = None


def _batch_array(x, width: int):
    """An array of `width` values in a buffer of its own (a target for dr.scatter): x's, or x repeated if it
    holds one. dr.copy and dr.tile may hand back x's own variable, or one shared with an equal array."""
    out = dr.empty(type(x), width)
    dr.scatter(out, x, dr.arange(UInt32, width))
    return out
