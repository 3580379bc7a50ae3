"""Where a mesh scene's ray time goes, for `validate bench`: the tracer's closest-hit and shadow-ray queries
alone (no shading) on the same random rays as Mitsuba's (Embree's) `ray_intersect_preliminary` and
`ray_test`, and the tracer's BVH work per ray (4-wide node rows visited, triangles tested; a counting copy of the
traversal, tracer.shapes.bvh.BVHKernel.closest_hit_work), and from it a packet's work per lane against its
busiest lane's when each lane walks its own ray to its end (the in-kernel walk: a packet keeps walking until
its longest walk ends), which the batched walk (BVHKernel._walk_batch) recovers.

The rays start uniformly inside the scene's bounding box, in uniformly random directions; shadow rays are
the same rays cut to a length uniform in (0, the distance at which they leave the box): both ends in the
scene, as a render's shadow rays (the tracer leaves out of its shadow rays the walls that such a segment
never crosses). Each query is launched LAUNCHES times after a warm-up launch (which compiles it); the median
counts. Both renderers' fractions of rays that hit and of shadow rays blocked are kept: equal fractions show
that both answered the same queries.
"""
from __future__ import annotations

import statistics
import time
from contextlib import contextmanager

import numpy as np

RAYS = 1 << 20
LAUNCHES = 5
REPLAYS = 3            # timed replays of a render's rays
REPLAY_OFFSET = 1e-4   # a replayed ray's start past its recorded origin, and its end short of its own, in extents
PACKET = 16        # lanes of an AVX-512 packet of 32-bit values, as Dr.Jit's LLVM backend runs a kernel


def random_rays(lo: np.ndarray, hi: np.ndarray, n: int = RAYS, seed: int = 0):
    """(origins, unit directions, shadow-ray lengths), float32 (n, 3), (n, 3), (n,)."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    o = lo + (hi - lo) * rng.uniform(0.02, 0.98, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    with np.errstate(divide="ignore"):
        exit = np.min(np.abs(np.where(d > 0, hi - o, lo - o)) / np.abs(d), axis=1)   # where the ray leaves the box
    dist = rng.uniform(0, 1, n) * exit
    return o.astype(np.float32), d.astype(np.float32), dist.astype(np.float32)


def _timed(*launches, runs: int | None = None) -> float:
    """Median seconds of `runs` (default LAUNCHES) runs of the launches in turn, each evaluated before the
    next, after a warm-up run."""
    import drjit as dr

    seconds = []
    for k in range((LAUNCHES if runs is None else runs) + 1):
        start = time.perf_counter()
        for launch in launches:
            dr.eval(*launch())
        dr.sync_thread()
        seconds.append(time.perf_counter() - start)
    return statistics.median(seconds[1:])


def profile_tracer(geometry) -> dict:
    """Rays per second of the tracer's queries and its BVH work per closest-hit ray."""
    from tracer.jit import NO_PRIM, Array3f, Float, UInt32

    from tracer.shapes.bvh import layout
    from tracer.shapes.bvh_build import build, sah_cost

    points = geometry.meshes.tri_vertices.reshape(-1, 3)
    o, d, dist = random_rays(points.min(axis=0), points.max(axis=0))
    o, d, dist = Array3f(*o.T), Array3f(*d.T), Float(dist)
    none = UInt32(NO_PRIM)

    def closest():
        h = geometry.closest_hit(o, d, 0.0, float("inf"), none)
        return h.t, h.prim

    def shadow():
        return (geometry.occluded(o, d, dist, none, none),)

    out = {"rays": RAYS, "closest_seconds": _timed(closest), "shadow_seconds": _timed(shadow)}
    with geometry.batched():   # the walks the path tracer and the report estimator's levels use
        out.update(closest_batch_seconds=_timed(closest), shadow_batch_seconds=_timed(shadow))
    hit = closest()[1]
    out["hit_fraction"] = float(np.mean(hit.numpy() != NO_PRIM))
    out["blocked_fraction"] = float(np.mean(shadow()[0].numpy()))
    if geometry.meshes.bvh is not None:
        start = time.perf_counter()
        layout(geometry.meshes.tri_vertices)
        out["bvh_build_seconds"] = time.perf_counter() - start
        out["bvh_sah_cost"] = sah_cost(build(geometry.meshes.tri_vertices))   # the tree's quality
        steps, tests = (a.numpy() for a in geometry.meshes.bvh.closest_hit_work(o, d))
        work = (steps + tests)[:len(steps) // PACKET * PACKET].reshape(-1, PACKET)
        out.update(steps_mean=float(steps.mean()), steps_p90=float(np.percentile(steps, 90)),
                   packet_busy=float(work.mean() / work.max(axis=1).mean()),
                   tests_mean=float(tests.mean()), tests_p90=float(np.percentile(tests, 90)),
                   bvh_rows=len(geometry.meshes.bvh.rows), bvh_depth=geometry.meshes.bvh.stack_size)
    return out


@contextmanager
def every_bounce_batched():
    """Within: the path tracer goes bounce by bounce (tracer.geometry.ALWAYS_BOUNCE_BY_BOUNCE: also without
    an envmap, where a render goes in one kernel) and walks every bounce's rays batched
    (tracer.integrators.path.TAIL_LANES 0; a render's last few paths otherwise go on in one kernel, their
    walks inside it), so that every walk is timed or recorded."""
    import tracer.geometry as geometry
    import tracer.integrators.path as path

    saved = path.TAIL_LANES, geometry.ALWAYS_BOUNCE_BY_BOUNCE
    path.TAIL_LANES, geometry.ALWAYS_BOUNCE_BY_BOUNCE = 0, True
    try:
        yield
    finally:
        path.TAIL_LANES, geometry.ALWAYS_BOUNCE_BY_BOUNCE = saved


def profile_render(render_once) -> dict:
    """Where one render's time goes: render_once() -> its seconds, run (after an untimed render that compiles
    its kernels) with every bounce's BVH walks batched and timed (every_bounce_batched,
    tracer.shapes.bvh.timed_walks: each walk waits for its inputs and its end, so this render takes a little
    longer than an untimed one). Returns its seconds and those of the closest-hit and shadow walks, and the
    fraction of each query's rays that were walked (the others enter no child box of the BVH's root row)."""
    from tracer.shapes.bvh import timed_walks

    with every_bounce_batched():
        render_once()         # its kernels compiled first: a timed walk would count their compilation
        with timed_walks() as walks:
            seconds = render_once()
    closest, shadow = walks.get("closest hit", 0.0), walks.get("shadow", 0.0)
    out = {"timed_render_seconds": seconds, "closest_walk_seconds": closest, "shadow_walk_seconds": shadow,
           "rest_seconds": seconds - closest - shadow}
    for query, key in (("closest hit", "closest"), ("shadow", "shadow")):
        if walks.get(f"{query}: rays"):
            out[f"{key}_walked_fraction"] = walks[f"{query}: walked"] / walks[f"{query}: rays"]
    return out


def profile_render_rays(geometry, render_once, mitsuba_scene) -> dict:
    """One render's own rays replayed through both renderers' queries: the tracer's (SceneGeometry's
    closest_hit and occluded, batched as in a render) and Mitsuba's (Embree's) `ray_intersect_preliminary`
    and `ray_test` on `mitsuba_scene`, the same scene loaded by Mitsuba; seconds summed over the render's
    batches, the median of REPLAYS replays after a warm-up. Each ray starts REPLAY_OFFSET (of the
    scene's extent) along its direction from its recorded origin and stops as far short of its end, on
    both sides (Mitsuba cannot skip the primitive a ray leaves, as the tracer does). Also each renderer's
    fraction of the shadow rays blocked (equal fractions: the same queries)."""
    import drjit as dr
    import mitsuba as mi

    from tracer.geometry import recorded_queries
    from tracer.jit import NO_PRIM, Array3f, Float, UInt32

    with recorded_queries() as queries, every_bounce_batched():
        render_once()
    eps = REPLAY_OFFSET * geometry.scene.extent()
    batches = [(q, o + eps * d, d, np.maximum(t - 2 * eps, 0)) for q, o, d, t in queries if len(o)]
    ours = [(q, Array3f(*o.T), Array3f(*d.T), Float(t)) for q, o, d, t in batches]
    theirs = [(q, mi.Ray3f(mi.Ray3f(mi.Point3f(*o.T), mi.Vector3f(*d.T)), mi.Float(np.minimum(t, 3e38))))
              for q, o, d, t in batches]
    none = UInt32(NO_PRIM)

    def ours_query(q, o, d, t):
        if q == "closest hit":
            return (geometry.closest_hit(o, d, 0.0, t, none).prim,)
        return (geometry.occluded(o, d, t, none, none),)

    def theirs_query(q, ray):
        return (mitsuba_scene.ray_intersect_preliminary(ray).t,) if q == "closest hit" else \
            (mitsuba_scene.ray_test(ray),)

    out = {"replayed_rays": int(sum(len(o) for _, o, _, _ in batches))}
    with geometry.batched():
        for query, key in (("closest hit", "closest"), ("shadow", "shadow")):
            mine = [x for x in ours if x[0] == query]
            out[f"replay_{key}_seconds"] = _timed(*(lambda x=x: ours_query(*x) for x in mine), runs=REPLAYS)
            out[f"replay_{key}_seconds_mitsuba"] = _timed(
                *(lambda x=x: theirs_query(*x) for x in theirs if x[0] == query), runs=REPLAYS)
        shadow = [x for x in ours if x[0] == "shadow"]
        if shadow:
            out["replay_blocked_fraction"] = float(np.mean(np.concatenate([ours_query(*x)[0].numpy() for x in shadow])))
            out["replay_blocked_fraction_mitsuba"] = float(np.mean(np.concatenate(
                [np.array(theirs_query(*x)[0]) for x in theirs if x[0] == "shadow"])))
    dr.sync_thread()
    return out


def profile_mitsuba(mi, scene) -> dict:
    """Rays per second of Mitsuba's preliminary intersection and shadow test on the same rays."""
    bbox = scene.bbox()
    mesh_lo = np.full(3, np.inf)
    mesh_hi = -mesh_lo
    for shape in scene.shapes():
        if shape.is_mesh() and shape.face_count() > 2:   # the meshes (rectangles are 2 triangles)
            b = shape.bbox()
            mesh_lo, mesh_hi = np.minimum(mesh_lo, np.array(b.min)), np.maximum(mesh_hi, np.array(b.max))
    if not np.isfinite(mesh_lo).all():
        mesh_lo, mesh_hi = np.array(bbox.min), np.array(bbox.max)
    o, d, dist = random_rays(mesh_lo, mesh_hi)
    origin, direction = mi.Point3f(*o.T), mi.Vector3f(*d.T)
    ray = mi.Ray3f(origin, direction)
    short = mi.Ray3f(ray, mi.Float(dist))   # Ray3f(o, d, x) would take x as the time, leaving maxt infinite

    def closest():
        pi = scene.ray_intersect_preliminary(ray)
        return pi.t, pi.prim_index

    return {"rays": RAYS, "closest_seconds": _timed(closest),
            "shadow_seconds": _timed(lambda: (scene.ray_test(short),)),
            "hit_fraction": float(np.mean(np.isfinite(np.array(closest()[0])))),
            "blocked_fraction": float(np.mean(np.array(scene.ray_test(short))))}
