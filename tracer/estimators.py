"""The two estimators as configured objects with one interface: each is built and checked once (its
settings out of their domain raise SettingsError) and renders one pass of samples into a film. tracer.rendering
only drives them: the plan, the passes, the film, the timing.

- `PathEstimator`: one path per sample, next-event estimation with MIS, Russian roulette (integrators.path);
- `BranchingEstimator`: the report's estimator (integrators.report), N shadow rays (eq. 10) and M hemisphere
  rays (eq. 11) at every diffuse vertex; its depth D in the report is max_depth D + 2 (`from_report_depth`).
"""
from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import ClassVar

import drjit as dr

from .camera import pixel_count, primary_rays
from .errors import SettingsError
from .film import Film
from .integrators.path import Strategies, path_radiance
from .integrators.report import Wavefront, trace_level
from .jit import NO_PRIM, Array3f, Bool, Float, UInt32, opaque_u32
from .launch import chunks, seed_state, trace_pass
from .sampling import seeded_rng

HEMISPHERES = ("cosine", "uniform")
REPORT_DEPTH_OFFSET = 2     # the report's depth D counts bounces after direct light: max_depth D + 2


def integer(name: str, value) -> int:
    """`value` as an int, refusing booleans and non-integers with SettingsError naming `name`."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise SettingsError(f"{name} must be an integer, got {value!r}")
    return int(value)


@dataclass(frozen=True)
class PathEstimator:
    max_depth: int               # Mitsuba's: path segments that may contribute, -1 unbounded
    name: ClassVar[str] = "path"

    def __post_init__(self):
        object.__setattr__(self, "max_depth", integer("max_depth", self.max_depth))
        if self.max_depth < -1:
            raise SettingsError(f"max_depth must be -1 (unbounded) or >= 0, got {self.max_depth}")

    @property
    def settings(self) -> dict:
        return {}

    def samples(self, geo, scene, sample: UInt32, pixel: UInt32, state: int):
        """One path per lane: lane k draws its random numbers from stream `sample[k]` of `state` and
        starts through pixel `pixel[k]` (y * width + x). Returns the film position (x, y), the radiance L
        and the rays each lane traced."""
        depth = 0xFFFFFFFF if self.max_depth < 0 else self.max_depth
        rng = seeded_rng(sample, state)
        o, d, t_min, t_max, x, y = primary_rays(scene.camera, pixel, rng)
        if scene.volumetric:
            from .integrators.volpath import volpath_radiance    # here: its import takes 0.02 s
            L, count = volpath_radiance(geo, o, d, t_min, t_max, rng, opaque_u32(depth), opaque_u32(scene.rr_depth),
                                        scene.spectral_mis)
        else:
            L, count = path_radiance(geo, o, d, t_min, t_max, rng, opaque_u32(depth), opaque_u32(scene.rr_depth),
                                     Strategies(*scene.shading_samples), scene.hide_emitters)
        return x, y, L, count

    def render_pass(self, geo, scene, film: Film, spp: int, seed: int, chunk: int, progress: bool) -> int:
        """`spp` samples per pixel into `film`, in launches of `chunk` paths; returns the rays traced."""
        sampler = lambda sample, pixel, state: self.samples(geo, scene, sample, pixel, state)  # noqa: E731
        return trace_pass(film, sampler, pixel_count(scene.camera) * spp, lambda sample: sample // opaque_u32(spp),
                          seed_state(seed), progress, "path", chunk=chunk, run=spp)


@dataclass(frozen=True)
class BranchingEstimator:
    max_depth: int               # finite: the estimator branches at every bounce
    direct: int = 16             # N: shadow rays per diffuse vertex (eq. 10)
    indirect: int = 8            # M: hemisphere rays per diffuse vertex (eq. 11)
    hemisphere: str = "cosine"   # how eq. 11's directions are drawn (each correctly weighted)
    name: ClassVar[str] = "report"

    def __post_init__(self):
        for field in ("max_depth", "direct", "indirect"):
            object.__setattr__(self, field, integer(field, getattr(self, field)))
        if self.max_depth < 0:
            raise SettingsError("the report estimator branches at every bounce: it needs max_depth >= 0 "
                                "(report depth D is max_depth D + 2), not -1 (unbounded)")
        if self.direct < 1 or self.indirect < 1:
            raise SettingsError(f"direct (N) and indirect (M) must be >= 1, got N = {self.direct}, "
                                f"M = {self.indirect}")
        if self.hemisphere not in HEMISPHERES:
            raise SettingsError(f"hemisphere must be one of {', '.join(HEMISPHERES)}, got {self.hemisphere!r}")

    @classmethod
    def from_report_depth(cls, depth: int, **settings) -> "BranchingEstimator":
        """The estimator at the report's depth D (its Table 2 rows D = 1, 2, 3 are max_depth 3, 4, 5)."""
        depth = integer("report depth", depth)
        if depth < 0:
            raise SettingsError(f"the report's depth must be >= 0 (max_depth D + 2; 0 is direct light), got {depth}")
        return cls(depth + REPORT_DEPTH_OFFSET, **settings)

    @property
    def report_depth(self) -> int:
        return self.max_depth - REPORT_DEPTH_OFFSET

    @property
    def slots(self) -> int:
        """Children one vertex may spawn: M at a diffuse vertex, two at glass."""
        return max(self.indirect, 2)

    @property
    def settings(self) -> dict:
        return {"direct": self.direct, "indirect": self.indirect, "hemisphere": self.hemisphere,
                "report_depth": self.report_depth}

    def render_pass(self, geo, scene, film: Film, spp: int, seed: int, chunk: int, progress: bool) -> int:
        """`spp` camera rays per pixel into `film`, in launches of `chunk` camera rays (their trees grow
        as M^(max_depth - 2)); returns the rays traced."""
        rays = 0
        for index, (start, n) in enumerate(chunks(pixel_count(scene.camera) * spp, chunk,
                                                   progress, "report")):
            sample = dr.arange(UInt32, n) + opaque_u32(start)
            rng = seeded_rng(sample, seed_state(seed, index))
            o, d, t_min, t_max, x, y = primary_rays(scene.camera, sample // opaque_u32(spp), rng)
            dr.eval(x, y)
            radiance = dr.zeros(Float, n * 3)
            wave = Wavefront(o, d, t_min, t_max, Array3f(1.0), dr.arange(UInt32, n), UInt32(NO_PRIM), Bool(True))
            vertex = 1
            while wave is not None and vertex <= max(self.max_depth, 0):
                wave, traced = trace_level(geo, wave, vertex, self.max_depth, self, radiance,
                                           seed_state(seed, index, vertex))
                rays += traced
                vertex += 1
            film.put(x, y, dr.gather(Array3f, radiance, dr.arange(UInt32, n)), run=spp)
            dr.eval(film.data)
        return rays


def make_estimator(name: str, max_depth: int, direct: int | None = None, indirect: int | None = None,
                   hemisphere: str | None = None) -> PathEstimator | BranchingEstimator:
    """The estimator called `name` ("path" or "report"); the path estimator refuses the branching one's
    settings rather than ignore them."""
    given = {k: v for k, v in (("direct", direct), ("indirect", indirect), ("hemisphere", hemisphere)) if v is not None}
    if name == PathEstimator.name:
        if given:
            raise SettingsError(f"{', '.join(given)}: the report estimator's settings; estimator='path' "
                                f"does not use them")
        return PathEstimator(max_depth)
    if name == BranchingEstimator.name:
        return BranchingEstimator(max_depth, **given)
    raise SettingsError(f"unknown estimator {name!r}; choose one of path, report")
