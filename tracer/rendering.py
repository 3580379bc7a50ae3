"""Rendering a scene: the driver of tracer.estimators. The render is planned before its first ray
(tracer.plan) and the estimator renders it in passes and chunks that bound memory, into a NumPy image."""
from __future__ import annotations

import numbers
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import memory_guard
from .compile_clock import CompileClock
from .errors import OutOfMemory, SettingsError
from .estimators import BranchingEstimator, PathEstimator, integer, make_estimator
from .film import FILTERS, Film, ReconstructionFilter
from .geometry import SceneGeometry, goes_bounce_by_bounce
from .shapes import MeshSet
from .jit import BACKEND, PRECISION
from .launch import seed_state
from .sampling import GUIDE_DENSITY
from .plan import INSTANCE_BYTES, TEXEL_BYTES, TRIANGLE_BYTES, Plan, available_memory, gib, plan_render
from .scene import Scene, SceneError

ESTIMATORS = (PathEstimator.name, BranchingEstimator.name)
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
    render that cannot fit in memory PlanError, both before the first ray; one that runs out of memory all
    the same raises OutOfMemory, with the passes it completed as its `partial` result. `geometry`: a
    SceneGeometry of this same scene to reuse across renders (built here when None; a mesh's BVH is reused in
    any case, tracer.shapes.bvh_cache)."""
    if isinstance(scene, (str, Path)):
        from .mitsuba_xml import load_scene
        scene = load_scene(scene)
    if not isinstance(scene, Scene):
        raise SettingsError(f"scene must be a Scene (tracer.load_scene) or a scene file's path, "
                            f"got {type(scene).__name__}")
    name, spp, seed, max_depth = check_settings(scene, estimator, spp, seed, max_depth)
    refusals = scene.estimator_refusals(name)
    if refusals:
        raise SceneError("\n".join(refusals))
    estimator = make_estimator(name, max_depth, direct, indirect, hemisphere)
    rfilter = check_rfilter(scene.camera.rfilter if rfilter is None else rfilter)
    check_border(scene.camera, rfilter)
    if time_limit is not None and (isinstance(time_limit, bool) or not isinstance(time_limit, numbers.Real)
                                   or not time_limit > 0):
        raise SettingsError(f"time_limit must be a positive number of seconds, got {time_limit!r}")
    cam = scene.camera
    film = Film(cam.width, cam.height, rfilter)
    if geometry is not None and geometry.scene is not scene:
        raise SettingsError("geometry must be a SceneGeometry of the scene rendered")
    plan = make_plan(scene, spp, estimator, film.border, one_spp_passes=time_limit is not None, geometry=geometry)
    geo = SceneGeometry(scene) if geometry is None else geometry
    rays = 0

    def one_pass(index: int, pass_spp: int) -> None:
        nonlocal rays
        rays += estimator.render_pass(geo, scene, film, pass_spp, pass_seed(seed, index), plan.chunk, progress)

    def passes():
        rendered, failure = run_passes(plan.passes, time_limit, one_pass, film)
        return rendered, failure, film.develop() if rendered else None

    (rendered, failure, pixels), seconds, compile_s = timed(passes)
    settings = estimator.settings | {"passes": len(rendered), "requested_spp": spp}
    result = None if not rendered else RenderResult(pixels, name, sum(rendered), max_depth, seconds, compile_s,
                                                    rays, settings=settings, seed=seed)
    if failure is not None:
        raise OutOfMemory(out_of_memory_message(failure, plan, rendered), result)
    return result


def out_of_memory_message(failure: BaseException, plan: Plan, rendered: list[int]) -> str:
    """One line: where the render ran out of memory, the figures, and what would fit."""
    held, available = memory_guard.resident_bytes(), available_memory()
    where = f"out of memory in pass {len(rendered) + 1} of {len(plan.passes)}"
    figures = (f"the process holds {gib(held)}, {gib(available)} more available, " if held else "") + \
        f"the plan estimated a peak of {gib(plan.peak_bytes)}"
    if rendered:
        fits = f"the {len(rendered)} passes done fit: {sum(rendered)} of {plan.spp} spp"
    else:
        fits = "no pass was complete (a render in passes, such as --time-limit's, keeps those done)"
    return f"{where} ({failure}; {figures}); {fits}"


def check_settings(scene: Scene, estimator: str, spp, seed, max_depth) -> tuple[str, int, int, int]:
    """(estimator, spp, seed, max_depth), unset ones from the scene, each checked: SettingsError names the
    parameter, its value and its domain."""
    if estimator not in ESTIMATORS:
        raise SettingsError(f"unknown estimator {estimator!r}; choose one of {', '.join(ESTIMATORS)}")
    spp = integer("spp", scene.spp if spp is None else spp)
    seed = integer("seed", scene.seed if seed is None else seed)
    max_depth = integer("max_depth", scene.max_depth if max_depth is None else max_depth)
    if spp < 1:
        raise SettingsError(f"spp must be >= 1, got {spp}")
    if not 0 <= seed < MAX_SEED:
        raise SettingsError(f"seed must be in [0, 2^32), got {seed}")
    if max_depth < -1:
        raise SettingsError(f"max_depth must be -1 (unbounded) or >= 0, got {max_depth}")
    return estimator, spp, seed, max_depth


def check_rfilter(rfilter) -> ReconstructionFilter:
    """A ReconstructionFilter, or the name of one (Mitsuba's defaults: gaussian stddev 0.5, tent radius 1)."""
    if isinstance(rfilter, str) and rfilter in FILTERS:
        return ReconstructionFilter(rfilter)
    if not isinstance(rfilter, ReconstructionFilter):
        raise SettingsError(f"rfilter must be a ReconstructionFilter or one of {', '.join(FILTERS)}, got {rfilter!r}")
    return rfilter


def check_border(camera, rfilter: ReconstructionFilter) -> None:
    """With hdrfilm's sample_border, camera rays start in the scene filter's border: another filter would
    need another border."""
    if camera.sample_border and rfilter != camera.rfilter:
        raise SettingsError(f"the film samples its border (sample_border) for its {camera.rfilter.describe()} "
                            f"filter; render it with that filter, not {rfilter.describe()}")


def make_plan(scene: Scene, spp: int, estimator: PathEstimator | BranchingEstimator, border: int,
              one_spp_passes: bool = False, images: int = 2, geometry: SceneGeometry | None = None) -> Plan:
    """tracer.plan's plan for the scene's camera, this backend's precision and the estimator's tree (or
    its path tracer bounce by bounce, where the scene's meshes go into a BVH: as `geometry` has them, or,
    before it is built, as a SceneGeometry with the default bvh_threshold will)."""
    width, height = scene.camera.sampled_size        # the image, and the border sample_border adds
    if isinstance(estimator, BranchingEstimator):
        extra = {"slots": estimator.slots, "direct": estimator.direct}
    elif geometry is not None:
        extra = {"wavefront": geometry.bounce_by_bounce}
    else:
        extra = {"wavefront": goes_bounce_by_bounce(scene, MeshSet.uses_bvh(scene.triangle_count)
                                                    or scene.instanced_triangles[1] > 0)}
    return plan_render(width, height, spp, estimator.name, estimator.max_depth, border=border,
                       float_bytes=8 if PRECISION == "double" else 4, images=images, scene_bytes=scene_bytes(scene),
                       max_pass_samples=width * height if one_spp_passes else None, **extra)


def scene_bytes(scene: Scene) -> int:
    """tracer.plan's estimate of the memory the scene's arrays take: its mesh triangles (those of shapegroups
    once, and per instance its rows: INSTANCE_BYTES), texels, and the environment map's guide tables
    (sampling.GuidedCDF)."""
    textures = {id(t): t for b in scene.bsdfs for t in b.every_texture()}
    images = [t.image for t in textures.values() if getattr(t, "image", None) is not None]
    if scene.envmap is not None:
        images.append(scene.envmap.image)
    texels = sum(image.shape[0] * image.shape[1] for image in images)
    instances = sum(len(g.to_world) for g in scene.groups if g.meshes)
    guides = scene.envmap.image[..., 0].size * 4 * GUIDE_DENSITY if scene.envmap is not None else 0
    return ((scene.triangle_count + scene.instanced_triangles[0]) * TRIANGLE_BYTES + instances * INSTANCE_BYTES
            + texels * TEXEL_BYTES + guides)


def pass_seed(seed: int, index: int) -> int:
    """The seed of pass `index`: the render's own for the first (a one-pass render is what it always
    was), then independent streams."""
    return seed if index == 0 else seed_state(seed, PASS_STREAM, index)


def run_passes(passes: list[int], time_limit: float | None, render_pass,
               film: Film | None = None) -> tuple[list[int], BaseException | None]:
    """Calls render_pass(index, spp) for each pass; with `time_limit` (seconds), stops before a pass that
    would end after it if it took as long as the last one (the first pass, which also compiles the kernels,
    is always rendered, and may make the second look longer than it is). A pass that runs out of memory
    (memory_guard) stops the render, and `film` is put back as the passes before left it. Returns the spp of
    the passes rendered and the allocation failure that stopped them, if one did."""
    start, done, last = time.perf_counter(), [], 0.0
    for index, spp in enumerate(passes):
        began = time.perf_counter()
        if time_limit is not None and done and began - start + last > time_limit:
            break
        # a second reference: the pass's first splat copies the film (Dr.Jit copies an array shared on write)
        before = None if film is None or not done else type(film.data)(film.data)
        try:
            render_pass(index, spp)
        except Exception as e:
            if not memory_guard.is_allocation_failure(e):
                raise
            if before is not None:
                film.data = before
            return done, e
        last = time.perf_counter() - began
        done.append(spp)
    return done, None


def timed(run):
    """(run's result, wall seconds, of which Dr.Jit's kernel generation and compilation): runs `run()`
    under a CompileClock."""
    with CompileClock() as clock:
        start = time.perf_counter()
        out = run()
        seconds = time.perf_counter() - start
    return out, seconds, clock.seconds
