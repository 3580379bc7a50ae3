"""Mitsuba 3 renders of a scene file, as independent passes so every pixel has a mean and a variance."""
from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

VARIANTS = ("llvm_ad_rgb", "scalar_rgb")


def mitsuba():
    """The mitsuba module with the first available variant of VARIANTS set."""
    import mitsuba as mi

    if mi.variant() is None:
        for variant in VARIANTS:
            if variant in mi.variants():
                try:
                    mi.set_variant(variant)
                    break
                except (ImportError, RuntimeError):
                    continue
        else:
            raise RuntimeError(f"none of Mitsuba's variants {VARIANTS} is available")
    return mi


@contextmanager
def loading() -> Iterator[None]:
    """Around Mitsuba's loaders: its bitmap reader waits forever on a Dr.Jit thread pool of one thread (as a
    suite's workers run, validation.suites.runner), so the pool has two threads while it loads."""
    import drjit as dr

    threads = dr.thread_count()
    if threads < 2:
        dr.set_thread_count(2)
    try:
        yield
    finally:
        if threads < 2:
            dr.set_thread_count(threads)


def render_passes(scene_file: str | Path, passes: int, spp: int, seed: int = 0, **params) -> np.ndarray:
    """(passes, height, width, 3) float32: `passes` independent renders of `spp` samples each.

    `params` override the scene's <default> values (width, height, max_depth, ...), as `mitsuba -D` does.
    """
    mi = mitsuba()
    with loading():
        scene = mi.load_file(str(scene_file), spp=spp, **{k: v for k, v in params.items()})
    out = [np.array(mi.render(scene, seed=(seed * 1_000_003 + k) % 2**32, spp=spp), dtype=np.float32)[..., :3]
           for k in range(passes)]
    return np.stack(out)


def version() -> str:
    import mitsuba as mi

    return f"mitsuba {mi.__version__} ({mitsuba().variant()})"
