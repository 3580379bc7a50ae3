"""Rendering a scene with either estimator, planned before its first ray (tracer.plan), in passes and
chunks that bound memory, into a NumPy image."""
from __future__ import annotations

import numbers
import time
from dataclasses import dataclass, field
from pathlib import Path

import drjit as dr
import numpy as np
from tqdm import tqdm

from .camera import primary_rays
from .errors import SettingsError
from .film import FILTERS, Film, ReconstructionFilter
from .geometry import SceneGeometry
from .integrators.path import path_radiance
from .integrators.report import ReportSettings, Wavefront, trace_level
from .jit import BACKEND, NO_PRIM, PRECISION, Array3f, Bool, Float, UInt32, opaque_u32
from .plan import PATH_CHUNK, Plan, plan_render
from .sampling import seeded_rng
from .scene import Scene

ESTIMATORS = ("path", "report")
HEMISPHERES = ("cosine", "uniform")
PASS_STREAM = 0x9A55_0000_0000     # random streams of passes after the first: (seed, PASS_STREAM, pass)
MAX_SEED = 2**32                   # seeds are 32-bit, as Mitsuba's sampler's


class Timed:
    """A result timed with `timed`: `seconds` of wall time, of which `compile_seconds` went to kernels."""

    seconds: float
    compile_seconds: float

    @property
    def render_seconds(self) -> float:
        return max(self.seconds - self.compile_seconds, 0.0)


@dataclass
class RenderResult(Timed):
    image: np.ndarray                 # (height, width, 3) float32, linear radiance
    estimator: str
    spp: int
    max_depth: int
    seconds: float = 0.0              # wall time of the whole render
    compile_seconds: float = 0.0      # of which Dr.Jit spent generating and compiling kernels
    rays: int = 0                     # closest-hit and shadow rays traced
    backend: str = BACKEND
    settings: dict = field(default_factory=dict)
    seed: int = 0

    @property
    def rays_per_second(self) -> float:
        return self.rays / self.render_seconds if self.render_seconds > 0 else 0.0


def render(scene: Scene | str | Path, estimator: str = "path", spp: int | None = None, seed: int | None = None,
           max_depth: int | None = None, direct: int | None = None, indirect: int | None = None,
           hemisphere: str | None = None, rfilter: ReconstructionFilter | str | None = None,
           progress: bool = False, time_limit: float | None = None,
           geometry: SceneGeometry | None = None) -> RenderResult:
    """Renders `scene` (a Scene, or the path of a scene file, loaded with its defaults).

    Unset arguments take the scene file's values (spp, seed, max_depth, rfilter); `direct`, `indirect`
    and `hemisphere` are the report estimator's N, M and eq. 11's sampling (defaults 16, 8, "cosine").
    `rfilter` is a ReconstructionFilter or the name of one with Mitsuba's defaults. `time_limit`
    (seconds) renders one sample per pixel per pass and stops after the last whole pass that fits:
    `result.spp` says how many were rendered. Arguments out of their domain raise SettingsError and a
    render that cannot fit in memory PlanError, both before the first ray. `geometry`: a SceneGeometry of
    this same scene to reuse across renders (built here when None; a mesh's BVH is reused in any case,
    tracer.bvh_cache)."""
    if isinstance(scene, (str, Path)):
        from .mitsuba_xml import load_scene
        scene = load_scene(scene)
    if not isinstance(scene, Scene):
        raise SettingsError(f"scene must be a Scene (tracer.load_scene) or a scene file's path, "
                            f"got {type(scene).__name__}")
    estimator, spp, seed, max_depth = check_settings(scene, estimator, spp, seed, max_depth)
    report = report_settings(estimator, max_depth, direct, indirect, hemisphere)
    rfilter = check_rfilter(scene.camera.rfilter if rfilter is None else rfilter)
    if time_limit is not None and (isinstance(time_limit, bool) or not isinstance(time_limit, numbers.Real)
                                   or not time_limit > 0):
        raise SettingsError(f"time_limit must be a positive number of seconds, got {time_limit!r}")
    cam = scene.camera
    film = Film(cam.width, cam.height, rfilter)
    plan = make_plan(cam.width, cam.height, spp, estimator, max_depth, film.border, report,
                     one_spp_passes=time_limit is not None)
    if geometry is not None and geometry.scene is not scene:
        raise SettingsError("geometry must be a SceneGeometry of the scene rendered")
    geo = SceneGeometry(scene) if geometry is None else geometry
    if report is not None:
        run = lambda: _render_report(geo, scene, film, plan, seed, max_depth, report, progress,  # noqa: E731
                                     time_limit)
        settings = {"direct": report.direct, "indirect": report.indirect, "hemisphere": report.hemisphere,
                    "report_depth": max_depth - 2}
    else:
        run = lambda: _render_path(geo, scene, film, plan, seed, max_depth, progress, time_limit)  # noqa: E731
        settings = {}
    ((rays, rendered), pixels), seconds, compile_s = timed(lambda: (run(), film.develop()))
    settings.update(passes=len(rendered), requested_spp=spp)
    return RenderResult(pixels, estimator, sum(rendered), max_depth, seconds, compile_s, rays, settings=settings,
                        seed=seed)


def _integer(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise SettingsError(f"{name} must be an integer, got {value!r}")
    return int(value)


def check_settings(scene: Scene, estimator: str, spp, seed, max_depth) -> tuple[str, int, int, int]:
    """(estimator, spp, seed, max_depth), unset ones from the scene, each checked: SettingsError names the
    parameter, its value and its domain."""
    if estimator not in ESTIMATORS:
        raise SettingsError(f"unknown estimator {estimator!r}; choose one of {', '.join(ESTIMATORS)}")
    spp = _integer("spp", scene.spp if spp is None else spp)
    seed = _integer("seed", scene.seed if seed is None else seed)
    max_depth = _integer("max_depth", scene.max_depth if max_depth is None else max_depth)
    if spp < 1:
        raise SettingsError(f"spp must be >= 1, got {spp}")
    if not 0 <= seed < MAX_SEED:
        raise SettingsError(f"seed must be in [0, 2^32), got {seed}")
    if max_depth < -1:
        raise SettingsError(f"max_depth must be -1 (unbounded) or >= 0, got {max_depth}")
    return estimator, spp, seed, max_depth


def report_settings(estimator: str, max_depth: int, direct, indirect, hemisphere) -> ReportSettings | None:
    """The report estimator's settings (None for the path estimator, which refuses them)."""
    given = {k: v for k, v in (("direct", direct), ("indirect", indirect), ("hemisphere", hemisphere)) if v is not None}
    if estimator != "report":
        if given:
            raise SettingsError(f"{', '.join(given)}: the report estimator's settings; estimator='path' "
                                f"does not use them")
        return None
    if max_depth < 0:
        raise SettingsError("the report estimator branches at every bounce: it needs max_depth >= 0 "
                            "(report depth D is max_depth D + 2), not -1 (unbounded)")
    direct = _integer("direct", 16 if direct is None else direct)
    indirect = _integer("indirect", 8 if indirect is None else indirect)
    if direct < 1 or indirect < 1:
        raise SettingsError(f"direct (N) and indirect (M) must be >= 1, got N = {direct}, M = {indirect}")
    hemisphere = "cosine" if hemisphere is None else hemisphere
    if hemisphere not in HEMISPHERES:
        raise SettingsError(f"hemisphere must be one of {', '.join(HEMISPHERES)}, got {hemisphere!r}")
    return ReportSettings(direct, indirect, hemisphere)


def check_rfilter(rfilter) -> ReconstructionFilter:
    """A ReconstructionFilter, or the name of one (Mitsuba's defaults: gaussian stddev 0.5, tent radius 1)."""
    if isinstance(rfilter, str) and rfilter in FILTERS:
        return ReconstructionFilter(rfilter)
    if not isinstance(rfilter, ReconstructionFilter):
        raise SettingsError(f"rfilter must be a ReconstructionFilter or one of {', '.join(FILTERS)}, got {rfilter!r}")
    return rfilter


def make_plan(width: int, height: int, spp: int, estimator: str, max_depth: int, border: int,
              report: ReportSettings | None, one_spp_passes: bool = False, images: int = 2) -> Plan:
    """tracer.plan's plan for this backend's precision and the estimator's tree."""
    extra = {} if report is None else {"slots": report.slots, "direct": report.direct}
    return plan_render(width, height, spp, estimator, max_depth, border=border,
                       float_bytes=8 if PRECISION == "double" else 4, images=images,
                       max_pass_samples=width * height if one_spp_passes else None, **extra)


def pass_seed(seed: int, index: int) -> int:
    """The seed of pass `index`: the render's own for the first (a one-pass render is what it always
    was), then independent streams."""
    return seed if index == 0 else seed_state(seed, PASS_STREAM, index)


def run_passes(passes: list[int], time_limit: float | None, render_pass) -> list[int]:
    """Calls render_pass(index, spp) for each pass; with `time_limit` (seconds), stops before a pass that
    would end after it if it took as long as the last one (the first pass, which also compiles the kernels,
    is always rendered, and may make the second look longer than it is). Returns the spp of the passes
    rendered."""
    start, done, last = time.perf_counter(), [], 0.0
    for index, spp in enumerate(passes):
        began = time.perf_counter()
        if time_limit is not None and done and began - start + last > time_limit:
            break
        render_pass(index, spp)
        last = time.perf_counter() - began
        done.append(spp)
    return done


def timed(run):
    """(run's result, wall seconds, of which Dr.Jit's kernel generation and compilation): runs `run()`
    with Dr.Jit's kernel history on."""
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()  # clear
    start = time.perf_counter()
    try:
        out = run()
        seconds = time.perf_counter() - start
        history = dr.kernel_history()
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    return out, seconds, sum(k.get("codegen_time", 0) + k.get("backend_time", 0) for k in history) / 1000


def chunks(total: int, size: int, progress: bool, label: str):
    """(start, count) of consecutive launches of at most `size` samples, with a progress bar."""
    bar = tqdm(total=total, unit="spl", unit_scale=True, desc=label, disable=not progress, leave=False)
    for start in range(0, total, size):
        n = min(size, total - start)
        yield start, n
        bar.update(n)
    bar.close()


def seed_state(seed: int, *stream: int) -> int:
    """The initial state of the random streams `stream` of `seed` (seeded_rng's seed)."""
    h = seed & 0xFFFFFFFFFFFFFFFF
    for s in stream:
        h = (h * 0x9E3779B97F4A7C15 + s + 1) % 2**64
    return h


def path_samples(geo, scene, sample: UInt32, pixel: UInt32, seed_state: int, max_depth: int):
    """One path per lane: lane k draws its random numbers from stream `sample[k]` of `seed_state` and
    starts through pixel `pixel[k]` (y * width + x). Returns the film position (x, y), the radiance L
    and the rays each lane traced."""
    depth = 0xFFFFFFFF if max_depth < 0 else max_depth
    rng = seeded_rng(sample, seed_state)
    o, d, t_min, t_max, x, y = primary_rays(scene.camera, pixel, rng)
    L, count = path_radiance(geo, o, d, t_min, t_max, rng, opaque_u32(depth), opaque_u32(scene.rr_depth))
    return x, y, L, count


def trace_pass(film: Film, sampler, total: int, pixel_of, state: int, progress: bool, label: str,
               squares: Film | None = None) -> int:
    """`total` samples into `film`, in launches of PATH_CHUNK: sample k goes through pixel pixel_of(k)
    and `sampler(sample, pixel, state)` (as path_samples) traces it. `squares`, if given, sums the
    squared radiance. Returns the rays traced."""
    rays = 0
    for start, n in chunks(total, PATH_CHUNK, progress, label):
        sample = dr.arange(UInt32, n) + opaque_u32(start)
        x, y, L, count = sampler(sample, pixel_of(sample), state)
        film.put(x, y, L)
        if squares is not None:
            squares.put(x, y, L * L)
        launched = dr.sum(count)
        dr.eval(film.data, launched, *([] if squares is None else [squares.data]))
        rays += int(launched[0])
    return rays


def _render_path(geo, scene, film, plan, seed, max_depth, progress, time_limit) -> tuple[int, list[int]]:
    sampler = lambda sample, pixel, state: path_samples(geo, scene, sample, pixel, state, max_depth)  # noqa: E731
    rays = 0

    def one_pass(index, spp):
        nonlocal rays
        rays += trace_pass(film, sampler, film.width * film.height * spp, lambda sample: sample // spp,
                           seed_state(pass_seed(seed, index)), progress, "path")

    done = run_passes(plan.passes, time_limit, one_pass)
    return rays, done


def _render_report(geo, scene, film, plan, seed, max_depth, settings, progress, time_limit) -> tuple[int, list[int]]:
    rays = 0

    def one_pass(index, spp):
        nonlocal rays
        rays += _report_pass(geo, scene, film, spp, pass_seed(seed, index), max_depth, settings, plan.chunk, progress)

    done = run_passes(plan.passes, time_limit, one_pass)
    return rays, done


def _report_pass(geo, scene, film, spp, seed, max_depth, settings, chunk, progress) -> int:
    rays = 0
    for index, (start, n) in enumerate(chunks(scene.camera.width * scene.camera.height * spp, chunk,
                                               progress, "report")):
        sample = dr.arange(UInt32, n) + opaque_u32(start)
        rng = seeded_rng(sample, seed_state(seed, index))
        o, d, t_min, t_max, x, y = primary_rays(scene.camera, sample // spp, rng)
        dr.eval(x, y)
        radiance = dr.zeros(Float, n * 3)
        wave = Wavefront(o, d, t_min, t_max, Array3f(1.0), dr.arange(UInt32, n), UInt32(NO_PRIM), Bool(True))
        vertex = 1
        while wave is not None and vertex <= max(max_depth, 0):
            wave, traced = trace_level(geo, wave, vertex, max_depth, settings, radiance,
                                       seed_state(seed, index, vertex))
            rays += traced
            vertex += 1
        film.put(x, y, dr.gather(Array3f, radiance, dr.arange(UInt32, n)))
        dr.eval(film.data)
    return rays
