"""`validate bench`: the tracer and Mitsuba timed side by side in one run, written to reports/performance.md.

Every measurement runs in a child process (so its peak resident memory is its own), renders once to
warm Dr.Jit's kernel cache and then REPEATS times; tables quote the median. Cold start is the first
render in a child whose kernel cache is empty (HOME pointed at a fresh folder).
"""
from __future__ import annotations

import json
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from tracer.estimators import REPORT_DEPTH_OFFSET

from .instances import instances as instance_section, markdown as instance_markdown
from .mesh_scene import write_mesh_scene
from .scene_bench import (compile_tracer, light_replaced, markdown as scene_markdown, scenes as scene_section,
                          tiled_light_cornell_box)

ROOT = Path(__file__).resolve().parents[2]
ROOM = ROOT / "mitsuba_scenes" / "hexagon_room.xml"
REPEATS = 3
# The report's own render times (its Tables 1 and 2, 600 x 600, one ray per pixel, M = 8).
REPORT_TABLE1 = {8: 120.93, 16: 208.80, 64: 751.50}
REPORT_TABLE2 = {1: 27.97, 2: 208.80, 3: 1554.18}
MESH_FOLDER = ROOT / ".cache" / "bench"      # the generated mesh scenes (validation/benchmark/mesh_scene.py)
MESH_TRIANGLES = (250_000, 1_000_000)
MESH_SPP, MESH_DEPTH, MESH_SIZE = 64, 5, 256
NEW_SCENE_TRIANGLES = (11000, 13000)   # cold start: two UV-sphere scenes whose BVHs have the same depth
LIGHT_TILES = (12, 16)                 # cold start: the Cornell box with its light cut into n x n rectangles
WHOLE_RUNS = 3                                  # whole-process runs of each renderer, alternated
# The memory section: mitsuba-renderer/mitsuba-data's docs scenes (one per kind of content the tracer renders:
# an environment map around serialized meshes in a BVH, area lights, spheres, PLY meshes, textures), at their
# own size and MEMORY_DOCS_SPP spp: three or more launches, past the first, after which memory stays flat.
MEMORY_DOCS = ("bsdf_dielectric_glass", "bsdf_diffuse_plain", "bsdf_conductor_gold", "bsdf_plastic_default",
               "bsdf_twosided_cbox", "shape_ply_bunny", "shape_sphere_basic", "texture_checkerboard",
               "integrator_depth_inf")
MEMORY_DOCS_SPP = 4


# ---- child side --------------------------------------------------------------------------------------
def _child(job: dict) -> dict:
    """Runs one job in this (child) process and returns its timings."""
    if job["renderer"] == "mitsuba":
        from ..verdict.mitsuba_render import mitsuba

        mi = mitsuba()
        start = time.perf_counter()
        scene = mi.load_file(job["scene"], **job["params"])   # builds Embree's BVH
        setup = time.perf_counter() - start
        split = {}

        def run(seed):
            start = time.perf_counter()
            image = np.array(mi.render(scene, seed=seed))
            return image[..., :3], time.perf_counter() - start, 0.0, 0
    else:
        import tracer
        from tracer.geometry import SceneGeometry
        from tracer.materials import CONDUCTOR, DIELECTRIC, DIFFUSE
        from tracer.rendering import render

        options = {}
        if job.get("bvh_threshold") is not None:
            options["bvh_threshold"] = job["bvh_threshold"]
        if job.get("generic"):  # every material's code in the kernel, whatever the scene holds
            options["material_kinds"] = {DIFFUSE, CONDUCTOR, DIELECTRIC}
        start = time.perf_counter()
        scene = tracer.load_scene(job["scene"], **job["params"])
        loaded = time.perf_counter()
        geometry = SceneGeometry(scene, **options)   # builds the BVH, reused by every render below
        setup = time.perf_counter() - start
        split = {"load_seconds": loaded - start, "geometry_seconds": setup - (loaded - start),
                 "triangles": geometry.meshes.count, "tracer_package": str(Path(tracer.__file__).resolve().parent)}

        def run(seed):
            r = render(scene, job["estimator"], seed=seed, geometry=geometry, **job["options"])
            return r.image, r.render_seconds, r.compile_seconds, r.rays

    def run_timed(seed):   # and the process's CPU seconds (every thread's): steadier than wall time under load
        start = time.process_time()
        return *run(seed), time.process_time() - start

    first = run_timed(0)
    runs = [run_timed(seed) for seed in range(1, job.get("repeats", REPEATS) + 1)]
    import resource

    out = {"setup_seconds": setup, "first_seconds": first[1] + first[2], "first_compile": first[2],
           "seconds": [r[1] for r in runs], "cpu_seconds": [r[4] for r in runs],
           "rays": runs[-1][3], "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
    out.update(split)
    if job.get("profile"):
        from .mesh_profile import profile_mitsuba, profile_render, profile_render_rays, profile_tracer

        if job["renderer"] == "mitsuba":
            out["profile"] = profile_mitsuba(mi, scene)
        else:
            from ..verdict.mitsuba_render import mitsuba

            render_once = lambda: run(REPEATS + 1)[1]   # noqa: E731
            out["profile"] = (profile_tracer(geometry) | profile_render(render_once)
                              | profile_render_rays(geometry, render_once,
                                                    mitsuba().load_file(job["scene"], **job["params"])))
            out["setup_cached_seconds"] = _setup_from_disk_cache(job)
    if job.get("save_image"):
        np.save(job["save_image"], runs[-1][0])
    return out


def _setup_from_disk_cache(job: dict) -> float:
    """The tracer's setup (as in _child) in a process that has built the scene's BVH before: the BVH read
    from the on-disk cache (shapes.bvh_cache), the meshes read again (this process's caches emptied)."""
    import tracer
    from tracer import meshes
    from tracer.geometry import SceneGeometry
    from tracer.shapes import bvh_cache

    def setup() -> float:
        bvh_cache.clear_memory()
        meshes._read_obj.cache_clear()
        start = time.perf_counter()
        SceneGeometry(tracer.load_scene(job["scene"], **job["params"]))
        return time.perf_counter() - start

    before = os.environ.get(bvh_cache.ENV)
    with tempfile.TemporaryDirectory() as tmp:
        os.environ[bvh_cache.ENV] = tmp
        try:
            setup()           # builds and stores the BVH
            return setup()    # reads it back
        finally:
            if before is None:
                del os.environ[bvh_cache.ENV]
            else:
                os.environ[bvh_cache.ENV] = before


def measure(job: dict, cold: bool = False, home: str | None = None, tracer_root: Path | None = None) -> dict:
    """Runs `job` in a child process; adds the median seconds and the child's peak RSS in MB. `cold`: with
    an empty Dr.Jit kernel cache (a new HOME), or `home`: with that HOME's. `tracer_root`: another checkout
    whose `tracer` package the child imports (this one's benchmark code runs it: validation.benchmark.ab)."""
    env = dict(os.environ)
    if job.get("renderer") == "tracer":
        env.setdefault("OPENBLAS_NUM_THREADS", "1")   # as the tracer command runs (tracer.cli.main)
        env["TRACER_BVH_CACHE"] = "off"              # setup builds its BVH; the whole-process runs time the cache
    tmp = tempfile.TemporaryDirectory() if cold else None
    if tmp or home:
        env["HOME"] = tmp.name if tmp else home
    cwd = tempfile.TemporaryDirectory() if tracer_root else None
    if cwd:   # `python -m` puts its folder first on sys.path: there `tracer` is the other checkout's
        (Path(cwd.name) / "tracer").symlink_to(Path(tracer_root).resolve() / "tracer")
        (Path(cwd.name) / "validation").symlink_to(ROOT / "validation")
    proc = subprocess.Popen([sys.executable, "-m", "validation.benchmark.bench", "--child", json.dumps(job)],
                            cwd=cwd.name if cwd else ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    out, err = proc.communicate()
    for folder in (tmp, cwd):
        if folder:
            folder.cleanup()
    if proc.returncode != 0:
        raise RuntimeError(f"benchmark job failed: {err.strip().splitlines()[-1] if err.strip() else proc.returncode}")
    result = json.loads(out.strip().splitlines()[-1])
    result["median"] = statistics.median(result["seconds"])
    return result


# ---- the benchmark -----------------------------------------------------------------------------------
def _tracer(estimator: str, size: int = 600, scene: Path = ROOM, **options) -> dict:
    return {"renderer": "tracer", "scene": str(scene), "estimator": estimator,
            "params": {"width": size, "height": size}, "options": options}


def _mitsuba(spp: int, max_depth: int, size: int = 600, scene: Path = ROOM) -> dict:
    return {"renderer": "mitsuba", "scene": str(scene),
            "params": {"width": size, "height": size, "spp": spp, "max_depth": max_depth}}


def side_by_side(out: Path, progress) -> dict:
    """Path estimator vs Mitsuba's path: 600 x 600, 64 spp, max_depth 5, with RMSE against a reference."""
    from ..verdict.metrics import rmse
    from ..verdict.references import reference

    ref = reference(ROOM, 5, 600, 16, 32)
    rows = {}
    for name, job in (("tracer path", _tracer("path", spp=64, max_depth=5)), ("Mitsuba path", _mitsuba(64, 5))):
        progress(name)
        job["save_image"] = str(out / f".{name.replace(' ', '_')}.npy")
        r = measure(job)
        image = np.load(job["save_image"])
        Path(job["save_image"]).unlink()
        r["rmse"] = rmse(image, ref)
        r["samples_per_second"] = 600 * 600 * 64 / r["median"]
        rows[name] = r
    # RMSE falls as 1/sqrt(time) for both (validation reports): time to equal RMSE = t * (rmse / target)^2
    target = min(r["rmse"] for r in rows.values())
    for r in rows.values():
        r["seconds_to_common_rmse"] = r["median"] * (r["rmse"] / target) ** 2
    rows["reference_spp"] = ref.spp
    return rows


def report_tables(progress) -> dict:
    """The report's Tables 1 and 2 at 600 x 600, one camera ray per pixel, M = 8."""
    rows = {}
    for label, n, depth in [("N=8", 8, 2), ("N=16", 16, 2), ("N=64", 64, 2), ("D=1", 16, 1), ("D=3", 16, 3)]:
        progress(f"report estimator {label}")
        job = _tracer("report", spp=1, direct=n, indirect=8, max_depth=depth + REPORT_DEPTH_OFFSET)
        job["repeats"] = 1 if depth == 3 or n == 64 else REPEATS
        rows[label] = measure(job)
    rows["D=2"] = rows["N=16"]
    rows["whole process"] = report_whole_process(progress)
    return rows


REPORT_COMMAND = ["--estimator", "report", "--report-depth", "2", "-N", "16", "-M", "8", "--size", "600x600"]


def report_whole_process(progress) -> dict:
    """Wall seconds of `tracer render` in the report's configuration (REPORT_COMMAND on the room), from
    process start to the written EXR and PNG: a run that warms Dr.Jit's kernel cache, then WHOLE_RUNS timed
    ones, the tracer's modules compiled to bytecode first (scene_bench.compile_tracer)."""
    compile_tracer()
    seconds = []
    with tempfile.TemporaryDirectory() as tmp:
        command = [sys.executable, "-m", "tracer.cli", "render", str(ROOM), *REPORT_COMMAND, "-o", f"{tmp}/r.exr"]
        for k in range(WHOLE_RUNS + 1):
            progress(f"report configuration, whole process, run {k}" if k else "report configuration, warm-up")
            start = time.perf_counter()
            subprocess.run(command, cwd=ROOT, check=True, capture_output=True)
            seconds.append(time.perf_counter() - start)
    return {"seconds": seconds[1:], "median": statistics.median(seconds[1:])}


def ceiling(progress) -> dict:
    """Closest-hit rays per second of the room's brute-force kernel on random rays (no shading)."""
    progress("closest-hit ceiling")
    code = (
        "import time, numpy as np, tracer, drjit as dr\n"
        "from tracer.geometry import SceneGeometry\n"
        "from tracer.jit import Array3f, UInt32, NO_PRIM\n"
        f"g = SceneGeometry(tracer.load_scene({str(ROOM)!r}))\n"
        "rng = np.random.default_rng(0); n = 1 << 23\n"
        "o = Array3f(*(np.array([4, 0, 0]) + rng.uniform(-2, 2, (n, 3))).T)\n"
        "d = rng.normal(size=(n, 3)); d /= np.linalg.norm(d, axis=1, keepdims=True); d = Array3f(*d.T)\n"
        "dr.eval(o, d); ts = []\n"
        "for _ in range(9):\n"
        "    t = time.perf_counter(); h = g.closest_hit(o, d, 0.0, float('inf'), UInt32(NO_PRIM)); dr.eval(h.t, h.prim); dr.sync_thread()\n"
        "    ts.append(time.perf_counter() - t)\n"
        "print(n / min(ts[1:]))\n")   # a ceiling: the least disturbed of 8 timed launches
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    progress("the room's path render by phase, against the ceiling (validation/benchmark/room_profile.py)")
    profile = subprocess.run([sys.executable, "-m", "validation.benchmark.room_profile", str(ROOM)], cwd=ROOT,
                             capture_output=True, text=True, check=True)
    return {"rays_per_second": float(out.stdout.strip().splitlines()[-1]),
            "room_path": json.loads(profile.stdout.strip().splitlines()[-1])}


def specialisation(progress) -> dict:
    """The kernel traced from the scene against one carrying every material's code (Cornell box: diffuse
    only), path estimator, 600 x 600, 16 spp, max_depth 6; and the room's one light against two."""
    rows = {}
    scene = ROOT / "mitsuba_scenes" / "cornell_box.xml"
    for label, generic in (("specialised", False), ("all materials", True)):
        progress(f"Cornell box, {label} kernel")
        job = _tracer("path", scene=scene, spp=16, max_depth=6)
        job["generic"] = generic
        rows[label] = measure(job)
    with tempfile.TemporaryDirectory() as tmp:
        for label, scene in (("one light", ROOM), ("two lights", _split_light_room(Path(tmp)))):
            progress(f"hexagon room, {label}")
            rows[label] = measure(_tracer("path", scene=scene, spp=16, max_depth=5))
    return rows


def _split_light_room(folder: Path) -> Path:
    """The room with its light cut into two halves of the same radiance: the same image in expectation,
    but a kernel that selects between two lights."""
    half = ('<shape type="rectangle"><transform name="to_world"><rotate x="1" angle="180"/>'
            '<scale x="1" y="1"/><translate x="{x}" y="0" z="4.9"/></transform>'
            '<bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>'
            '<emitter type="area"><rgb name="radiance" value="32"/></emitter></shape>')
    return light_replaced(ROOM, half.format(x=3) + half.format(x=5), folder, "hexagon_room_two_lights")


def cold_start(progress) -> dict:
    """The room's first render with an empty kernel cache; a new mesh scene's first render with the cache
    holding only the kernels of another (a UV sphere of another size in the Cornell box, a BVH of the same
    depth: kernels free of the scene's sizes and boxes come from the cache); and the same for the Cornell
    box with its light cut into n x n tiles (LIGHT_TILES: a BVH of rectangles, lights from a table)."""
    progress("cold start")
    job = _tracer("path", size=600, spp=1, max_depth=5)
    job["repeats"] = 1
    out = measure(job, cold=True)
    out["mesh_scenes"] = _first_renders(progress, "triangles", 4, [
        (n, f"a mesh scene of {n:,} triangles", lambda folder, n=n: _sphere_scene(folder, n))
        for n in NEW_SCENE_TRIANGLES])
    out["light_scenes"] = _first_renders(progress, "lights", 6, [
        (n * n, f"the Cornell box with {n * n} lights", lambda folder, n=n: tiled_light_cornell_box(folder, n))
        for n in LIGHT_TILES])
    return out


def _first_renders(progress, key: str, max_depth: int, scenes: list) -> list[dict]:
    """Each scene's first render (path, 256 x 256, 16 spp), in turn, each in a process of its own, the kernel
    cache empty before the first. `scenes`: (size, description, a function writing the scene into a folder);
    each measurement is returned with its size as `key`."""
    out = []
    with tempfile.TemporaryDirectory() as home, tempfile.TemporaryDirectory() as tmp:
        for size, description, write in scenes:
            progress(f"cold start, {description}")
            job = _tracer("path", size=256, scene=write(Path(tmp)), spp=16, max_depth=max_depth)
            job["repeats"] = 1
            out.append(measure(job, home=home) | {key: size})
    return out


def scaling(progress) -> dict:
    """Time against resolution, samples, depth (path estimator) and primitive count (BVH or brute force)."""
    curves: dict[str, list] = {"resolution": [], "spp": [], "max_depth": [], "triangles": [], "setup": []}
    for size in (100, 200, 400, 600):
        progress(f"resolution {size}")
        curves["resolution"].append((size * size, measure(_tracer("path", size=size, spp=16, max_depth=5))["median"]))
    for spp in (4, 16, 64):
        progress(f"spp {spp}")
        curves["spp"].append((spp, measure(_tracer("path", size=300, spp=spp, max_depth=5))["median"]))
    for depth in (2, 3, 5, 8, -1):
        progress(f"max_depth {depth}")
        curves["max_depth"].append((depth, measure(_tracer("path", size=300, spp=16, max_depth=depth))["median"]))
    with tempfile.TemporaryDirectory() as tmp:
        for n in (100, 1000, 10_000, 100_000):
            scene = _sphere_scene(Path(tmp), n)
            triangles = _triangles(scene)
            for kind, threshold in (("bvh", 0), ("brute force", 10**9), ("Mitsuba", None)):
                if kind == "brute force" and n > 2000:
                    continue
                progress(f"{n} triangles, {kind}")
                if threshold is None:
                    job = _mitsuba(16, 4, size=256, scene=scene)
                else:
                    job = _tracer("path", size=256, scene=scene, spp=16, max_depth=4)
                    job["bvh_threshold"] = threshold
                result = measure(job)
                curves["triangles"].append((kind, triangles, result["median"]))
                curves["setup"].append((kind, triangles, result["setup_seconds"]))
    return curves


def _light_scene_lines(scenes: list[dict] | None) -> list[str]:
    """The cold-start section's tiled-light scenes, where the run measured them."""
    if not scenes:
        return []
    first, second = scenes
    return [f"A scene of many lights, the kernel cache empty, then holding only the first's kernels (the Cornell "
            f"box with its light cut into {first['lights']} then {second['lights']} rectangles, path, 256 x 256, "
            f"16 spp, max_depth 6, each in a process of its own): the first's first render compiles for "
            f"{first['first_compile']:.2f} s (its render {first['median']:.2f} s once compiled), the second's "
            f"for {second['first_compile']:.2f} s (its render {second['median']:.2f} s).", ""]


def _new_scene_lines(scenes: list[dict] | None) -> list[str]:
    """The cold-start section's new mesh scene, where the run measured it."""
    if not scenes:
        return []
    first, second = scenes
    return [f"A new mesh scene, the kernel cache empty but for another's (the Cornell box with UV spheres of "
            f"{first['triangles']:,} then {second['triangles']:,} triangles, path, 256 x 256, 16 spp, max_depth 4, "
            f"each in a process of its own): the first scene's first render compiles for "
            f"{first['first_compile']:.2f} s, the second's for {second['first_compile']:.2f} s (a scene's sizes "
            "and boxes enter the kernels as run-time constants, `tracer.jit.opaque_u32`).", ""]


def _sphere_scene(folder: Path, n: int) -> Path:
    """The Cornell box with both blocks replaced by a UV sphere of about n triangles each."""
    seg = max(4, int(np.sqrt(n / 2)))
    rings = max(2, n // (2 * seg))
    theta, phi = np.meshgrid(np.linspace(0, np.pi, rings + 1), np.linspace(0, 2 * np.pi, seg, endpoint=False),
                             indexing="ij")
    v = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1).reshape(-1, 3)
    r, s = np.meshgrid(np.arange(rings), np.arange(seg), indexing="ij")
    a, b = r * seg + s, r * seg + (s + 1) % seg
    c, d = a + seg, b + seg
    faces = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    mesh = folder / f"sphere_{n}.obj"
    mesh.write_text("".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in v)
                    + "".join(f"f {i + 1} {j + 1} {k + 1}\n" for i, j, k in faces))
    text = (ROOT / "mitsuba_scenes" / "cornell_box.xml").read_text()
    text = text.replace('value="meshes/cube.obj"', f'value="{mesh}"')
    scene = folder / f"cbox_{n}.xml"
    scene.write_text(text)
    return scene


def _triangles(scene: Path) -> int:
    import tracer

    return tracer.load_scene(scene).triangle_count


def meshes(progress) -> dict:
    """The project's multi-mesh scene (validation/benchmark/mesh_scene.py) at MESH_TRIANGLES: render only and setup
    (in one child per renderer, with the ray-query profile of validation/benchmark/mesh_profile.py), and the whole
    process (`tracer render` against the `mitsuba` command, same XML and defines, alternated)."""
    rows = {}
    for n in MESH_TRIANGLES:
        progress(f"mesh scene of {n:,} triangles: writing")
        scene = write_mesh_scene(MESH_FOLDER, n)
        jobs = {"tracer": _tracer("path", size=MESH_SIZE, scene=scene, spp=MESH_SPP, max_depth=MESH_DEPTH),
                "Mitsuba": _mitsuba(MESH_SPP, MESH_DEPTH, size=MESH_SIZE, scene=scene)}
        row = {}
        for name, job in jobs.items():
            progress(f"mesh scene of {n:,} triangles: {name}, render only and profile")
            row[name] = measure(job | {"profile": True})
        for name, job in reversed(jobs.items()):   # again, in the other order: a drift of the machine's speed
            progress(f"mesh scene of {n:,} triangles: {name}, render only again")   # then weighs on both alike
            _pool(row[name], measure(job))
        row["triangles"] = row["tracer"]["triangles"]
        row["whole"] = whole_process(scene, lambda what: progress(f"mesh scene of {n:,} triangles: {what}"))
        rows[str(n)] = row
    return rows


def _pool(first: dict, second: dict) -> None:
    """Adds a second child's renders and setup to the first's measurement: medians over both children."""
    first["seconds"] = first["seconds"] + second["seconds"]
    first["median"] = statistics.median(first["seconds"])
    first["setup_runs"] = [first["setup_seconds"], second["setup_seconds"]]
    first["setup_seconds"] = statistics.median(first["setup_runs"])


def whole_process(scene: Path, progress) -> dict:
    """Wall seconds of `tracer render` (without and with a warm on-disk BVH cache) and of the `mitsuba`
    command on `scene` (-D spp, max_depth, width, height), WHOLE_RUNS each, alternated in turn, the
    tracer's modules compiled to bytecode first (scene_bench.compile_tracer)."""
    compile_tracer()
    defines = [f"spp={MESH_SPP}", f"max_depth={MESH_DEPTH}", f"width={MESH_SIZE}", f"height={MESH_SIZE}"]
    defines = [x for d in defines for x in ("-D", d)]
    times: dict[str, list[float]] = {"tracer": [], "tracer, BVH from disk cache": [], "Mitsuba": []}
    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp) / "bvh"
        commands = {
            "tracer": [sys.executable, "-m", "tracer.cli", "render", str(scene), "-o", f"{tmp}/t.exr", "--no-png",
                       *defines],
            "Mitsuba": [str(Path(sys.executable).parent / "mitsuba"), "-m", "llvm_ad_rgb", *defines,
                        "-o", f"{tmp}/m.exr", str(scene)],
        }
        commands["tracer, BVH from disk cache"] = commands["tracer"]
        env = {name: dict(os.environ) for name in times}
        for e in env.values():
            e["TRACER_BVH_CACHE"] = "off"
        env["tracer, BVH from disk cache"]["TRACER_BVH_CACHE"] = str(cache)
        subprocess.run([sys.executable, "-c", "import sys, tracer; from tracer.geometry import SceneGeometry; "
                        "SceneGeometry(tracer.load_scene(sys.argv[1]))", str(scene)],
                       cwd=ROOT, env=env["tracer, BVH from disk cache"], check=True)   # fills the cache
        names = list(times)
        for k in range(WHOLE_RUNS):
            for name in names[k % len(names):] + names[:k % len(names)]:   # each renderer first in turn
                progress(f"whole process, {name}, run {k + 1}")
                start = time.perf_counter()
                subprocess.run(commands[name], cwd=ROOT, env=env[name], check=True, capture_output=True)
                times[name].append(time.perf_counter() - start)
    return {name: {"seconds": t, "median": statistics.median(t)} for name, t in times.items()}


# `tracer render` in a child that writes its own peak resident set (VmHWM) at exit: wait4's ru_maxrss would also
# count the parent's pages the child held between fork and exec (the bench's own ~200 MB).
_PEAK_CHILD = """import atexit, os, sys
def _peak():
    with open("/proc/self/status") as f, open(os.environ["TRACER_PEAK_FILE"], "w") as out:
        out.write(next(line.split()[1] for line in f if line.startswith("VmHWM:")))
atexit.register(_peak)
from tracer.cli import main
sys.exit(main(sys.argv[1:]))
"""


def peak_memory(scene: Path, defines: list[str] = ()) -> dict:
    """`tracer render SCENE` in a child process: the plan's estimate of peak memory (as it prints it) and the
    child's peak resident set (its VmHWM at exit), both in MiB, and its wall seconds."""
    with tempfile.TemporaryDirectory() as tmp:
        peak = Path(tmp) / "peak"
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", TRACER_BVH_CACHE="off", TRACER_PEAK_FILE=str(peak))
        start = time.perf_counter()   # the BVH is built, as on a scene's first render
        run = subprocess.run([sys.executable, "-c", _PEAK_CHILD, "render", str(scene), "-o", f"{tmp}/m.exr",
                              "--no-png", "--quiet", *defines], cwd=ROOT, env=env, capture_output=True, text=True)
        seconds = time.perf_counter() - start
        if run.returncode != 0:
            raise RuntimeError(f"tracer render {scene.name} failed ({run.returncode}): {run.stderr.strip()[-300:]}")
        peak_kib = int(peak.read_text())
    found = re.search(r"peak memory about ([\d.]+) (MiB|GiB)", run.stdout)
    estimate = float(found[1]) * (1024 if found[2] == "GiB" else 1)
    size = re.search(r" at (\d+) x (\d+), (\d+) spp", run.stdout)
    return {"estimate_mib": estimate, "peak_mib": peak_kib / 1024, "seconds": seconds,
            "settings": f"{size[1]} x {size[2]}, {size[3]} spp"}


def memory(progress, mitsuba_data: Path | None = None) -> dict:
    """The plan's estimate of peak memory against the peak measured (peak_memory): every project scene at its
    own settings, and, given a copy of mitsuba-data, its MEMORY_DOCS scenes at MEMORY_DOCS_SPP spp."""
    scenes = [(f"mitsuba_scenes/{p.name}", p, []) for p in sorted((ROOT / "mitsuba_scenes").glob("*.xml"))]
    if mitsuba_data is not None:
        scenes += [(f"docs/scenes/{name}.xml", mitsuba_data / "docs" / "scenes" / f"{name}.xml",
                    ["-D", f"spp={MEMORY_DOCS_SPP}"]) for name in MEMORY_DOCS]
    rows = {}
    for name, path, defines in scenes:
        progress(f"memory: {name}")
        rows[name] = peak_memory(path, defines)
    return {"rows": rows, "docs": mitsuba_data is not None}


def memory_markdown(section: dict) -> list[str]:
    """The memory section of the report: estimate, measured peak and their ratio per scene."""
    rows = section["rows"]
    ratios = {name: r["peak_mib"] / r["estimate_mib"] for name, r in rows.items()}
    worst = max(ratios, key=lambda n: max(ratios[n], 1 / ratios[n]))
    docs = (f"and `mitsuba-renderer/mitsuba-data`'s docs scenes that show each kind of content the tracer renders, "
            f"at their own size and {MEMORY_DOCS_SPP} spp (three or more launches)" if section["docs"] else
            "(mitsuba-data's docs scenes not measured in this run: `--mitsuba-data` not given)")
    lines = ["## Memory: the plan's estimate against the measured peak", "",
             "`tracer render SCENE` in a process of its own (BVHs built, no on-disk cache): the peak memory the plan "
             "prints before the first ray (`tracer/plan.py`: the process, the scene's meshes and textures, film "
             "and images, one launch) against the process's peak resident set (its `VmHWM` at exit). The project's "
             "scenes at "
             f"their own settings {docs}. Ratio: measured / estimate.", "",
             "| scene | settings | estimate [MiB] | measured peak [MiB] | ratio |", "|---|---|---:|---:|---:|"]
    for name, r in rows.items():
        lines.append(f"| {name} | {r['settings']} | {r['estimate_mib']:.0f} | {r['peak_mib']:.0f} | "
                     f"{ratios[name]:.2f} |")
    lines += ["", f"Ratios from {min(ratios.values()):.2f} to {max(ratios.values()):.2f} (furthest from 1: {worst}).",
              ""]
    return lines


def main_child(arg: str) -> None:
    print(json.dumps(_child(json.loads(arg))))


if __name__ == "__main__" and len(sys.argv) > 2 and sys.argv[1] == "--child":
    main_child(sys.argv[2])


OPTIONAL = ("against",)   # sections run only when named: they need an argument (--against)


def sections(mitsuba_data: Path | None = None, scene_options: dict | None = None,
             against: tuple[Path, int] | None = None) -> dict:
    """The bench's sections by name, in the order they run (`mitsuba_data`: a copy of mitsuba-data, whose
    docs scenes the memory section measures too and whose scenes the scenes section times; `scene_options`:
    the scenes section's caps, as validation.scene_bench.scenes takes them; `against`: another checkout and
    the rounds to time it in, validation.benchmark.ab)."""
    from .ab import against as ab

    def other(out, progress):
        if against is None:
            from tracer.errors import UserError

            raise UserError("validate bench: the section 'against' needs --against TREE")
        return ab(progress, *against)

    return {"side_by_side": lambda out, progress: side_by_side(out, progress),
            "tables": lambda out, progress: report_tables(progress),
            "ceiling": lambda out, progress: ceiling(progress),
            "cold": lambda out, progress: cold_start(progress),
            "specialisation": lambda out, progress: specialisation(progress),
            "scaling": lambda out, progress: scaling(progress),
            "meshes": lambda out, progress: meshes(progress),
            "memory": lambda out, progress: memory(progress, mitsuba_data),
            "scenes": lambda out, progress: scene_section(progress, mitsuba_data, **(scene_options or {})),
            "instances": lambda out, progress: instance_section(progress),
            "against": other}


def without_paths(results):
    """`results` without the children's "tracer_package" (the folder on the machine that ran them, which
    validate bench --against checks and the report does not keep)."""
    if isinstance(results, dict):
        return {k: without_paths(v) for k, v in results.items() if k != "tracer_package"}
    if isinstance(results, list):
        return [without_paths(v) for v in results]
    return results


def run(out: Path, only: list[str] | None = None, mitsuba_data: Path | None = None,
        scene_options: dict | None = None, against: tuple[Path, int] | None = None) -> str:
    """Every measurement (or only the sections named, the others kept from the previous run's
    performance.json), then reports/performance.md and its plot; returns the markdown."""
    from datetime import datetime, timezone

    from tracer.errors import UserError

    from ..reports.plots import performance_scaling, scene_ratios

    out.mkdir(parents=True, exist_ok=True)
    progress = lambda what: print(f"bench: {what}", file=sys.stderr, flush=True)  # noqa: E731
    previous = out / "performance.json"
    results = json.loads(previous.read_text()) if only and previous.exists() else {}
    unknown = set(only or ()) - set(sections())
    if unknown:
        raise UserError(f"unknown bench sections {sorted(unknown)}; the sections are {list(sections())}")
    missing = [name for name in sections() if name not in results and name not in (only or ())
               and name not in OPTIONAL]
    if only and missing:
        raise UserError(f"{previous} has no {missing}: run those sections too")
    today = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    results.setdefault("when", {})
    results.setdefault("load", {})
    for name, section in sections(mitsuba_data, scene_options, against).items():
        if (not only and name not in OPTIONAL) or name in (only or ()):
            before = os.getloadavg()[0]
            results[name] = section(out, progress)
            results["when"][name] = today
            results["load"][name] = [before, os.getloadavg()[0]]   # other work on the machine, 1-min averages
    previous.write_text(json.dumps(without_paths(results), indent=1))
    performance_scaling(results["scaling"], out / "performance_scaling.png")
    if "ratio" in json.dumps(results["scenes"]):
        scene_ratios({n: r["ratio"] for n, r in results["scenes"]["rows"].items() if "ratio" in r},
                     out / "performance_scenes.png")
    text = markdown(results)
    (out / "performance.md").write_text(text)
    return text


def _machine() -> str:
    import drjit
    import mitsuba

    cpu = platform.processor() or platform.machine()
    try:
        cpu = next(l.split(":", 1)[1].strip() for l in Path("/proc/cpuinfo").read_text().splitlines()
                   if l.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return (f"{cpu}, {os.cpu_count()} cores; Python {platform.python_version()}, Dr.Jit {drjit.__version__} (LLVM), "
            f"Mitsuba {mitsuba.__version__} (llvm_ad_rgb)")


def markdown(r: dict) -> str:
    sbs, tables, scaling = r["side_by_side"], r["tables"], r["scaling"]
    ours, theirs = sbs["tracer path"], sbs["Mitsuba path"]
    when = r.get("when", {})
    measured = [name for name in sections() if name not in OPTIONAL or name in r]
    dates = sorted(set(when.get(name, "an earlier run") for name in measured))
    provenance = (f"all numbers from one run, {dates[0]}" if len(dates) == 1 else
                  "sections from separate runs: " + "; ".join(f"{name} {when.get(name, 'an earlier run')}"
                                                               for name in measured))
    load = r.get("load", {})
    lines = [
        "# Performance: the tracer and Mitsuba side by side",
        "",
        f"Generated by `validate bench` ({provenance}; medians of "
        f"{REPEATS} renders after a warm-up render, each configuration in its own process). Machine: {_machine()}.",
        "Machine load (1-minute load average at the start and end of each section, "
        f"{os.cpu_count()} cores): " + ("; ".join(f"{name} {a:.1f}–{b:.1f}" for name, (a, b) in load.items())
                                        or "not recorded") + ".",
        "Timings are render time without kernel compilation; peak memory is the process's maximum resident set.",
        "",
        "## Path tracing: the tracer against Mitsuba's `path` (hexagon_room, 600 x 600, 64 spp, max_depth 5)",
        "",
        "| renderer | render time [s] | samples/s | rays/s | peak memory [MB] | RMSE | time to common RMSE [s] |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name in ("tracer path", "Mitsuba path"):
        x = sbs[name]
        rays = f"{x['rays'] / x['median'] / 1e6:.1f} M" if x["rays"] else "–"
        lines.append(f"| {name} | {x['median']:.2f} | {x['samples_per_second'] / 1e6:.2f} M | {rays} | "
                     f"{x['peak_mb']:.0f} | {x['rmse']:.4f} | {x['seconds_to_common_rmse']:.2f} |")
    lines += [
        "",
        f"Samples per second: the tracer / Mitsuba = **{ours['samples_per_second'] / theirs['samples_per_second']:.2f}x**. "
        f"Time to the same RMSE: the tracer needs **{ours['seconds_to_common_rmse'] / theirs['seconds_to_common_rmse']:.2f}x** "
        f"Mitsuba's time (RMSE against a {sbs['reference_spp']}-spp Mitsuba reference with its variance subtracted; "
        "the time to a common RMSE assumes error falling as 1/sqrt(time), which the validation reports' fitted slopes support).",
        "",
        "## The report's tables (hexagon_room, 600 x 600, one camera ray per pixel, M = 8)",
        "",
        "| configuration | max_depth | rays | render time [s] | the report's time [s] | speed-up | rays/s | peak memory [MB] |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for label, report_s in [("N=8", REPORT_TABLE1[8]), ("N=16", REPORT_TABLE1[16]), ("N=64", REPORT_TABLE1[64]),
                            ("D=1", REPORT_TABLE2[1]), ("D=2", REPORT_TABLE2[2]), ("D=3", REPORT_TABLE2[3])]:
        x = tables[label]
        depth = int(label[2:]) + 2 if label.startswith("D") else 4
        lines.append(f"| {'N=16, report depth ' + label[2:] if label.startswith('D') else label + ', report depth 2'} "
                     f"| {depth} | {x['rays'] / 1e6:.0f} M | {x['median']:.2f} | {report_s:.2f} | {report_s / x['median']:.0f}x | "
                     f"{x['rays'] / x['median'] / 1e6:.0f} M | {x['peak_mb']:.0f} |")
    ceil = r["ceiling"]["rays_per_second"]
    n16 = tables["N=16"]
    lines += [
        "",
        "The report's times are its own (its C++ code on its author's machine).",
    ]
    if "whole process" in tables:   # absent from runs before it was measured
        whole = tables["whole process"]
        lines += [
            "",
            f"The N = 16, report depth 2 configuration from process start to the written EXR and PNG (`tracer render "
            f"mitsuba_scenes/hexagon_room.xml {' '.join(REPORT_COMMAND)}`, Dr.Jit's kernel cache warm, the modules "
            f"compiled to bytecode): **{whole['median']:.2f} s**, median of {len(whole['seconds'])} runs "
            f"({min(whole['seconds']):.2f}–{max(whole['seconds']):.2f} s).",
        ]
    same_run = when.get("ceiling") == when.get("tables")
    report_rate = (f"The report estimator at N = 16 reaches {n16['rays'] / n16['median'] / 1e6:.0f} M rays/s "
                   f"({n16['rays'] / n16['median'] / ceil:.2f} of it; the ceiling is the fastest of 8 launches, the "
                   "estimator a median of 3 renders). " if same_run else
                   "(The report estimator's rays per second, in the tables above, come from another run, under "
                   "another load: not compared.) ")
    lines += [
        "",
        "## Rays per second against the brute-force ceiling",
        "",
        f"The room's closest-hit kernel alone (random rays, no shading, brute force over its 21 primitives) traces "
        f"**{ceil / 1e6:.0f} M rays/s**. " + report_rate +
        "Most of the report estimator's rays are shadow rays, which test only the primitives that can "
        "block them (the room's walls are left out), so its rate is not bounded by this one; beyond its ray queries, "
        "its time goes to light sampling and BRDF evaluation in the shadow-ray kernel, the compaction of each level's "
        "rays (`dr.compress`) and the gathers that build the next level.",
        "",
        *room_profile_markdown(r["ceiling"].get("room_path")),
        "## A kernel traced from the scene",
        "",
        "The Cornell box holds only diffuse surfaces: its kernel has no mirror or dielectric code. Forcing both in "
        f"(path, 600 x 600, 16 spp, max_depth 6): {r['specialisation']['all materials']['median']:.2f} s against "
        f"{r['specialisation']['specialised']['median']:.2f} s specialised "
        f"({r['specialisation']['all materials']['median'] / r['specialisation']['specialised']['median']:.2f}x). "
        "Light sampling is unrolled per light in the same way (one light: no light selection at all). The room "
        "with its light cut into two halves (the same image in expectation; path, 600 x 600, 16 spp, max_depth 5): "
        f"{r['specialisation']['two lights']['median']:.2f} s against {r['specialisation']['one light']['median']:.2f} s "
        f"with one light ({r['specialisation']['two lights']['median'] / r['specialisation']['one light']['median']:.2f}x).",
        "",
        "## Cold start",
        "",
        f"First render with an empty Dr.Jit kernel cache (path, 600 x 600, 1 spp, max_depth 5): "
        f"{r['cold']['first_seconds']:.2f} s, of which {r['cold']['first_compile']:.2f} s kernel generation and compilation; "
        f"the same render with the cache warm: {r['cold']['median']:.2f} s.",
        "",
        *_new_scene_lines(r["cold"].get("mesh_scenes")),
        *_light_scene_lines(r["cold"].get("light_scenes")),
        "## Scaling",
        "",
        "![time against pixels, samples, depth and triangles](performance_scaling.png)",
        "",
        "The Cornell box with both blocks replaced by a UV sphere of n triangles each; path, 256 x 256, 16 spp, "
        "max_depth 4. Render times exclude loading the scene; the last two columns give that time (reading "
        "the OBJ files and building the tracer's BVH, or Mitsuba's `load_file`, which builds Embree's).",
        "",
        "| triangles | BVH [s] | brute force [s] | Mitsuba (Embree) [s] | tracer scene setup [s] | Mitsuba load [s] |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    by_n: dict[int, dict] = {}
    for kind, n, t in scaling["triangles"]:
        by_n.setdefault(n, {})[kind] = t
    setup = {(kind, n): t for kind, n, t in scaling["setup"]}
    for n in sorted(by_n):
        cells = [by_n[n].get(kind) for kind in ("bvh", "brute force", "Mitsuba")]
        cells += [setup.get(("bvh", n)), setup.get(("Mitsuba", n))]
        lines.append(f"| {n:,} | " + " | ".join("–" if c is None else f"{c:.2f}" for c in cells) + " |")
    from tracer.shapes import BVH_THRESHOLD

    smallest, largest = min(by_n), max(by_n)
    ours = {n: min(t for k, t in by_n[n].items() if k != "Mitsuba") for n in (smallest, largest)}
    lines += ["", f"The largest mesh takes **{ours[largest] / ours[smallest]:.1f}x** the time of the "
              f"{smallest}-triangle scene (each with its faster kernel; the tracer uses the BVH above "
              f"`tracer.shapes.BVH_THRESHOLD` = {BVH_THRESHOLD} triangles). Mitsuba, whose meshes Embree traces, "
              f"takes {by_n[largest]['Mitsuba'] / by_n[smallest]['Mitsuba']:.1f}x.", ""]
    lines += mesh_markdown(r["meshes"])
    lines += memory_markdown(r["memory"])
    lines += instance_markdown(r["instances"])
    lines += scene_markdown(r["scenes"], "performance_scenes.png" if "ratio" in json.dumps(r["scenes"]) else None)
    from .ab import markdown as against_markdown

    lines += against_markdown(r.get("against"))
    return "\n".join(lines)


def room_profile_markdown(p: dict | None) -> list[str]:
    """The room's path render against the ceiling, by phase (validation/benchmark/room_profile.py)."""
    if not p:
        return []
    from .room_profile import phases

    s, v, c = p["settings"], p["variants"], p["ceiling"]
    full = v["full"]
    wall_rate, cpu_rate = full["rays"] / min(full["wall"]), full["rays"] / min(full["cpu"])
    t = phases(p)
    lines = [f"The path tracer on the room ({s['size']} x {s['size']}, {s['spp']} spp, max_depth {s['max_depth']}; "
             f"{full['rays'] / 1e6:.1f} M rays: {v['no_nee']['rays'] / 1e6:.1f} M closest hits, the rest shadow rays), "
             "in the process that measured the ceiling again (the fastest of its renders and of its launches): "
             f"**{wall_rate / c['rays_per_second']:.2f}** of the ceiling in wall time ({wall_rate / 1e6:.1f} M "
             f"against {c['rays_per_second'] / 1e6:.1f} M rays/s), **{cpu_rate / c['rays_per_cpu_second']:.2f}** in "
             f"CPU time ({cpu_rate / 1e6:.1f} M against {c['rays_per_cpu_second'] / 1e6:.1f} M rays per CPU second). "
             "Its CPU seconds by phase, measured by ablation (each variant rendered in turn, the fastest of "
             f"{s['rounds']} renders; `validation/benchmark/room_profile.py` says how each phase is derived):", "",
             "| phase | CPU [s] | share |", "|---|---:|---:|"]
    lines += [f"| {name} | {x:.3f} | {x / t['full']:.0%} |" for name, x in t.items() if name != "full"]
    lines += [f"| the render | {t['full']:.3f} | 100% |", "",
              "Ray queries are the first two rows; for the path tracer to reach 0.75 of the ceiling, everything "
              f"else would have to take at most {max(full['rays'] / (0.75 * c['rays_per_cpu_second']) - t['closest-hit queries'] - t['shadow-ray queries'], 0):.3f} "
              "CPU s. In one kernel a lane's masked-off code runs with its packet unless no lane of the packet "
              "takes it: a packet's paths reach their last vertex (depth + 1 = max_depth) together, where none "
              "samples a light or its BSDF.", ""]
    return lines


def _mesh_spread(row: dict) -> str:
    """A line of the mesh table's spreads: each figure's fastest and slowest run."""
    def spread(seconds: list[float]) -> str:
        return f"{min(seconds):.2f}–{max(seconds):.2f} ({len(seconds)})"

    t, m, w = row["tracer"], row["Mitsuba"], row["whole"]
    parts = [f"render: tracer {spread(t['seconds'])}, Mitsuba {spread(m['seconds'])}"]
    if "setup_runs" in t and "setup_runs" in m:   # a run from before they were kept has none
        parts.append(f"setup: tracer {spread(t['setup_runs'])}, Mitsuba {spread(m['setup_runs'])}")
    parts.append("whole process: " + ", ".join(f"{name} {spread(x['seconds'])}" for name, x in w.items()))
    return f"- {row['triangles']:,} triangles: " + "; ".join(parts) + "."


def mesh_markdown(rows: dict) -> list[str]:
    """The multi-mesh scene's section of the report."""
    lines = [
        "## Meshes: the project's multi-mesh scene",
        "",
        "The Cornell box's walls and light around three smooth meshes (angle-weighted vertex normals): a diffuse "
        "torus (40% of the triangles), a mirror (conductor) blob (40%) and a glass (dielectric) ellipsoid (20%), "
        "generated by `validation/benchmark/mesh_scene.py` into `.cache/bench`. Path, "
        f"{MESH_SIZE} x {MESH_SIZE}, {MESH_SPP} spp, max_depth {MESH_DEPTH}. Render only: median of {2 * REPEATS} "
        f"renders in two processes per renderer, run tracer, Mitsuba, Mitsuba, tracer (each process renders once "
        f"to warm up, then {REPEATS} times, the scene loaded once). Setup (the mean of the two processes'): the "
        "tracer's `load_scene` (XML, OBJ, normals) and `SceneGeometry` (BVH build, tables), Mitsuba's `load_file` "
        "(which builds Embree's BVH); the tracer's also in a process that built the scene before, its BVH read "
        "from the on-disk cache (the meshes read again). Whole process: "
        f"`tracer render` and `mitsuba -m llvm_ad_rgb`, same XML, `-D spp={MESH_SPP} -D max_depth={MESH_DEPTH} "
        f"-D width={MESH_SIZE} -D height={MESH_SIZE}`, wall time of the command including writing the EXR, "
        f"median of {WHOLE_RUNS} runs each, the renderers alternated (each first in turn); the tracer also with a "
        "warm on-disk BVH cache (`TRACER_BVH_CACHE`); the tracer's modules compiled to bytecode beforehand, as an "
        "installed package's are. Ratios: tracer / Mitsuba (below 1: the tracer is faster).",
        "",
        "| triangles | render: tracer [s] | Mitsuba [s] | ratio | setup: tracer [s] | tracer, cached BVH [s] "
        "| Mitsuba [s] | ratio (uncached, cached) | whole process: tracer [s] | tracer, cached BVH [s] | Mitsuba [s] "
        "| ratio (uncached, cached) |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in rows.values():
        t, m, w = row["tracer"], row["Mitsuba"], row["whole"]
        wt, wc, wm = w["tracer"]["median"], w["tracer, BVH from disk cache"]["median"], w["Mitsuba"]["median"]
        st, sm = t["setup_seconds"], m["setup_seconds"]
        sc = t.get("setup_cached_seconds")    # None in a run from before it was measured
        cached = (f"{sc:.2f}", f"{sc / sm:.2f}") if sc is not None else ("–", "–")
        lines.append(f"| {row['triangles']:,} | {t['median']:.2f} | {m['median']:.2f} | {t['median'] / m['median']:.2f} "
                     f"| {st:.2f} | {cached[0]} | {sm:.2f} | {st / sm:.2f}, {cached[1]} "
                     f"| {wt:.2f} | {wc:.2f} | {wm:.2f} | {wt / wm:.2f}, {wc / wm:.2f} |")
    lines += ["", "The runs behind each figure, fastest to slowest in seconds (how many runs in brackets):", ""]
    lines += [_mesh_spread(row) for row in rows.values()]
    lines += ["", "### Where the time goes", "",
              "Ray queries alone (no shading): 2^20 rays from random points inside the meshes' bounding box in "
              "random directions, closest hit (the tracer's `closest_hit`, Mitsuba's `ray_intersect_preliminary`) "
              "and the same rays as shadow rays (`occluded`, `ray_test`) ending at a random point before the "
              "box's side (both ends in the scene, as a render's shadow rays); median of 5 launches. "
              "BVH work per closest-hit ray is counted by a copy of the traversal that counts "
              "(`BVHKernel.closest_hit_work`). The tracer walks its BVH in two ways: inside the kernel that asks "
              "(each lane its own ray to the end, so a packet of lanes takes as many steps as its longest walk), or "
              "batched, over rays in memory, by persistent lanes that each take the next ray when theirs is done "
              "(`BVHKernel._walk_batch`). On the LLVM backend renders go bounce by bounce, their walks batched, only "
              "under an envmap (`tracer.geometry.goes_bounce_by_bounce`): this scene, lit by an area light, renders "
              "in one kernel. One more render, bounce by bounce with every walk batched "
              "(`validation.benchmark.mesh_profile.every_bounce_batched`), times its walks "
              "(`tracer.shapes.bvh.timed_walks`: each walk waits for its inputs and its end, so "
              "that render takes a little longer than the others). Another render's own rays are recorded "
              "(`tracer.geometry.recorded_queries`) and replayed through both renderers' queries, the whole "
              "scene's (the tracer's `SceneGeometry.closest_hit` and `occluded`, batched as in a render; Mitsuba's "
              "`ray_intersect_preliminary` and `ray_test`, in the tracer's process), each ray started and stopped "
              "1e-4 of the scene's extent inside its ends (Mitsuba cannot skip the primitive a ray leaves); "
              "seconds summed over the render's batches, median of 3 replays.",
              ""]
    header = "| | " + " | ".join(f"tracer, {row['triangles']:,} | Mitsuba, {row['triangles']:,}" for row in rows.values()) + " |"
    lines += [header, "|---|" + "---:|" * (2 * len(rows))]

    def cells(f_tracer, f_mitsuba) -> str:
        out = []
        for row in rows.values():
            for f, x in ((f_tracer, row["tracer"]), (f_mitsuba, row["Mitsuba"])):
                out.append(f(x) if f is not None else "–")
        return " | ".join(out)

    def replayed(key: str, fmt: str) -> str:   # the tracer's value and Mitsuba's (measured in its process)
        out = []
        for row in rows.values():
            p = row["tracer"]["profile"]
            out += [format(p[k], fmt) if k in p else "–" for k in (key, key + "_mitsuba")]
        return " | ".join(out)

    def number(key):   # "–" where a run from before the key was measured has none
        return lambda x: f"{x['profile'][key]:.2f}" if key in x["profile"] else "–"

    def rate(key):   # "–" where a run from before the key was measured has none
        return lambda x: f"{x['profile']['rays'] / x['profile'][key] / 1e6:.1f} M" if key in x["profile"] else "–"
    lines += [
        "| scene loading (XML, OBJ, normals) [s] | " + cells(lambda x: f"{x['load_seconds']:.2f}",
                                                         lambda x: f"{x['setup_seconds']:.2f} (with BVH)") + " |",
        "| BVH build alone [s] | " + cells(lambda x: f"{x['profile']['bvh_build_seconds']:.2f}", None) + " |",
        "| the BVH's SAH cost: a walk's expected triangle tests, of a ray through its root box (`bvh_build.sah_cost`) | "
        + cells(number("bvh_sah_cost"), None) + " |",
        "| geometry: BVH (or cache hit), tables [s] | " + cells(lambda x: f"{x['geometry_seconds']:.2f}", None) + " |",
        "| first render: kernel compile (Dr.Jit's kernel cache as the bench left it) [s] | " + cells(lambda x: f"{x['first_compile']:.2f}", None) + " |",
        "| render [s] | " + cells(lambda x: f"{x['median']:.2f}", lambda x: f"{x['median']:.2f}") + " |",
        "| the process's first render (its memory fresh; its kernels compiled, or read from the cache) [s] | "
        + cells(lambda x: f"{x['first_seconds']:.2f}", lambda x: f"{x['first_seconds']:.2f}") + " |",
        "| the process's peak resident memory after setup and 4 renders [MiB] | "
        + cells(lambda x: f"{x['peak_mb']:.0f}", lambda x: f"{x['peak_mb']:.0f}") + " |",
        "| rays traced per render (closest hit + shadow) | " + cells(lambda x: f"{x['rays'] / 1e6:.1f} M", None) + " |",
        "| a render with its BVH walks timed [s] | " + cells(number("timed_render_seconds"), None) + " |",
        "| of which closest-hit walks [s] | " + cells(number("closest_walk_seconds"), None) + " |",
        "| of which shadow-ray walks [s] | " + cells(number("shadow_walk_seconds"), None) + " |",
        "| of which the rest: camera rays, shading, light samples, compaction between bounces [s] | "
        + cells(number("rest_seconds"), None) + " |",
        "| a render's rays walked through the BVH, of those asked (closest hit, shadow; the others enter no "
        "child box of its root row) | " + cells(lambda x: f"{x['profile']['closest_walked_fraction']:.0%}, "
                                                  f"{x['profile']['shadow_walked_fraction']:.0%}"
                                        if "shadow_walked_fraction" in x["profile"] else "–", None) + " |",
        "| a render's own rays replayed: closest-hit queries [s] | " + replayed("replay_closest_seconds", ".2f") + " |",
        "| a render's own rays replayed: shadow queries [s] | " + replayed("replay_shadow_seconds", ".2f") + " |",
        "| a render's own rays replayed: shadow rays blocked | " + replayed("replay_blocked_fraction", ".3f") + " |",
        "| closest-hit queries alone, batched walk (the renders') [rays/s] | "
        + cells(rate("closest_batch_seconds"), rate("closest_seconds")) + " |",
        "| closest-hit queries alone, walk in the caller's kernel [rays/s] | " + cells(rate("closest_seconds"), None) + " |",
        "| shadow queries alone, batched walk (the renders') [rays/s] | "
        + cells(rate("shadow_batch_seconds"), rate("shadow_seconds")) + " |",
        "| shadow queries alone, walk in the caller's kernel [rays/s] | " + cells(rate("shadow_seconds"), None) + " |",
        "| a 16-lane packet's work (rows and triangles tested) per lane, against its busiest lane's, walk in "
        "the caller's kernel | "
        + cells(lambda x: f"{x['profile']['packet_busy']:.0%}" if "packet_busy" in x["profile"] else "–", None) + " |",
        "| random rays that hit | " + cells(lambda x: f"{x['profile']['hit_fraction']:.2f}",
                                            lambda x: f"{x['profile']['hit_fraction']:.2f}") + " |",
        "| random shadow rays blocked | " + cells(number("blocked_fraction"), number("blocked_fraction")) + " |",
        "| BVH node rows (4-wide) visited per closest-hit ray, revisits included (mean, p90) | "
        + cells(lambda x: f"{x['profile']['steps_mean']:.0f}, {x['profile']['steps_p90']:.0f}", None) + " |",
        "| triangles tested per closest-hit ray (mean, p90) | "
        + cells(lambda x: f"{x['profile']['tests_mean']:.0f}, {x['profile']['tests_p90']:.0f}", None) + " |",
        "| BVH node rows (4-wide), stack entries per lane | " + cells(lambda x: f"{x['profile']['bvh_rows']:,}, {x['profile']['bvh_depth']}", None) + " |",
        "| render: rays traced per second | " + cells(lambda x: f"{x['rays'] / x['median'] / 1e6:.1f} M", None) + " |",
        ""]
    return lines
