"""The plan of a render, made before its first ray: passes, launch sizes and an estimate of peak memory.

A render that cannot succeed is refused here, in one line with the figure and what would fit, instead of
dying late (an index overflow after hours, the kernel's out-of-memory killer, a NumPy traceback).

- **Passes.** Sample indices are 32-bit within a pass (the random streams and the pixel of a sample
  derive from them), so the samples per pixel are split into passes of at most 2^32 samples each; any
  spp works. A render that fits one pass is that one pass, exactly as it always was.
- **Memory.** The estimate adds the film (four sums per pixel, with the filter's border), the developed
  image and its copies for the outputs, and the working set of one launch: the path tracer's lanes, or
  the branching estimator's widest level of its ray tree (its lanes and the children array it spawns).
  A path tracer in one kernel holds a few registers per lane; bounce by bounce (a scene with a BVH,
  integrators.path) it holds each path's state and its rays in memory. Per-lane figures were measured
  (peak RSS of 2^21 against 2^19 path lanes, on hexagon_room and on validate bench's 249,354-triangle
  scene; of the report estimator at 128 x 128, max_depth 4, M = 8) and rounded up; they are estimates,
  not bounds.
- **Developing.** Film.develop divides the sums band by band (film.DEVELOP_PIXELS), so that the film and
  its developing stay within DEVELOP_MULTIPLE of the image's own size, plus one band's few megabytes
  (tests/test_api_plan.py measures it).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

from .errors import PlanError

MAX_PASS_SAMPLES = 1 << 32  # sample indices are 32-bit within a pass
PATH_CHUNK = 1 << 21        # samples per path-tracing launch
WAVEFRONT_CHUNK = 1 << 20   # the same bounce by bounce: as fast from the second launch on, a first launch
                            # that touches half the fresh memory (a first render at 997,534 triangles:
                            # 0.1 s slower than the next instead of 0.2-0.5 s)
REPORT_BUDGET = 1 << 25     # worst-case rays per report-estimator level, which sets its launch size
MAX_LANES = 1 << 32         # lanes of one Dr.Jit array (32-bit indices)

IMAGE_BYTES = 12            # per pixel of a developed image: float32 RGB
DEVELOP_MULTIPLE = 3.0      # film (16 bytes per pixel) and its developing, in developed images (12 bytes)
PATH_LANE_BYTES = 64        # per path-tracer lane of a launch in one kernel (measured about 10)
WAVEFRONT_LANE_BYTES = 512  # per path-tracer lane of a launch bounce by bounce (measured about 420)
WAVE_LANE_BYTES = 192       # per ray of a report-estimator level: ray, weight, hit surface (measured about 150)
SPAWN_LANE_BYTES = 16       # per possible child of a level (a spawned one takes its mark and parent rank)


def pass_spps(pixels: int, spp: int, max_samples: int = MAX_PASS_SAMPLES) -> list[int]:
    """Samples per pixel of each pass: as few passes as keep every pass within `max_samples` samples."""
    per_pass = max_samples // pixels
    if per_pass < 1:
        raise PlanError(f"{pixels:,} pixels is more than {max_samples:,} samples in one pass")
    return [per_pass] * (spp // per_pass) + ([spp % per_pass] if spp % per_pass else [])


def report_tree(slots: int, direct: int, max_depth: int) -> tuple[int, int]:
    """(camera samples per launch, widest level's rays per camera sample) of the branching estimator:
    its launch size keeps the worst-case rays of a level (shadow rays included) within REPORT_BUDGET."""
    widest = slots ** max(max_depth - 2, 0) * direct
    return max(1, REPORT_BUDGET // widest), slots ** max(max_depth - 2, 0)


@dataclass(frozen=True)
class Plan:
    width: int
    height: int
    spp: int
    passes: list[int]          # samples per pixel of each pass
    chunk: int                 # camera samples per launch
    film_bytes: int            # film, developed image and output copies
    launch_bytes: int          # the working set of one launch
    available_bytes: int

    @property
    def peak_bytes(self) -> int:
        return self.film_bytes + self.launch_bytes

    def describe(self) -> str:
        passes = f"{len(self.passes)} passes" if len(self.passes) > 1 else "1 pass"
        return (f"{self.width * self.height * self.spp:,} samples in {passes}, launches of {self.chunk:,}; "
                f"peak memory about {gib(self.peak_bytes)} (film and images {gib(self.film_bytes)}, "
                f"launch {gib(self.launch_bytes)}) of {gib(self.available_bytes)} available")


def gib(n: float) -> str:
    return f"{n / 2**30:.2f} GiB" if n >= 2**28 else f"{n / 2**20:.0f} MiB"


def available_memory() -> int:
    """Bytes of memory available to a new allocation: Linux's MemAvailable, else the physical memory."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def film_bytes(width: int, height: int, border: int, float_bytes: int, images: int) -> int:
    """The film (four sums per pixel over the bordered film) and `images` developed images."""
    return (width + 2 * border) * (height + 2 * border) * 4 * float_bytes + images * width * height * IMAGE_BYTES


def plan_render(width: int, height: int, spp: int, estimator: str, max_depth: int, *, border: int = 0,
                float_bytes: int = 4, images: int = 2, slots: int = 8, direct: int = 16,
                memory: int | None = None, max_pass_samples: int | None = None, wavefront: bool = False) -> Plan:
    """The render's plan, or PlanError when it cannot fit. `images`: developed images held at once (the
    image and its PNG encoding count about two); `slots`, `direct`: the branching estimator's children
    per vertex and shadow rays (BranchingEstimator); `wavefront`: the path tracer goes bounce by bounce."""
    memory = available_memory() if memory is None else memory
    pixels = width * height
    passes = pass_spps(pixels, spp, MAX_PASS_SAMPLES if max_pass_samples is None else max_pass_samples)
    film = film_bytes(width, height, border, float_bytes, images)
    if pixels * 4 >= MAX_LANES:
        raise PlanError(f"{width} x {height} is {pixels:,} pixels; the film holds at most {MAX_LANES // 4:,} "
                        f"(e.g. {_fit_size(width, height, MAX_LANES // 4 - 1)})")
    if estimator == "report":
        chunk, lanes = report_tree(slots, direct, max_depth)
        chunk = min(chunk, pixels * max(passes))
        children = chunk * lanes * slots
        launch = chunk * lanes * WAVE_LANE_BYTES + children * SPAWN_LANE_BYTES
        if film + launch > memory or children >= MAX_LANES:
            fit = _report_fit(slots, direct, max_depth, memory - film)
            raise PlanError(f"the branching estimator's widest level holds up to {lanes:,} rays per camera sample "
                            f"(max_depth {max_depth}, {slots} children per vertex): about {gib(film + launch)} of "
                            f"memory with the film, {gib(memory)} available; {fit}")
    else:
        chunk = min(WAVEFRONT_CHUNK if wavefront else PATH_CHUNK, pixels * max(passes))
        launch = chunk * (WAVEFRONT_LANE_BYTES if wavefront else PATH_LANE_BYTES)
    plan = Plan(width, height, spp, passes, chunk, film, launch, memory)
    if plan.peak_bytes > memory:
        per_pixel = plan.film_bytes / pixels
        raise PlanError(f"{width} x {height} needs about {gib(plan.peak_bytes)} of memory (film and images "
                        f"{gib(film)}), {gib(memory)} available; at most about "
                        f"{_fit_size(width, height, int((memory - launch) / per_pixel))} fits")
    return plan


def _fit_size(width: int, height: int, pixels: int) -> str:
    """The largest size of the same aspect ratio within `pixels`."""
    scale = math.sqrt(max(pixels, 0) / (width * height))
    return f"{max(int(width * scale), 1)} x {max(int(height * scale), 1)}"


def _report_fit(slots: int, direct: int, max_depth: int, memory: int) -> str:
    """What would fit of the branching estimator at one camera sample per launch: a smaller M at this depth,
    or a smaller depth at this M."""
    def fits(s: int, depth: int) -> bool:
        lanes = s ** max(depth - 2, 0)
        return lanes * s < MAX_LANES and lanes * WAVE_LANE_BYTES + lanes * s * SPAWN_LANE_BYTES <= memory

    options = []
    m = max((s for s in range(2, slots) if fits(s, max_depth)), default=None)
    if m is not None:
        options.append(f"indirect (M) {m} at this depth")
    depth = max((d for d in range(2, max_depth) if fits(slots, d)), default=None)
    if depth is not None:
        options.append(f"max_depth {depth} (report depth {depth - 2}) at this M")
    return "at most " + " or ".join(options) + " would fit" if options else "nothing of this size fits"
