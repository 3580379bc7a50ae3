"""Where the room's path render goes, for `validate bench` (section `ceiling`): the render against the
brute-force closest-hit ceiling, by phase.

The room is small enough that the path tracer traces it in one kernel (no BVH), so its phases cannot be
timed apart; they are measured by ablation instead, in one process, the variants interleaved round by
round (so that the load of a shared machine weighs on each alike) and timed in the process's CPU seconds
(all its threads), the fastest of ROUNDS renders:
- `full`: the render as the tracer runs it;
- `unblocked`: every shadow ray answered "not blocked" without being traced (the rest unchanged);
- `no_nee`: no emitter sampling (Strategies(emitter=0)): no light sample, BSDF evaluation, shadow ray or MIS;
- `camera`: max_depth 1: camera rays, their closest hits, emission and the film.
With the ceiling (closest-hit queries on random rays, the same kernel as geometry.closest_hit, no shading)
these give: closest-hit queries = the render's closest hits / the ceiling's rate; shadow queries = full -
unblocked; the rest of next-event estimation (light sample, BSDF evaluation, MIS) = full - no_nee - shadow
queries; camera and film = camera - its closest hits; each bounce's surface, BSDF sampling and Russian
roulette = no_nee - camera - the bounces' closest hits. Images of the ablated variants are discarded.

In one kernel a lane's masked-off code runs with its packet unless no lane of the packet takes it. A packet's
paths reach their last vertex (depth + 1 = max_depth) together, and there the path tracer samples no light and
no BSDF (integrators.path): the camera variant's one vertex scatters nowhere, and the full render scatters
at max_depth - 1 of its max_depth vertices.
"""
from __future__ import annotations

import json
import sys
import time

import numpy as np

SIZE, SPP, MAX_DEPTH = 600, 16, 5
ROUNDS = 3
CEILING_RAYS = 1 << 23
VARIANTS = ("full", "unblocked", "no_nee", "camera")


def _ceiling(geo) -> dict:
    """Closest-hit rays per wall and per CPU second on random rays from inside the room (the fastest of 8
    launches after a warm-up)."""
    import drjit as dr

    from tracer.jit import NO_PRIM, Array3f, UInt32

    rng = np.random.default_rng(0)
    o = Array3f(*(np.array([4, 0, 0]) + rng.uniform(-2, 2, (CEILING_RAYS, 3))).T)
    d = rng.normal(size=(CEILING_RAYS, 3))
    d = Array3f(*(d / np.linalg.norm(d, axis=1, keepdims=True)).T)
    dr.eval(o, d)
    wall, cpu = [], []
    for _ in range(9):
        w, c = time.perf_counter(), time.process_time()
        h = geo.closest_hit(o, d, 0.0, float("inf"), UInt32(NO_PRIM))
        dr.eval(h.t, h.prim)
        dr.sync_thread()
        wall.append(time.perf_counter() - w)
        cpu.append(time.process_time() - c)
    return {"rays_per_second": CEILING_RAYS / min(wall[1:]), "rays_per_cpu_second": CEILING_RAYS / min(cpu[1:])}


def profile(scene_path: str) -> dict:
    import tracer
    import tracer.estimators as estimators
    from tracer.geometry import SceneGeometry
    from tracer.integrators.path import Strategies
    from tracer.jit import Bool
    from tracer.rendering import render

    scene = tracer.load_scene(scene_path, width=SIZE, height=SIZE)
    geo = SceneGeometry(scene)
    occluded = SceneGeometry.occluded

    def variant(name: str, seed: int) -> tuple[float, float, int]:
        SceneGeometry.occluded = (lambda *a, **k: Bool(False)) if name == "unblocked" else occluded
        estimators.Strategies = (lambda *a: Strategies(0, 1)) if name == "no_nee" else Strategies
        try:
            w, c = time.perf_counter(), time.process_time()
            r = render(scene, "path", spp=SPP, max_depth=1 if name == "camera" else MAX_DEPTH, seed=seed,
                       geometry=geo)
            return time.perf_counter() - w - r.compile_seconds, time.process_time() - c, r.rays
        finally:
            SceneGeometry.occluded, estimators.Strategies = occluded, Strategies

    out = {name: {"wall": [], "cpu": []} for name in VARIANTS}
    for name in VARIANTS:
        variant(name, 0)                       # compiles
    ceiling = [_ceiling(geo)]
    for k in range(ROUNDS):
        for name in VARIANTS if k % 2 == 0 else VARIANTS[::-1]:
            wall, cpu, rays = variant(name, k + 1)
            out[name]["wall"].append(wall)
            out[name]["cpu"].append(cpu)
            out[name]["rays"] = rays
    ceiling.append(_ceiling(geo))
    return {"variants": out, "ceiling": {key: max(c[key] for c in ceiling) for key in ceiling[0]},
            "settings": {"size": SIZE, "spp": SPP, "max_depth": MAX_DEPTH, "rounds": ROUNDS}}


def phases(p: dict) -> dict:
    """CPU seconds of the full render by phase (see the module's docstring), from profile()'s result."""
    v, rate = p["variants"], p["ceiling"]["rays_per_cpu_second"]
    t = {name: min(x["cpu"]) for name, x in v.items()}
    closest, camera_hits = v["no_nee"]["rays"], v["camera"]["rays"]
    shadow = t["full"] - t["unblocked"]
    return {"closest-hit queries": closest / rate,
            "shadow-ray queries": shadow,
            "light sample, BSDF evaluation and MIS": t["full"] - t["no_nee"] - shadow,
            "camera rays, their surfaces, emission and film": t["camera"] - camera_hits / rate,
            "surface, BSDF sampling, Russian roulette": t["no_nee"] - t["camera"] - (closest - camera_hits) / rate,
            "full": t["full"]}


if __name__ == "__main__":
    print(json.dumps(profile(sys.argv[1])))
