"""Rendering a scene with either estimator, in chunks that bound memory, into a NumPy image."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import drjit as dr
import numpy as np
from tqdm import tqdm

from .camera import primary_rays
from .film import Film, ReconstructionFilter
from .geometry import SceneGeometry
from .integrators.path import path_radiance
from .integrators.report import ReportSettings, Wavefront, trace_level
from .jit import BACKEND, NO_PRIM, Array3f, Bool, Float, UInt32, opaque_u32
from .sampling import seeded_rng
from .scene import Scene

ESTIMATORS = ("path", "report")
PATH_CHUNK = 1 << 21       # samples per path-tracing launch
REPORT_BUDGET = 1 << 23    # worst-case rays per report-estimator level


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

    @property
    def rays_per_second(self) -> float:
        return self.rays / self.render_seconds if self.render_seconds > 0 else 0.0


def render(scene: Scene, estimator: str = "path", spp: int | None = None, seed: int | None = None,
           max_depth: int | None = None, direct: int = 16, indirect: int = 8, hemisphere: str = "cosine",
           rfilter: ReconstructionFilter | None = None, progress: bool = False) -> RenderResult:
    """Renders `scene`; unset arguments take the scene file's values (spp, seed, max_depth, rfilter)."""
    if estimator not in ESTIMATORS:
        raise ValueError(f"unknown estimator '{estimator}'; choose one of {', '.join(ESTIMATORS)}")
    spp = scene.spp if spp is None else spp
    seed = scene.seed if seed is None else seed
    max_depth = scene.max_depth if max_depth is None else max_depth
    if spp < 1:
        raise ValueError(f"spp must be >= 1, got {spp}")
    if max_depth < -1:
        raise ValueError(f"max_depth must be -1 (unbounded) or >= 0, got {max_depth}")
    geo = SceneGeometry(scene)
    cam = scene.camera
    film = Film(cam.width, cam.height, cam.rfilter if rfilter is None else rfilter)
    if estimator == "report":
        if max_depth < 0:
            raise ValueError("the report estimator branches at every bounce: it needs a finite max_depth")
        report = ReportSettings(direct, indirect, hemisphere)
        run = lambda: _render_report(geo, scene, film, spp, seed, max_depth, report, progress)  # noqa: E731
        settings = {"direct": direct, "indirect": indirect, "hemisphere": hemisphere, "report_depth": max_depth - 2}
    else:
        run = lambda: _render_path(geo, scene, film, spp, seed, max_depth, progress)  # noqa: E731
        settings = {}
    (rays, pixels), seconds, compile_s = timed(lambda: (run(), film.develop()))
    return RenderResult(pixels, estimator, spp, max_depth, seconds, compile_s, rays, settings=settings)


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


def _render_path(geo, scene, film, spp, seed, max_depth, progress) -> int:
    sampler = lambda sample, pixel, state: path_samples(geo, scene, sample, pixel, state, max_depth)  # noqa: E731
    return trace_pass(film, sampler, film.width * film.height * spp, lambda sample: sample // spp,
                      seed_state(seed), progress, "path")


def _render_report(geo, scene, film, spp, seed, max_depth, settings, progress) -> int:
    widest = settings.slots ** max(max_depth - 2, 0) * settings.direct
    chunk = max(1, REPORT_BUDGET // widest)
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
