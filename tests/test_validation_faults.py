"""The harness's power: each known fault injected into the tracer (validation.faults) makes Welch's test
against Mitsuba fail, while the correct tracer passes at the same settings.

Every comparison is Welch's test per 4x4 block and channel, Bonferroni-corrected, with family-wise
false-positive rate ALPHA = 1e-3: the five "correct tracer passes" tests together fail by chance with
probability below 0.5%. The "fault is caught" tests can fail only by lack of power.
"""
import numpy as np
import pytest

import tracer
from tracer.rendering import render
from validation.faults import FAULTS
from validation.stats import welch_test

from .conftest import SCENES, mitsuba_passes

ALPHA = 1e-3
PASSES = 16      # independent images of each renderer
SIZE = 32
# samples per pass of the path estimator and Mitsuba: each fault's own `spp` (64; 256 for Schlick's small bias)
REPORT = dict(spp=2, direct=4, indirect=4)   # per pass, report estimator


def tracer_passes(scene_name: str, estimator: str, max_depth: int, spp: int) -> np.ndarray:
    scene = tracer.load_scene(SCENES / scene_name, width=SIZE, height=SIZE)
    opts = dict(REPORT) if estimator == "report" else dict(spp=spp)
    return np.stack([render(scene, estimator, seed=2000 + k, max_depth=max_depth, **opts).image
                     for k in range(PASSES)])


def compare(fault, faulty: bool):
    ref = mitsuba_passes(fault.scene, PASSES, fault.spp, width=SIZE, height=SIZE, max_depth=fault.max_depth)
    if faulty:
        with fault.inject():
            ours = tracer_passes(fault.scene, fault.estimator, fault.max_depth, fault.spp)
    else:
        ours = tracer_passes(fault.scene, fault.estimator, fault.max_depth, fault.spp)
    return welch_test(ours, ref, alpha=ALPHA)


@pytest.mark.parametrize("name", list(FAULTS))
def test_fault_is_caught(name):
    result = compare(FAULTS[name], faulty=True)
    assert not result.passed, f"{name} not detected: {result.summary()}"


@pytest.mark.parametrize("name", list(FAULTS))
def test_correct_tracer_passes_at_the_same_settings(name):
    result = compare(FAULTS[name], faulty=False)
    assert result.passed, result.summary()


def test_injection_is_undone():
    """After a fault's context the tracer renders exactly what it rendered before."""
    fault = FAULTS["missing_inv_pi"]
    scene = tracer.load_scene(SCENES / fault.scene, width=8, height=8)
    before = render(scene, "path", spp=4, seed=3, max_depth=2).image
    with fault.inject():
        during = render(scene, "path", spp=4, seed=3, max_depth=2).image
    after = render(scene, "path", spp=4, seed=3, max_depth=2).image
    assert not np.array_equal(before, during)
    np.testing.assert_array_equal(before, after)
