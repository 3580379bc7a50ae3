import functools
import os
from pathlib import Path

import numpy as np
import pytest

from validation.verdict.check import REPORT_REFERENCE_SPP

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "mitsuba_scenes"
os.environ.setdefault("TRACER_BVH_CACHE", "off")   # tests keep nothing in the user's cache folder
os.environ.pop("CI", None)   # validate check defaults to a margin under CI: tests that want it set it themselves


@functools.lru_cache(maxsize=None)
def mitsuba_passes(scene: str, passes: int, spp: int, **params) -> np.ndarray:
    """Mitsuba's independent passes of a scene, shared by all tests of a session."""
    from validation.verdict.mitsuba_render import render_passes

    return render_passes(SCENES / scene, passes, spp, seed=12345, **params)


PASSES, SIZE, SPP = 16, 32, 64                 # the plugin agreement tests' design: the check's equal budgets
# per pass, the branching estimator: as many camera rays as the check gives it against SPP Mitsuba samples
REPORT = dict(spp=SPP // REPORT_REFERENCE_SPP, direct=4, indirect=4)


def plugin_passes(scene_name: str, estimator: str, max_depth: int, seed: int, edit=None) -> np.ndarray:
    """PASSES tracer passes of mitsuba_scenes/scene_name at SIZE x SIZE (pass k with seed `seed + k`);
    `edit(scene)` changes the loaded scene first (a fault the test must catch)."""
    import tracer
    from tracer.rendering import render

    scene = tracer.load_scene(SCENES / scene_name, width=SIZE, height=SIZE)
    if edit is not None:
        edit(scene)
    opts = dict(REPORT) if estimator == "report" else dict(spp=SPP)
    return np.stack([render(scene, estimator, seed=seed + k, max_depth=max_depth, **opts).image
                     for k in range(PASSES)])


def kernel_hashes(run) -> set[str]:
    """The hashes of the Dr.Jit kernels `run()` launches (compiled or from a cache alike), those in the
    history that `run` reads itself included (tracer.render keeps its kernel history to itself)."""
    import drjit as dr

    history, read, seen = dr.flag(dr.JitFlag.KernelHistory), dr.kernel_history, []

    def spy():
        entries = read()
        seen.extend(entries)
        return entries

    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history = spy
    try:
        read()    # clears it
        run()
        spy()
        return {k["hash"] for k in seen if k["type"] == dr.KernelType.JIT}
    finally:
        dr.kernel_history = read
        dr.set_flag(dr.JitFlag.KernelHistory, history)


@pytest.fixture
def scenes() -> Path:
    return SCENES


LAST_STARTED = ROOT / ".pytest_cache" / "last-started"


def pytest_runtest_logstart(nodeid: str, location) -> None:
    """Each test's id, written as it starts: where the process dies of a signal (a crash in compiled code),
    `make test` and `make test-fast` name the test it died in (pytest itself prints nothing more)."""
    LAST_STARTED.parent.mkdir(exist_ok=True)
    LAST_STARTED.write_text(nodeid + "\n")
