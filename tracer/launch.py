"""Launching samples: consecutive chunks of a pass, the random streams of a seed, and a pass of path
samples splatted into a film."""
from __future__ import annotations

import drjit as dr

from . import compile_clock, memory_guard
from .film import Film
from .jit import UInt32, opaque_u32
from .plan import PATH_CHUNK


def chunks(total: int, size: int, progress: bool, label: str):
    """(start, count) of consecutive launches of at most `size` samples, with a progress bar if `progress`."""
    bar = _bar(total, label) if progress else None
    for start in range(0, total, size):
        n = min(size, total - start)
        yield start, n
        compile_clock.lap()    # the launch's kernels leave Dr.Jit's history
        memory_guard.check()
        if bar is not None:
            bar.update(n)
    if bar is not None:
        bar.close()


def _bar(total: int, label: str):
    from tqdm import tqdm      # here: its import takes 0.04 s, a tenth of a small scene's whole process
    return tqdm(total=total, unit="spl", unit_scale=True, desc=label, leave=False)


def seed_state(seed: int, *stream: int) -> int:
    """The initial state of the random streams `stream` of `seed` (seeded_rng's seed)."""
    h = seed & 0xFFFFFFFFFFFFFFFF
    for s in stream:
        h = (h * 0x9E3779B97F4A7C15 + s + 1) % 2**64
    return h


def trace_pass(film: Film, sampler, total: int, pixel_of, state: int, progress: bool, label: str,
               squares: Film | None = None, chunk: int = PATH_CHUNK, run: int = 1) -> int:
    """`total` samples into `film`, in launches of `chunk`: sample k goes through pixel pixel_of(k)
    and `sampler(sample, pixel, state)` (as PathEstimator.samples) traces it. `squares`, if given, sums the
    squared radiance; `run`: consecutive samples that share a pixel (Film.put). Returns the rays traced."""
    rays = 0
    for start, n in chunks(total, chunk, progress, label):
        sample = dr.arange(UInt32, n) + opaque_u32(start)
        x, y, L, count = sampler(sample, pixel_of(sample), state)
        film.put(x, y, L, run=run)
        if squares is not None:
            squares.put(x, y, L * L, run=run)
        launched = dr.sum(count)
        dr.eval(film.data, launched, *([] if squares is None else [squares.data]))
        rays += int(launched[0])
    return rays
