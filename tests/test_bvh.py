"""The BVH traversal finds exactly the hits of the brute-force tests it replaces."""
import os
import sys

import numpy as np
import pytest

import tracer
import tracer.geometry as geometry
import drjit as dr

from tracer.shapes.bvh import LEAF_BIT, WIDTH, BVHKernel, layout, wide_children
from tracer.jit import aligned
from tracer.shapes.bvh_build import BINS, LEAF_SIZE, SAMPLES, TRAVERSAL_COST, Tree, build, depth_first, sah_cost
from tracer.jit import NO_PRIM, Array3f, ArrayXu, Bool, Float, UInt32

from .conftest import SCENES, kernel_hashes


def _rays(n, center, spread, seed=0):
    rng = np.random.default_rng(seed)
    o = np.asarray(center) + rng.uniform(-spread, spread, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return Array3f(*o.T), Array3f(*d.T)


def test_build_covers_every_triangle_once():
    tris = np.random.default_rng(1).uniform(-1, 1, (1000, 3, 3))
    flat = build(tris)
    assert sorted(flat.order) == list(range(1000))
    leaves = flat.count > 0
    assert flat.count[leaves].sum() == 1000
    for node in np.flatnonzero(leaves):   # each leaf's box bounds its triangles
        t = tris[flat.order[flat.first[node]:flat.first[node] + flat.count[node]]]
        assert (t.min(axis=(0, 1)) >= flat.lo[node]).all() and (t.max(axis=(0, 1)) <= flat.hi[node]).all()


@pytest.mark.parametrize("skip_prim", [False, True])
def test_bvh_matches_brute_force(skip_prim):
    scene = tracer.load_scene(SCENES / "hexagon_room.xml")
    o, d = _rays(4000, [4, 0, 0], 2.5)
    brute = geometry.SceneGeometry(scene)
    bvh = geometry.SceneGeometry(scene, bvh_threshold=0)
    assert bvh.meshes.bvh is not None and brute.meshes.bvh is None
    h1 = brute.closest_hit(o, d, 0.0, float("inf"), UInt32(NO_PRIM))
    skip = h1.prim if skip_prim else UInt32(NO_PRIM)
    h1 = brute.closest_hit(o, d, 0.0, float("inf"), skip)
    h2 = bvh.closest_hit(o, d, 0.0, float("inf"), skip)
    np.testing.assert_array_equal(h1.prim.numpy(), h2.prim.numpy())
    np.testing.assert_array_equal(h1.t.numpy(), h2.t.numpy())
    brute.occluders = bvh.occluders = set(range(brute.n_prims))  # random segments: every occluder counts
    dist = Float(np.random.default_rng(2).uniform(0.1, 8, 4000))
    np.testing.assert_array_equal(brute.occluded(o, d, dist, skip, UInt32(NO_PRIM)).numpy(),
                                  bvh.occluded(o, d, dist, skip, UInt32(NO_PRIM)).numpy())


def test_depth_first_order_puts_each_subtree_in_one_run():
    tree = build(np.random.default_rng(3).uniform(-1, 1, (500, 3, 3)))
    position, size = depth_first(tree), tree.subtree
    assert sorted(position) == list(range(len(position)))
    for node in np.flatnonzero(tree.inner):
        left, right = tree.left[node], tree.right[node]
        assert position[left] == position[node] + 1 and position[right] == position[left] + size[left]


@pytest.mark.parametrize("n", [1, 2, 3, 500])
def test_node_table_reaches_every_triangle_once(n):
    """Walked on the host from the root row, the table's links reach each triangle exactly once, only
    through full slots, and no leaf lies below more rows than the kernel's stack holds."""
    tris = np.random.default_rng(n).uniform(-1, 1, (n, 3, 3))
    kernel = BVHKernel.over(tris, prim_base=0)
    table = np.asarray(kernel.nodes).reshape(-1, 4 * WIDTH)
    assert kernel.rows[0] == 0   # the root comes first
    reached, pending, deepest = [], [(kernel.root[0], 1)], 0
    while pending:
        item, rows = pending.pop()   # rows: on the path from the root, this one included
        row = table[item >> WIDTH]
        for k in range(WIDTH):
            link = row[4 * k + 3]
            if not item >> k & 1:
                assert link == 0   # an empty slot
            elif link >= LEAF_BIT:
                first, count = (link - LEAF_BIT) >> 3, (link - LEAF_BIT) & 7
                reached += range(first, first + count)
                deepest = max(deepest, rows)
            else:
                pending.append((link, rows + 1))
    assert sorted(reached) == list(range(n))
    assert deepest <= kernel.stack_size   # each row above a leaf holds at most one stack entry


def _numpy_closest_hits(o, d, tris):
    """Reference: Moeller-Trumbore against every triangle, in float64."""
    v0, e1, e2 = tris[:, 0], tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    t_best, prim = np.full(len(o), np.inf), np.full(len(o), -1)
    for i in range(len(tris)):
        p = np.cross(d, e2[i])
        det = p @ e1[i]
        tv = o - v0[i]
        u = (tv * p).sum(1) / det
        q = np.cross(tv, e1[i])
        v, t = (d * q).sum(1) / det, q @ e2[i] / det
        hit = (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0) & (t < t_best)
        t_best, prim = np.where(hit, t, t_best), np.where(hit, i, prim)
    return t_best, prim


def test_bvh_closest_hits_and_shadow_rays_on_a_large_mesh():
    """600 triangles in a cube; rays in random directions and along the axes against a float64 reference."""
    rng = np.random.default_rng(4)
    tris = rng.uniform(-1, 1, (600, 1, 3)) + rng.uniform(-0.15, 0.15, (600, 3, 3))
    o, d = _rays(6000, [0, 0, 0], 1.5, seed=5)
    axes = np.repeat(np.vstack([np.eye(3), -np.eye(3)]), 100, axis=0)   # 600 rays along the axes
    d = Array3f(*np.vstack([d.numpy().T[:-600], axes]).T)
    kernel = BVHKernel.over(tris, prim_base=7)
    n = 6000
    t, prim, _, _ = kernel.closest_hit(o, d, 0.0, Float(np.full(n, np.inf)), UInt32(np.full(n, NO_PRIM, np.uint32)),
                                       Float(np.zeros(n)), Float(np.zeros(n)), UInt32(NO_PRIM))
    t_ref, prim_ref = _numpy_closest_hits(o.numpy().T.astype(np.float64), d.numpy().T.astype(np.float64), tris)
    hit = np.isfinite(t_ref)
    assert 0.1 < hit.mean() < 0.9   # the rays exercise both hits and misses
    assert np.array_equal(np.isfinite(t.numpy()), hit)
    np.testing.assert_allclose(t.numpy()[hit], t_ref[hit], rtol=1e-4)
    assert (prim.numpy()[hit] == prim_ref[hit] + 7).mean() > 0.999   # ties at shared depths may differ
    dist = np.where(hit, t_ref * 1.001, 10.0)
    blocked = kernel.occluded(o, d, Float(dist), UInt32(NO_PRIM), UInt32(NO_PRIM)).numpy()
    assert np.array_equal(blocked, hit)
    shorter = kernel.occluded(o, d, Float(np.where(hit, t_ref * 0.999, 10.0)), UInt32(NO_PRIM), UInt32(NO_PRIM))
    assert not shorter.numpy()[hit].any()
    active = np.arange(n) % 3 != 0   # inactive lanes answer False, active ones as before
    masked = kernel.occluded(o, d, Float(dist), UInt32(NO_PRIM), UInt32(NO_PRIM), Bool(active)).numpy()
    assert np.array_equal(masked, hit & active)


@pytest.mark.parametrize("offset, extent", [(0.0, 1.0), (1e4, 1.0), (-3.0, 1e-5), (0.0, 0.0)])
def test_decoded_node_boxes_contain_their_triangles(offset, extent):
    """The table's 16-bit corners, decoded, bound every node's box, at most a few grid steps (or float
    spacings) wider; also for a mesh far from the origin, a thin one, and a flat one (extent 0 along z)."""
    rng = np.random.default_rng(7)
    tris = offset + rng.uniform(0, 1, (3000, 3, 3)) * [1.0, 1.0, extent]
    kernel, tree = BVHKernel.over(tris, prim_base=0), build(tris)
    words = dr.gather(ArrayXu, kernel.nodes, dr.arange(UInt32, len(kernel.rows)),
                      shape=(4 * WIDTH, len(kernel.rows)))
    children = wide_children(tree, kernel.rows)
    assert (children[:, [0, 2]] >= 0).all() and (children >= 0).sum() > 2.5 * len(children)   # wider than binary
    for k in range(WIDTH):
        q = kernel.grid.coords([words[4 * k + i] for i in range(3)])   # unpacked as the kernel does
        lo, hi = (kernel.grid.decode(c.numpy().T.astype(np.int64)) for c in q)
        full = children[:, k] >= 0
        child, lo, hi = children[full, k], lo[full], hi[full]
        assert (lo <= tree.lo[child]).all() and (hi >= tree.hi[child]).all()
        slack = 3 * kernel.grid.step.astype(np.float64) + 2 * np.spacing(np.abs(tree.lo[child]).astype(lo.dtype))
        assert (tree.lo[child] - lo <= slack).all() and (hi - tree.hi[child] <= slack).all()


@pytest.mark.parametrize("offset", range(5))
def test_device_tables_start_on_a_cache_line(offset):
    """Dr.Jit turns gathers into packet loads only from aligned memory."""
    a = np.arange(1000, dtype=np.float32)[offset:]
    out = aligned(a)
    assert out.ctypes.data % 64 == 0 and out.dtype == a.dtype
    np.testing.assert_array_equal(out, a)


def _node_slots(tree):
    """Each node's triangles: its leaves' slots, gathered bottom-up."""
    slots = {}
    for begin, end in tree.levels[::-1]:
        for node in range(begin, end):
            slots[node] = (tree.order[tree.first[node]:tree.first[node] + tree.count[node]]
                           if tree.left[node] < 0 else np.concatenate([slots[tree.left[node]], slots[tree.right[node]]]))
    return slots


def _area(lo, hi):
    e = hi - lo
    return 2 * (e[0] * e[1] + e[1] * e[2] + e[2] * e[0])


def _sorted_along(slots, centroid):
    """`slots` sorted along each axis, as the build's lists: by float32 centroid, ties by the next axis."""
    c = centroid[slots]
    return [slots[np.lexsort((slots, c[:, (a + 1) % 3], c[:, a]))] for a in range(3)]


def _split_cost(tris, order, n_left):
    """n_l A_l + n_r A_r of the triangles `order` cut after the first n_left."""
    a, b = tris[order[:n_left]], tris[order[n_left:]]
    return (n_left * _area(a.min(axis=(0, 1)), a.max(axis=(0, 1)))
            + len(b) * _area(b.min(axis=(0, 1)), b.max(axis=(0, 1))))


@pytest.mark.parametrize("ties", [False, True])
def test_build_splits_each_node_where_the_surface_area_heuristic_is_least(ties):
    """Every inner node: its left child is the first triangles of the node's list sorted along one axis
    (_sorted_along), and no split between the BINS equal-count bins along any
    of the three axes has a lower SAH cost n_l A_l + n_r A_r (recomputed here in float64, by brute force
    over the candidates); also with many equal centroid coordinates. A node of at most LEAF_SIZE triangles
    is a leaf where no split costs fewer triangle tests (TRAVERSAL_COST + that cost / A), and only there.
    Leaves hold at most LEAF_SIZE triangles; boxes are exact."""
    rng = np.random.default_rng(11)
    tris = rng.uniform(-1, 1, (2000, 1, 3)) * [4.0, 1.0, 0.5] + rng.uniform(-0.05, 0.05, (2000, 3, 3))
    if ties:
        tris = np.round(tris * 4) / 4
    tree = build(tris)
    centroid = ((tris.min(axis=1) + tris.max(axis=1)) / 2).astype(np.float32)
    slots = _node_slots(tree)
    assert (tree.count[~tree.inner] <= LEAF_SIZE).all() and (tree.count[~tree.inner] >= 1).all()
    axes = []
    for node in np.flatnonzero(tree.inner):
        left = slots[tree.left[node]]
        mine = np.concatenate([left, slots[tree.right[node]]])
        lo, hi = tris[mine].min(axis=(0, 1)), tris[mine].max(axis=(0, 1))
        assert np.array_equal(tree.lo[node], lo) and np.array_equal(tree.hi[node], hi)   # exact boxes
        ordered = _sorted_along(mine, centroid)
        along = [a for a in range(3) if set(ordered[a][:len(left)]) == set(left)]
        assert along, "the left child is no prefix of the node's triangles along any axis"
        axes.append(along[0])
        if len(mine) > SAMPLES:
            continue   # bins of sampled triangles: checked on the smaller nodes
        bins = min(len(mine), BINS)
        best = min(_split_cost(tris, order, len(mine) * k // bins) for order in ordered for k in range(1, bins))
        assert _split_cost(tris, ordered[along[0]], len(left)) <= best * (1 + 1e-5)
        if len(mine) <= LEAF_SIZE:   # split only where that costs fewer triangle tests than a leaf
            assert TRAVERSAL_COST + best / _area(lo, hi) < len(mine) * (1 + 1e-5)
    for leaf in np.flatnonzero(~tree.inner & (tree.count > 1)):   # and a leaf where splitting costs more
        mine = slots[leaf]
        best = min(_split_cost(tris, order, n_left) for order in _sorted_along(mine, centroid)
                   for n_left in range(1, len(mine)))
        whole = _area(tris[mine].min(axis=(0, 1)), tris[mine].max(axis=(0, 1)))
        assert whole == 0 or TRAVERSAL_COST + best / whole >= len(mine) * (1 - 1e-5)   # no area: no ray to split
    assert len(set(axes)) == 3    # the scene is wider along x than y and z, yet nodes split along each


def test_sah_cost_weighs_each_node_by_its_area():
    """A root box [0, 1]^3 (area 6) split across z into two leaves of area 4 each, holding 3 and 4
    triangles: TRAVERSAL_COST + (3 * 4 + 4 * 4) / 6 triangle tests; a lone leaf costs its triangles. The
    build's tree of two far clusters costs under a tenth of one leaf of all, and under half the same tree with
    its triangles dealt out at random among its leaves."""
    lo = np.array([[0, 0, 0], [0, 0, 0], [0, 0, 0.5]])
    hi = np.array([[1, 1, 1], [1, 1, 0.5], [1, 1, 1]])
    tree = Tree(lo, hi, np.array([1, -1, -1]), np.array([2, -1, -1]), np.array([0, 0, 3]), np.array([0, 3, 4]),
                np.arange(7), [(0, 1), (1, 3)])
    assert sah_cost(tree) == pytest.approx(TRAVERSAL_COST + 28 / 6, rel=1e-12)
    one = Tree(lo[:1], hi[:1], np.array([-1]), np.array([-1]), np.array([0]), np.array([7]), np.arange(7), [(0, 1)])
    assert sah_cost(one) == 7
    rng = np.random.default_rng(3)
    tris = rng.uniform(0, 0.01, (400, 3, 3)) + np.where(rng.random(400) < 0.5, 0, 1)[:, None, None]
    built = build(tris)
    assert sah_cost(built) < 0.1 * len(tris)
    dealt = rng.permutation(built.order)     # the same nodes, the triangles dealt among the leaves at random
    lo, hi = built.lo.copy(), built.hi.copy()
    for node, mine in _node_slots(Tree(lo, hi, built.left, built.right, built.first, built.count, dealt,
                                       built.levels)).items():
        lo[node], hi[node] = tris[mine].min(axis=(0, 1)), tris[mine].max(axis=(0, 1))
    dealt = Tree(lo, hi, built.left, built.right, built.first, built.count, dealt, built.levels)
    assert sah_cost(dealt) > 2 * sah_cost(built)


def test_build_of_equal_triangles_stays_balanced():
    """Equal triangles cost the same however they are split: the build halves them (no chain of nodes,
    which would need a deep traversal stack)."""
    tree = build(np.tile(np.eye(3), (1000, 1, 1)))
    assert len(tree.levels) <= 10 and (tree.count[~tree.inner] <= LEAF_SIZE).all()


def test_layout_compiles_no_kernel_anew_for_another_mesh():
    """The layout's encoding kernels (tracer.shapes.bvh; the tree itself is built by the compiled
    extension) take sizes, counts and grid constants as opaque values: a mesh of another size and extent
    runs the kernels of the previous layout (a value baked into a kernel as a literal would compile it anew
    for every scene: most of a second). Compared by kernel hash, whatever Dr.Jit's disk cache holds."""
    rng = np.random.default_rng(13)
    first = kernel_hashes(lambda: layout(rng.uniform(-1, 1, (3000, 3, 3))))
    second = kernel_hashes(lambda: layout(rng.uniform(-1, 1, (2345, 3, 3)) * [3.0, 0.5, 2.0] + 10))
    assert second and second <= first


@pytest.mark.parametrize("real", [np.float32, np.float64])
def test_build_is_a_tree_of_nested_boxes_over_every_triangle_once(real):
    """The compiled build's tree, checked without its code: levels hold consecutive nodes, each inner
    node's children are a pair on the next level; the leaves' slots tile [0, n) and `order` is a
    permutation, so every triangle lies in exactly one leaf; a leaf's box is exactly its triangles' and an
    inner node's exactly its children's (so every box contains its subtree's triangles); the vertices'
    precision is kept; indexed triangles (vertices, faces) give the same tree as their corners; and the
    tree's SAH cost is under a third of the same nodes with the triangles dealt among the leaves at random."""
    rng = np.random.default_rng(17)
    corners = rng.uniform(-1, 1, (700, 1, 3)) * [2.0, 1.0, 0.3] + rng.uniform(-0.05, 0.05, (700, 3, 3))
    faces = rng.permutation(2100).reshape(700, 3)     # small triangles, their corners shuffled in `vertices`
    vertices = np.empty((2100, 3), real)
    vertices[faces] = corners
    tree, tris = build(vertices, faces), vertices[faces]
    n, nodes = len(faces), len(tree.left)
    assert tree.lo.dtype == real and tree.hi.dtype == real
    assert tree.levels[0] == (0, 1) and tree.levels[-1][1] == nodes
    assert all(e == b2 for (_, e), (b2, _) in zip(tree.levels, tree.levels[1:]))
    for (b, e), (b2, e2) in zip(tree.levels, tree.levels[1:] + [(nodes, nodes)]):
        inner = b + np.flatnonzero(tree.left[b:e] >= 0)
        np.testing.assert_array_equal(tree.left[inner], b2 + 2 * np.arange(len(inner)))
        np.testing.assert_array_equal(tree.right[inner], tree.left[inner] + 1)
        assert e2 - b2 == 2 * len(inner)
    leaf = np.flatnonzero(~tree.inner)
    assert (tree.count[leaf] >= 1).all() and (tree.count[leaf] <= LEAF_SIZE).all() and (tree.count[tree.inner] == 0).all()
    covered = np.zeros(n, np.int64)
    for node in leaf:
        covered[tree.first[node]:tree.first[node] + tree.count[node]] += 1
    assert (covered == 1).all()
    np.testing.assert_array_equal(np.sort(tree.order), np.arange(n))
    for node, mine in _node_slots(tree).items():
        assert np.array_equal(tree.lo[node], tris[mine].min(axis=(0, 1)))
        assert np.array_equal(tree.hi[node], tris[mine].max(axis=(0, 1)))
    corners = build(tris)
    for name in ("lo", "hi", "left", "right", "first", "count", "order"):
        np.testing.assert_array_equal(getattr(corners, name), getattr(tree, name))
    assert corners.levels == tree.levels
    lo, hi, dealt = tree.lo.copy(), tree.hi.copy(), rng.permutation(tree.order)
    for node, mine in _node_slots(Tree(lo, hi, tree.left, tree.right, tree.first, tree.count, dealt,
                                       tree.levels)).items():
        lo[node], hi[node] = tris[mine].min(axis=(0, 1)), tris[mine].max(axis=(0, 1))
    assert sah_cost(Tree(lo, hi, tree.left, tree.right, tree.first, tree.count, dealt, tree.levels)) > 3 * sah_cost(tree)


def test_build_without_its_extension_says_how_to_install_it(monkeypatch):
    """Without the compiled extension the build refuses in one line, naming the command that installs it."""
    from tracer.errors import BackendError

    monkeypatch.setitem(sys.modules, "bvh_native", None)     # import fails
    with pytest.raises(BackendError, match=r"pip install \./native"):
        build(np.eye(3)[None])


@pytest.mark.parametrize("vertices, faces, message", [
    (np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int64), "no triangles"),
    (np.eye(3, dtype=np.float32), np.array([[0, 1, 3]]), "outside the vertices"),
    (np.eye(3, dtype=np.float32), np.array([[0, -1, 2]]), "outside the vertices"),
    (np.eye(3, dtype=np.float32), np.array([[0, 1]]), "faces: \\(n, 3\\)"),
])
def test_the_extension_refuses_what_would_take_it_outside_its_arrays(vertices, faces, message):
    """The compiled phases check their arrays' shapes and indices before touching them: an empty or
    malformed mesh is a ValueError, not a write or read outside an array (an empty one crashed the process)."""
    with pytest.raises(ValueError, match=message):
        build(vertices, faces)


PIDS = "/sys/fs/cgroup/pids"    # cgroup v1's pids controller: caps a group's threads


_NO_THREADS = """
import os, sys, numpy as np
import bvh_native
from tracer.shapes import bvh_build as b
rng = np.random.default_rng(3)
n = 30_000
v, f = rng.random((3 * n, 3)).astype(np.float32), rng.integers(0, 3 * n, (n, 3))
boxes, bits = np.empty((n, 6), np.float32), np.empty((3, n), np.uint32)
bvh_native.triangle_keys(v, f, boxes, bits)
ids = b._sorted_lists(bits)
expected = bvh_native.build_nodes(ids.copy(), boxes, b.LEAF_SIZE, b.BINS, b.SAMPLES, b.TRAVERSAL_COST, 1)
group = sys.argv[1]
try:
    open(os.path.join(group, "cgroup.procs"), "w").write(str(os.getpid()))
    threads = int(open(os.path.join(group, "pids.current")).read())
    open(os.path.join(group, "pids.max"), "w").write(str(threads + 1))    # one more thread, not the 7 others
except OSError as e:
    sys.exit(f"no cap: {e}")
got = bvh_native.build_nodes(ids, boxes, b.LEAF_SIZE, b.BINS, b.SAMPLES, b.TRAVERSAL_COST, 8)
assert all((x == y).all() for x, y in zip(got, expected))
print("same tree")
"""


@pytest.mark.skipif(not (os.path.isdir(PIDS) and os.access(PIDS, os.W_OK)),
                    reason="needs cgroup v1's pids controller, writable (root)")
def test_the_build_goes_on_where_threads_cannot_be_started(tmp_path):
    """Where the system lets the build start fewer threads than it asks for (a container's cap on threads), the
    calling thread does the rest: the same tree, not a process aborted by the threads it had started ("terminate
    called without an active exception", as it was)."""
    import subprocess

    group = os.path.join(PIDS, f"tracer-test-{os.getpid()}")
    try:
        os.mkdir(group)
    except OSError as e:
        pytest.skip(f"cannot make a cgroup here: {e}")
    try:
        out = subprocess.run([sys.executable, "-c", _NO_THREADS, group], capture_output=True, text=True,
                             timeout=300, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
    finally:
        os.rmdir(group)
    if out.returncode == 1 and out.stderr.startswith("no cap:"):
        pytest.skip(f"cannot cap a process's threads here ({out.stderr.strip()})")
    assert out.returncode == 0 and out.stdout.strip() == "same tree", out.stderr[-2000:]


def test_the_disk_cache_folder(monkeypatch, tmp_path):
    from tracer.shapes import bvh_cache

    monkeypatch.delenv("TRACER_BVH_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert bvh_cache.disk_folder() == tmp_path / "xdg" / "tracer" / "bvh"      # on by default
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert bvh_cache.disk_folder() == tmp_path / "home" / ".cache" / "tracer" / "bvh"
    for off in ("off", "OFF", "0", ""):
        monkeypatch.setenv("TRACER_BVH_CACHE", off)
        assert bvh_cache.disk_folder() is None
    monkeypatch.setenv("TRACER_BVH_CACHE", str(tmp_path / "mine"))
    assert bvh_cache.disk_folder() == tmp_path / "mine"


def test_only_large_meshes_go_to_disk_by_default(monkeypatch, tmp_path):
    from tracer.shapes import bvh_cache

    monkeypatch.setenv("TRACER_BVH_CACHE", str(tmp_path))
    monkeypatch.setattr(bvh_cache, "DISK_MIN_TRIANGLES", 200)
    rng = np.random.default_rng(3)
    bvh_cache.clear_memory()
    bvh_cache.cached_layout(rng.uniform(-1, 1, (199, 3, 3)))
    assert not list(tmp_path.glob("*.npz"))
    bvh_cache.cached_layout(rng.uniform(-1, 1, (200, 3, 3)))
    assert len(list(tmp_path.glob("*.npz"))) == 1
    bvh_cache.clear_memory()


def test_the_least_recently_used_files_are_evicted(monkeypatch, tmp_path):
    from tracer.shapes import bvh_cache

    rng = np.random.default_rng(4)
    meshes = [rng.uniform(-1, 1, (300, 3, 3)) for _ in range(3)]
    bvh_cache.clear_memory()
    for t, tris in enumerate(meshes):
        bvh_cache.cached_layout(tris, tmp_path)
        path = tmp_path / f"{bvh_cache.key(tris)}.npz"
        os.utime(path, (1000 + t, 1000 + t))          # written in this order
    bvh_cache.clear_memory()
    bvh_cache.cached_layout(meshes[0], tmp_path)       # read back: now the most recently used
    sizes = {p.name: p.stat().st_size for p in tmp_path.glob("*.npz")}
    bvh_cache._evict(tmp_path, sum(sizes.values()) - 1)
    kept = {p.name for p in tmp_path.glob("*.npz")}
    assert kept == {f"{bvh_cache.key(m)}.npz" for m in (meshes[0], meshes[2])}   # the oldest unused one went
    bvh_cache.clear_memory()


def test_layout_cache_reuses_in_memory_and_on_disk(tmp_path):
    from tracer.shapes import bvh_cache

    rng = np.random.default_rng(12)
    tris = rng.uniform(-1, 1, (300, 3, 3))
    bvh_cache.clear_memory()
    built = bvh_cache.cached_layout(tris, tmp_path)
    assert bvh_cache.cached_layout(tris, tmp_path) is built            # this process: the same object
    (stored,) = tmp_path.glob("*.npz")
    assert not list(tmp_path.glob(".*"))                               # no temporary left behind
    bvh_cache.clear_memory()
    loaded = bvh_cache.cached_layout(tris, tmp_path)                   # from disk
    assert loaded is not built
    for field in ("nodes", "order", "rows", "root"):
        assert np.array_equal(getattr(loaded, field), getattr(built, field))
    assert loaded.stack_size == built.stack_size
    moved = tris.copy()
    moved[0, 0, 0] += 1e-9                                             # another mesh: another key
    assert bvh_cache.key(moved) != bvh_cache.key(tris)
    bvh_cache.clear_memory()


@pytest.mark.parametrize("damage", ["truncate", "order", "link", "key"])
def test_layout_cache_rebuilds_a_damaged_file(tmp_path, damage):
    from tracer.shapes import bvh_cache

    tris = np.random.default_rng(13).uniform(-1, 1, (300, 3, 3))
    bvh_cache.clear_memory()
    built = bvh_cache.cached_layout(tris, tmp_path)
    (path,) = tmp_path.glob("*.npz")
    if damage == "truncate":
        path.write_bytes(path.read_bytes()[:200])
    else:
        with np.load(path) as f:
            arrays = dict(f)
        if damage == "order":
            arrays["order"][0] = arrays["order"][1]                   # no longer a permutation
        elif damage == "link":
            arrays["nodes"][0, 3] = len(arrays["nodes"]) << WIDTH | 3    # a row past the table
        else:
            arrays["key"] = np.array("0" * 40)
        with open(path, "wb") as f:
            np.savez(f, **arrays)
    assert bvh_cache._load(path, bvh_cache.key(tris), len(tris)) is None
    bvh_cache.clear_memory()
    rebuilt = bvh_cache.cached_layout(tris, tmp_path)
    assert np.array_equal(rebuilt.nodes, built.nodes) and np.array_equal(rebuilt.order, built.order)
    assert bvh_cache._load(path, bvh_cache.key(tris), len(tris)) is not None   # overwritten with a good file
    bvh_cache.clear_memory()


def test_render_reuses_a_given_geometry():
    from tracer.errors import SettingsError
    from tracer.rendering import render

    scene = tracer.load_scene(SCENES / "cornell_box.xml", width=16, height=16)
    geo = geometry.SceneGeometry(scene, bvh_threshold=0)
    assert geo.meshes.bvh is not None
    a = render(scene, "path", spp=4, seed=1, max_depth=3, geometry=geo)
    b = render(scene, "path", spp=4, seed=1, max_depth=3, geometry=geo)
    np.testing.assert_array_equal(a.image, b.image)
    other = tracer.load_scene(SCENES / "cornell_box.xml", width=16, height=16)
    with pytest.raises(SettingsError, match="geometry"):
        render(other, "path", spp=4, geometry=geo)


def test_closest_hit_work_counts_the_walk():
    """A ray that misses the root box visits the root only and tests nothing; a ray that hits tests at
    least the triangle it hits; no ray visits more inner nodes than the table has."""
    rng = np.random.default_rng(14)
    tris = rng.uniform(-1, 1, (400, 1, 3)) + rng.uniform(-0.1, 0.1, (400, 3, 3))
    kernel = BVHKernel.over(tris, prim_base=0)
    o, d = _rays(2000, [0, 0, 0], 0.5, seed=15)
    away = Array3f(*np.tile([10.0, 10.0, 10.0], (2000, 1)).T)     # outside, pointing away
    steps, tests = (a.numpy() for a in kernel.closest_hit_work(away, Array3f(*np.abs(d.numpy()))))
    assert (steps == 1).all() and (tests == 0).all()
    n = 2000
    t, _, _, _ = kernel.closest_hit(o, d, 0.0, Float(np.full(n, np.inf)), UInt32(np.full(n, NO_PRIM, np.uint32)),
                                    Float(np.zeros(n)), Float(np.zeros(n)), UInt32(NO_PRIM))
    steps, tests = (a.numpy() for a in kernel.closest_hit_work(o, d))
    hit = np.isfinite(t.numpy())
    assert hit.any() and (tests[hit] >= 1).all() and (steps >= 1).all() and (steps <= len(kernel.rows)).all()


def test_mesh_sets_key_their_bvh_by_vertices_and_faces(monkeypatch):
    from tracer.shapes import bvh_cache
    from tracer.shapes.mesh import Mesh, MeshSet

    monkeypatch.setenv("TRACER_BVH_CACHE", "off")
    rng = np.random.default_rng(14)
    v, f = rng.uniform(-1, 1, (200, 3)), rng.integers(0, 200, (300, 3))
    bvh_cache.clear_memory()
    built = bvh_cache.cached_layout(v[f], source=[v, f])
    assert MeshSet([Mesh(v, f, bsdf=None)], base=0, bvh_threshold=0).bvh.rows is built.rows   # the same key
    moved = v.copy()
    moved[f[0, 0]] += 1e-9
    assert bvh_cache.key(moved, f) != bvh_cache.key(v, f) and bvh_cache.key(v, f[:, ::-1]) != bvh_cache.key(v, f)
    bvh_cache.clear_memory()
