"""The plan of a render, made before its first ray: passes, launch sizes and an estimate of peak memory.

A render that cannot succeed is refused here, in one line with the figure and what would fit, instead of
dying late (an index overflow after hours, the kernel's out-of-memory killer, a NumPy traceback).

- **Passes.** Sample indices are 32-bit within a pass (the random streams and the pixel of a sample
  derive from them), so the samples per pixel are split into passes of at most 2^32 samples each; any
  spp works. A render that fits one pass is that one pass, exactly as it always was.
- **Memory.** The estimate is of the process's peak resident memory. It adds the process itself (the
  interpreter, NumPy, Dr.Jit, LLVM and the compiled kernels), the scene's arrays (per mesh triangle: its
  vertices on the host and in the kernels' arrays and its BVH; per texel of a texture or environment map:
  its copies and sampling tables), the film (four sums per pixel, with the filter's border), the developed
  image and its copies for the outputs, and the working set of one launch: the path tracer's lanes, or
  the branching estimator's widest level of its ray tree (its lanes and the children array it spawns).
  A path tracer in one kernel holds a few registers per lane; bounce by bounce (a scene with a mesh BVH,
  integrators.path) it holds each path's state and its rays in memory. Per-lane figures were measured
  (peak RSS of 2^21 against 2^19 path lanes, on hexagon_room and on validate bench's 249,354-triangle
  scene; of the report estimator at 128 x 128, max_depth 4, M = 8) and rounded up; they are estimates,
  not bounds. `validate bench --only memory` checks the whole against measured peaks (reports/performance.md).
  A render is refused when what it has still to allocate (all but the process) exceeds the memory available.
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
PATH_LANE_BYTES = 16        # per path-tracer lane of a launch in one kernel (measured about 7)
WAVEFRONT_LANE_BYTES = 640  # per path-tracer lane of a launch bounce by bounce (measured 520 after 3 launches,
                            # 600 over 42 of mitsuba-data's glass scene: it settles within about 20 launches)
WAVE_LANE_BYTES = 192       # per ray of a report-estimator level: ray, weight, hit surface (measured about 150)
SPAWN_LANE_BYTES = 16       # per possible child of a level (a spawned one takes its mark and parent rank)
PROCESS_BYTES = 120 << 20   # the interpreter and libraries with the kernels compiled (measured 112 MiB)
TRIANGLE_BYTES = 1024       # per mesh triangle (measured about 650 to 1,030 after building the BVH)
TEXEL_BYTES = 48            # per texel of a texture or environment map
INSTANCE_BYTES = TRIANGLE_BYTES + 256   # per instance of a shapegroup's meshes: a top-level BVH entry, as a
                                        # triangle's, and its two matrices


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
    scene_bytes: int = 0       # the scene's meshes, BVHs and textures
    process_bytes: int = PROCESS_BYTES

    @property
    def peak_bytes(self) -> int:
        """The process's peak resident memory."""
        return self.process_bytes + self.scene_bytes + self.film_bytes + self.launch_bytes

    @property
    def needed_bytes(self) -> int:
        """What the render has still to allocate when it is planned (the process is there already)."""
        return self.peak_bytes - self.process_bytes

    def describe(self) -> str:
        passes = f"{len(self.passes)} passes" if len(self.passes) > 1 else "1 pass"
        return (f"{self.width * self.height * self.spp:,} samples in {passes}, launches of {self.chunk:,}; "
                f"peak memory about {gib(self.peak_bytes)} (process {gib(self.process_bytes)}, scene "
                f"{gib(self.scene_bytes)}, film and images {gib(self.film_bytes)}, launch {gib(self.launch_bytes)}) "
                f"of {gib(self.available_bytes)} available")


def gib(n: float) -> str:
    return f"{n / 2**30:.2f} GiB" if n >= 2**28 else f"{n / 2**20:.0f} MiB"


def available_memory() -> int:
    """Bytes of memory available to a new allocation: Linux's MemAvailable, else the physical memory."""
    available = proc_bytes("/proc/meminfo", "MemAvailable")
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") if available is None else available


def proc_bytes(path: str, key: str) -> int | None:
    """A `key: N kB` line of a Linux /proc file (meminfo, self/status) in bytes; None where there is none."""
    try:
        with open(path) as f:
            for line in f:
                if line.startswith(f"{key}:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def film_bytes(width: int, height: int, border: int, float_bytes: int, images: int, films: int = 1) -> int:
    """`films` films (four sums per pixel over the bordered film) and `images` developed images."""
    return films * (width + 2 * border) * (height + 2 * border) * 4 * float_bytes + images * width * height * IMAGE_BYTES


def plan_render(width: int, height: int, spp: int, estimator: str, max_depth: int, *, border: int = 0,
                float_bytes: int = 4, images: int = 2, slots: int = 8, direct: int = 16,
                memory: int | None = None, max_pass_samples: int | None = None, wavefront: bool = False,
                scene_bytes: int = 0) -> Plan:
    """The render's plan, or PlanError when it cannot fit. `images`: developed images held at once (the
    image and its PNG encoding count about two); `slots`, `direct`: the branching estimator's children
    per vertex and shadow rays (BranchingEstimator); `wavefront`: the path tracer goes bounce by bounce;
    `scene_bytes`: the scene's arrays (scene_bytes())."""
    memory = available_memory() if memory is None else memory
    room = memory - scene_bytes     # what the film and the launches may take
    pixels = width * height
    passes = pass_spps(pixels, spp, MAX_PASS_SAMPLES if max_pass_samples is None else max_pass_samples)
    # in passes, the film as the passes before left it is kept through each (tracer.rendering.run_passes)
    film = film_bytes(width, height, border, float_bytes, images, films=2 if len(passes) > 1 else 1)
    if pixels * 4 >= MAX_LANES:
        raise PlanError(f"{width} x {height} is {pixels:,} pixels; the film holds at most {MAX_LANES // 4:,} "
                        f"(e.g. {fit_size(width, height, MAX_LANES // 4 - 1)})")
    if estimator == "report":
        chunk, lanes = report_tree(slots, direct, max_depth)
        chunk = min(chunk, pixels * max(passes))
        children = chunk * lanes * slots
        launch = chunk * lanes * WAVE_LANE_BYTES + children * SPAWN_LANE_BYTES
        if film + launch > room or children >= MAX_LANES:
            fit = _report_fit(slots, direct, max_depth, room - film)
            raise PlanError(f"the branching estimator's widest level holds up to {lanes:,} rays per camera sample "
                            f"(max_depth {max_depth}, {slots} children per vertex): about {gib(film + launch)} of "
                            f"memory with the film, {gib(room)} available{_besides(scene_bytes)}; {fit}")
    else:
        chunk = min(WAVEFRONT_CHUNK if wavefront else PATH_CHUNK, pixels * max(passes))
        launch = chunk * (WAVEFRONT_LANE_BYTES if wavefront else PATH_LANE_BYTES)
    plan = Plan(width, height, spp, passes, chunk, film, launch, memory, scene_bytes)
    if film + launch > room:
        per_pixel = plan.film_bytes / pixels
        raise PlanError(f"{width} x {height} needs about {gib(film + launch)} of memory (film and images "
                        f"{gib(film)}), {gib(room)} available{_besides(scene_bytes)}; at most about "
                        f"{fit_size(width, height, int((room - launch) / per_pixel))} fits")
    return plan


def _besides(scene_bytes: int) -> str:
    return f" besides the scene's {gib(scene_bytes)}" if scene_bytes >= 1 << 20 else ""


def fit_size(width: int, height: int, pixels: int) -> str:
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
