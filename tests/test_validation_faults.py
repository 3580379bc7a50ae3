"""The check's power: each known fault injected into the tracer (validation.suites.faults) makes `validate check`'s
function disagree with Mitsuba, while the correct tracer agrees at the same settings.

Each comparison has family-wise false-positive rate ALPHA = 1e-3 (measured: reports/calibration.md): the five
"correct tracer agrees" tests together fail by chance with probability below 0.5%. The "fault is caught"
tests can fail only by lack of power.
"""
import numpy as np
import pytest

import tracer
from tracer.rendering import render
from validation.verdict.check import Settings, check
from validation.suites.faults import FAULTS
from validation.suites.power import REPORT
from validation.verdict.renderers import TracerRenderer

from .conftest import SCENES

REPORT_SPP = 2   # camera rays per pass of the branching estimator; the path estimator uses each fault's spp


def verdict(fault, faulty: bool):
    renderer = TracerRenderer(fault.estimator, **(REPORT if fault.estimator == "report" else {}))
    spp = REPORT_SPP if fault.estimator == "report" else fault.spp
    settings = Settings(spp=spp, max_spp=spp)
    if faulty:
        with fault.inject():
            return check(SCENES / fault.scene, renderer, fault.max_depth, settings=settings)
    return check(SCENES / fault.scene, renderer, fault.max_depth, settings=settings)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(FAULTS))
def test_fault_is_caught(name):
    result = verdict(FAULTS[name], faulty=True)
    assert result.verdict == "disagree", f"{name} not detected: {result.line()}"


@pytest.mark.slow
@pytest.mark.parametrize("name", list(FAULTS))
def test_correct_tracer_agrees_at_the_same_settings(name):
    result = verdict(FAULTS[name], faulty=False)
    assert result.verdict == "agree", result.line()


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
