"""Every module imports on its own, first in a fresh interpreter (no import cycle depends on what was
imported before it)."""
import os
import pkgutil
import subprocess
import sys

import pytest

import tracer
import validation

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SKIP = {"validation.benchmark.bench", "validation.verdict.mitsuba_render",   # import Mitsuba, whose variant a child sets
        "validation.verdict.peers.cycles_worker", "validation.verdict.peers.luxcore_worker"}   # run in the peers' Python


def modules() -> list[str]:
    return [m.name for pkg in (tracer, validation) for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + ".")
            if m.name not in SKIP and not m.name.endswith("__main__")]


@pytest.mark.slow   # a fresh interpreter per module: about 40 s on two loaded cores
def test_every_module_imports_first():
    env = {**os.environ, "PYTHONPATH": ROOT}
    procs = {m: subprocess.Popen([sys.executable, "-c", f"import {m}"], env=env, cwd=ROOT,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for m in modules()}
    failed = {}
    for m, p in procs.items():
        _, err = p.communicate(timeout=120)
        if p.returncode:
            failed[m] = err.strip().splitlines()[-1]
    assert not failed, failed
