"""Batched BVH walks (persistent lanes over rays in memory) and the path tracer bounce by bounce give
exactly the results of the walk and the paths in one kernel."""
import drjit as dr
import numpy as np
import pytest

import tracer
import tracer.geometry as geometry_module
import tracer.integrators.path as path_integrator
from tracer.camera import primary_rays
from tracer.estimators import PathEstimator
from tracer.geometry import SceneGeometry
from tracer.jit import NO_PRIM, Array3f, Bool, Float, UInt32, opaque_u32
from tracer.plan import PATH_LANE_BYTES, WAVEFRONT_LANE_BYTES
from tracer.rendering import make_plan
from tracer.sampling import seeded_rng
from tracer.shapes import BVH_THRESHOLD
from tracer.shapes.bvh import BATCH_LANES, BATCHED_WALKS, BVHKernel

from .conftest import SCENES, kernel_hashes

N = 3 * BATCH_LANES + 123     # rays: every lane takes several, the last ones a part


@pytest.fixture(scope="module")
def kernel_and_rays():
    rng = np.random.default_rng(21)
    tris = rng.uniform(-1, 1, (3000, 1, 3)) + rng.uniform(-0.08, 0.08, (3000, 3, 3))
    o = rng.uniform(-1.2, 1.2, (N, 3))
    d = rng.normal(size=(N, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return BVHKernel.over(tris, prim_base=5), Array3f(*o.T), Array3f(*d.T), rng


def test_batched_closest_hits_are_the_walks(kernel_and_rays):
    kernel, o, d, rng = kernel_and_rays
    t_best = Float(np.where(rng.uniform(size=N) < 0.3, rng.uniform(0.1, 2, N), np.inf))  # a hit found before
    prim = UInt32(np.where(np.isfinite(t_best.numpy()), 1, NO_PRIM).astype(np.uint32))
    b1, b2 = Float(rng.uniform(size=N)), Float(rng.uniform(size=N))
    skip = UInt32(rng.integers(5, 3005, N).astype(np.uint32))
    walk = kernel.closest_hit(o, d, 0.0, t_best, prim, b1, b2, skip)
    batch = kernel.closest_hit(o, d, 0.0, t_best, prim, b1, b2, skip, batch=True)
    assert 0.2 < np.isfinite(walk[0].numpy()).mean() < 0.95
    for a, b in zip(walk, batch):
        np.testing.assert_array_equal(a.numpy(), b.numpy())


def test_batched_shadow_rays_are_the_walks(kernel_and_rays):
    kernel, o, d, rng = kernel_and_rays
    dist = Float(rng.uniform(0.01, 2.5, N))
    skip, target = (UInt32(rng.integers(5, 3005, N).astype(np.uint32)) for _ in range(2))
    active = Bool(rng.uniform(size=N) < 0.7)
    walk = kernel.occluded(o, d, dist, skip, target, active).numpy()
    batch = kernel.occluded(o, d, dist, skip, target, active, batch=True).numpy()
    assert 0.1 < walk.mean() < 0.6 and not walk[~active.numpy()].any()
    np.testing.assert_array_equal(walk, batch)
    nothing = kernel.occluded(o, d, dist, skip, target, Bool(False), batch=True).numpy()
    assert len(nothing) == N and not nothing.any()


def test_rays_that_enter_no_box_of_the_root_row_stay_out_of_the_batched_walk(kernel_and_rays, monkeypatch):
    """The root row's test before a batched walk (_enters_root) is the walk's first step: rays away from
    the triangles, or stopped before them, are left out of the batch, and every result stays the walk's."""
    import tracer.shapes.bvh as bvh

    kernel, _, _, rng = kernel_and_rays
    o = np.concatenate([rng.uniform(2, 3, (N, 3)), rng.uniform(2, 3, (N, 3))])   # beyond the triangles' box
    d = np.concatenate([o[:N] / np.linalg.norm(o[:N], axis=1, keepdims=True),     # away from it,
                        -o[N:] / np.linalg.norm(o[N:], axis=1, keepdims=True)])   # and towards its middle
    o, d = Array3f(*o.T), Array3f(*d.T)
    t_best = Float(np.concatenate([np.full(N, np.inf), np.where(rng.uniform(size=N) < 0.5, 0.5, np.inf)]))
    enters = kernel._enters_root(o, d, t_best).numpy()
    assert not enters[:N].any() and 0.3 < enters[N:].mean() < 0.7    # the stopped half enters nothing
    walked = []
    compress = dr.compress
    monkeypatch.setattr(bvh.dr, "compress", lambda m: walked.append(dr.count(m)) or compress(m))
    prim, b = UInt32(np.full(2 * N, NO_PRIM, np.uint32)), Float(np.zeros(2 * N))
    batch = kernel.closest_hit(o, d, 0.0, t_best, prim, b, b, UInt32(NO_PRIM), batch=True)
    assert walked == [enters.sum()]
    walk = kernel.closest_hit(o, d, 0.0, t_best, prim, b, b, UInt32(NO_PRIM))
    assert np.isfinite(walk[0].numpy()[N:]).mean() > 0.2
    for a, c in zip(walk, batch):
        np.testing.assert_array_equal(a.numpy(), c.numpy())


def _paths(geo, scene, trace):
    """Radiance and rays of 16 x 16 pixels at 4 spp traced by `trace` (the integrator's loop)."""
    sample = UInt32(np.arange(16 * 16 * 4, dtype=np.uint32))
    rng = seeded_rng(sample, 7)
    o, d, t_min, t_max, _, _ = primary_rays(scene.camera, sample // 4, rng)
    path = path_integrator.PathState(o, d, t_min, t_max, Bool(True))
    L, rays = trace(geo, rng, path, path_integrator._bounce, opaque_u32(5), opaque_u32(scene.rr_depth))
    return L.numpy(), rays.numpy()


@pytest.mark.parametrize("tail", [0, 300])
def test_paths_bounce_by_bounce_are_the_paths_in_one_kernel(monkeypatch, tail):
    """The Cornell box with its blocks in a BVH: the same radiance and ray counts to the bit, every bounce
    batched (tail 0) or the last paths, from `tail` on (of 1,024), in one kernel."""
    scene = tracer.load_scene(SCENES / "cornell_box.xml", width=16, height=16)
    geo = SceneGeometry(scene, bvh_threshold=0)
    one_kernel = _paths(geo, scene, path_integrator._megakernel)
    monkeypatch.setattr(path_integrator, "TAIL_LANES", tail)
    bounces, bounce = [], path_integrator._bounce
    monkeypatch.setattr(path_integrator, "_bounce", lambda geo, rng, path, *a: bounces.append(dr.width(path.o))
                        or bounce(geo, rng, path, *a))
    wavefront = _paths(geo, scene, path_integrator._wavefront)
    assert one_kernel[1].min() >= 1 and one_kernel[1].max() > 5   # paths of several bounces
    assert bounces[0] == 1024 and min(bounces) > tail          # batched bounces down to the tail
    for a, b in zip(one_kernel, wavefront):
        np.testing.assert_array_equal(a, b)
    used = []
    monkeypatch.setattr(path_integrator, "_wavefront", lambda *a: used.append(a) or one_kernel)
    PathEstimator(5).samples(geo, scene, UInt32(0), UInt32(0), 1)
    assert not used                    # a BVH but no envmap: one kernel (geometry.goes_bounce_by_bounce)
    monkeypatch.setattr(geometry_module, "ALWAYS_BOUNCE_BY_BOUNCE", True)
    PathEstimator(5).samples(geo, scene, UInt32(0), UInt32(0), 1)
    assert bool(used) == BATCHED_WALKS                # bounce by bounce (on the CPU)


def test_the_plan_counts_a_wavefronts_memory(tmp_path, monkeypatch):
    from validation.benchmark.mesh_scene import write_mesh_scene

    room = tracer.load_scene(SCENES / "hexagon_room.xml", width=64, height=64)
    meshes = tracer.load_scene(write_mesh_scene(tmp_path, 3000), width=64, height=64)
    assert meshes.triangle_count > BVH_THRESHOLD >= room.triangle_count
    estimator = PathEstimator(5)
    assert make_plan(room, 16, estimator, 0).launch_bytes == 64 * 64 * 16 * PATH_LANE_BYTES
    assert make_plan(meshes, 16, estimator, 0).launch_bytes == 64 * 64 * 16 * PATH_LANE_BYTES   # no envmap
    monkeypatch.setattr(geometry_module, "ALWAYS_BOUNCE_BY_BOUNCE", True)
    lane_bytes = WAVEFRONT_LANE_BYTES if BATCHED_WALKS else PATH_LANE_BYTES
    assert make_plan(meshes, 16, estimator, 0).launch_bytes == 64 * 64 * 16 * lane_bytes
    # a geometry built with another threshold: the plan follows what it holds
    brute = SceneGeometry(meshes, bvh_threshold=meshes.triangle_count)
    assert make_plan(meshes, 16, estimator, 0, geometry=brute).launch_bytes == 64 * 64 * 16 * PATH_LANE_BYTES
    assert make_plan(meshes, 16, estimator, 0, geometry=SceneGeometry(meshes)).launch_bytes == 64 * 64 * 16 * lane_bytes


def test_the_branching_estimators_levels_walk_the_bvh_batched(monkeypatch, request):
    """The report estimator's levels are in memory: their closest hits go batched, with the same image
    (with one Dr.Jit thread: the estimator adds its rays' radiance atomically, in any order with two)."""
    from contextlib import nullcontext

    import drjit as dr

    from tracer.rendering import render

    threads = dr.thread_count()
    dr.set_thread_count(1)
    request.addfinalizer(lambda: dr.set_thread_count(threads))

    scene = tracer.load_scene(SCENES / "cornell_box.xml", width=12, height=12)
    geo = SceneGeometry(scene, bvh_threshold=0)
    walks = []
    batch = geo.meshes.bvh._walk_batch
    monkeypatch.setattr(geo.meshes.bvh, "_walk_batch", lambda *a, **kw: walks.append(1) or batch(*a, **kw))
    batched = render(scene, "report", spp=2, seed=3, max_depth=4, direct=2, indirect=2, geometry=geo).image
    assert bool(walks) == BATCHED_WALKS
    monkeypatch.setattr(geo, "batched", nullcontext)
    in_kernel = render(scene, "report", spp=2, seed=3, max_depth=4, direct=2, indirect=2, geometry=geo).image
    np.testing.assert_array_equal(batched, in_kernel)


def test_a_batch_of_another_size_compiles_no_kernel_anew(kernel_and_rays):
    """The batch's size enters the walk's kernel as an opaque value: each bounce of a render (a batch of
    its own size) runs the same kernels (a literal made one per bounce, compiled anew for every render
    of another size or spp: over a second). Compared by kernel hash, whatever Dr.Jit's disk cache holds."""
    kernel, o, d, rng = kernel_and_rays
    dist = Float(rng.uniform(0.01, 2.5, N))
    none = UInt32(NO_PRIM)
    walks = [kernel_hashes(lambda: kernel.occluded(o, d, dist, none, none, Bool(rng.uniform(size=N) < p),
                                                   batch=True).numpy()) for p in (0.9, 0.8, 0.6)]
    assert walks[2] and walks[2] == walks[1]     # (the first walk's kernel may differ by a lazily made table)


def test_another_bvh_of_the_same_depth_compiles_no_kernel_anew(kernel_and_rays):
    """The grid's origin and step and the root row (tested before a batched walk) enter the kernels as
    values in memory, not literals: a scene's first render finds its kernels in Dr.Jit's cache wherever its
    meshes lie (as literals they cost a new scene 0.15-0.2 s of compilation). Compared by kernel hash."""
    kernel, o, d, rng = kernel_and_rays
    tris = rng.uniform(-1, 1, (3000, 1, 3)) + rng.uniform(-0.08, 0.08, (3000, 3, 3))
    other = BVHKernel.over(tris * 2.0 + 3.0, prim_base=5)   # other boxes, another root row
    assert other.stack_size == kernel.stack_size and not np.array_equal(other.grid.origin, kernel.grid.origin)
    none = UInt32(NO_PRIM)

    def queries(k, o):    # as many rays enter either BVH, so that their batches are alike
        return lambda: [dr.eval(*k.closest_hit(o, d, 0.0, Float(np.inf), none, Float(0), Float(0), none, batch=True)),
                        dr.eval(k.occluded(o, d, Float(1.0), none, none, Bool(True), batch=True))]

    here, moved = o * 1.5 - 0.25, o * 2.0 + 3.0   # both in Dr.Jit's memory (a kernel's inputs' alignment is in it)
    dr.eval(here, moved)
    for k, origins in ((kernel, here), (other, moved)):   # first runs: tables made lazily
        queries(k, origins)()
    assert kernel_hashes(queries(kernel, here)) == kernel_hashes(queries(other, moved))


def test_a_batch_of_one_ray_is_its_walk(kernel_and_rays):
    """A batch of a single ray (the last path still going, say): its payload holds one value, which the
    batch must copy into buffers of their own before scattering into them."""
    kernel, o, d, _ = kernel_and_rays
    one_o, one_d = (Array3f(*v.numpy()[:, :1]) for v in (o, d))
    none = UInt32(NO_PRIM)
    walk = kernel.closest_hit(one_o, one_d, 0.0, Float(2.0), none, Float(0), Float(0), none)
    batch = kernel.closest_hit(one_o, one_d, 0.0, Float(2.0), none, Float(0), Float(0), none, batch=True)
    for a, b in zip(walk, batch):
        np.testing.assert_array_equal(a.numpy(), b.numpy())
    assert (kernel.occluded(one_o, one_d, Float(9.0), none, none, batch=True).numpy()
            == kernel.occluded(one_o, one_d, Float(9.0), none, none).numpy()).all()


def test_unbounded_paths_bounce_by_bounce_are_the_paths_in_one_kernel(tmp_path, monkeypatch, request):
    """max_depth -1: the last bounces hold a few paths, down to one."""
    import drjit as dr

    from tracer.rendering import render
    from validation.benchmark.mesh_scene import write_mesh_scene

    scene = tracer.load_scene(write_mesh_scene(tmp_path, 3000), width=12, height=12)
    geo = SceneGeometry(scene)
    monkeypatch.setattr(geometry_module, "ALWAYS_BOUNCE_BY_BOUNCE", True)   # it has no envmap
    assert geo.bounce_by_bounce == BATCHED_WALKS
    threads = dr.thread_count()
    dr.set_thread_count(1)        # the film adds samples atomically: in any order with two threads
    request.addfinalizer(lambda: dr.set_thread_count(threads))
    monkeypatch.setattr(path_integrator, "TAIL_LANES", 0)   # every bounce batched
    bounces = render(scene, "path", spp=4, seed=2, max_depth=-1, geometry=geo)
    monkeypatch.setattr(path_integrator, "_wavefront", path_integrator._megakernel)
    one_kernel = render(scene, "path", spp=4, seed=2, max_depth=-1, geometry=geo)
    assert bounces.rays == one_kernel.rays
    np.testing.assert_array_equal(bounces.image, one_kernel.image)


def test_scenes_with_a_mesh_bvh_under_an_envmap_go_bounce_by_bounce():
    """The rest go in one kernel (geometry.goes_bounce_by_bounce); describe() says which."""
    room = SceneGeometry(tracer.load_scene(SCENES / "hexagon_room.xml"))
    box = SceneGeometry(tracer.load_scene(SCENES / "cornell_box.xml"), bvh_threshold=0)
    constant = SceneGeometry(tracer.load_scene(SCENES / "constant_environment.xml"), bvh_threshold=0)
    sky = SceneGeometry(tracer.load_scene(SCENES / "environment_map.xml"), bvh_threshold=0)
    assert all(g.meshes.bvh is not None for g in (box, constant, sky)) and sky.envmap is not None
    assert not room.bounce_by_bounce and not box.bounce_by_bounce and not constant.bounce_by_bounce
    assert sky.bounce_by_bounce == BATCHED_WALKS
    for geo in (room, box, constant, sky):
        assert any("bounce by bounce" in line for line in geo.describe()) == geo.bounce_by_bounce


@pytest.mark.parametrize("count", [[0, 3, 1, 0, 0, 2, 8], [5], [1, 1, 1], [0, 0, 4], [0, 0]])
def test_a_levels_children_are_each_parents_slots_in_order(count):
    from tracer.integrators.report import _children

    parent, slot = _children(UInt32(count))
    assert list(zip(parent.numpy().tolist(), slot.numpy().tolist())) == \
        [(p, s) for p, c in enumerate(count) for s in range(c)]


@pytest.mark.parametrize("tail", [0, path_integrator.TAIL_LANES])
def test_a_new_mesh_scene_of_the_same_structure_compiles_no_kernel_anew(tmp_path, monkeypatch, tail):
    """Two scenes that differ only in their meshes' sizes and shapes (BVHs of the same depth) render with the
    same kernels: no primitive count, box or root row is a literal in them (a new scene's first render
    compiled 0.4-0.7 s of kernels before). Compared by kernel hash."""
    from validation.benchmark.bench import _sphere_scene
    from tracer.rendering import render

    scenes = []
    for n in (2000, 2600):
        folder = tmp_path / str(n)
        folder.mkdir()
        scenes.append(tracer.load_scene(_sphere_scene(folder, n), width=16, height=16))
    geos = [SceneGeometry(s) for s in scenes]
    assert geos[0].meshes.count != geos[1].meshes.count
    assert geos[0].meshes.bvh.stack_size == geos[1].meshes.bvh.stack_size
    monkeypatch.setattr(path_integrator, "TAIL_LANES", tail)   # 0: every bounce batched; else all in one kernel
    monkeypatch.setattr(geometry_module, "ALWAYS_BOUNCE_BY_BOUNCE", tail == 0)   # (the scenes have no envmap)
    runs = [lambda s=s, g=g: render(s, "path", spp=2, max_depth=4, geometry=g) for s, g in zip(scenes, geos)]
    for run in runs:
        run()
    first, second = kernel_hashes(runs[0]), kernel_hashes(runs[1])
    assert len(first) > (5 if tail == 0 else 0) and first == second
