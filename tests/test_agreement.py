"""Both estimators against Mitsuba's `path` integrator on the same XML: Welch's t-test per 4x4 block and
channel, Bonferroni-corrected (validation.stats), with family-wise false-positive rate ALPHA per
comparison — and the same test shown to fail on a wrong image and on the report code's estimator bug.
"""
import numpy as np
import pytest

import tracer
from tracer.integrators import report as report_estimator
from tracer.rendering import render
from validation.stats import welch_test

from .conftest import SCENES, mitsuba_passes

ALPHA = 1e-3     # family-wise false-positive rate of one comparison; 11 comparisons: < 1.1% in all
PASSES = 16
SIZE = 32
SPP = 64         # per pass, path estimator and Mitsuba
REPORT = dict(spp=2, direct=4, indirect=4)   # per pass; any N, M is unbiased


def tracer_passes(scene_name, estimator, max_depth, **kw):
    scene = tracer.load_scene(SCENES / scene_name, width=SIZE, height=SIZE)
    opts = dict(REPORT) if estimator == "report" else dict(spp=SPP)
    opts.update(kw)
    return np.stack([render(scene, estimator, seed=1000 + k, max_depth=max_depth, **opts).image
                     for k in range(PASSES)])


def reference(scene_name, max_depth):
    return mitsuba_passes(scene_name, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)


@pytest.mark.parametrize("estimator", ["path", "report"])
@pytest.mark.parametrize("max_depth", [2, 3, 4, 5])
def test_hexagon_room_agrees_with_mitsuba(estimator, max_depth):
    ours = tracer_passes("hexagon_room.xml", estimator, max_depth)
    result = welch_test(ours, reference("hexagon_room.xml", max_depth), alpha=ALPHA)
    assert result.passed, result.summary()


@pytest.mark.parametrize("max_depth", [6, -1])
def test_cornell_box_path_agrees_with_mitsuba(max_depth):
    ours = tracer_passes("cornell_box.xml", "path", max_depth)
    result = welch_test(ours, reference("cornell_box.xml", max_depth), alpha=ALPHA)
    assert result.passed, result.summary()


def test_uniform_hemisphere_sampling_agrees_with_mitsuba():
    ours = tracer_passes("hexagon_room.xml", "report", 3, hemisphere="uniform")
    result = welch_test(ours, reference("hexagon_room.xml", 3), alpha=ALPHA)
    assert result.passed, result.summary()


def test_fails_on_a_deliberately_wrong_image():
    ours = tracer_passes("hexagon_room.xml", "path", 3) * 1.05
    result = welch_test(ours, reference("hexagon_room.xml", 3), alpha=ALPHA)
    assert not result.passed, result.summary()


def test_fails_on_the_report_codes_double_cosine(monkeypatch):
    """The report's code weights cosine-sampled directions by the cosine a second time."""
    correct = report_estimator.hemisphere_sample

    def double_cosine(albedo, u1, u2, hemisphere):
        local, weight = correct(albedo, u1, u2, hemisphere)
        return local, weight * local.z

    monkeypatch.setattr(report_estimator, "hemisphere_sample", double_cosine)
    ours = tracer_passes("hexagon_room.xml", "report", 3)
    result = welch_test(ours, reference("hexagon_room.xml", 3), alpha=ALPHA)
    assert not result.passed, result.summary()


@pytest.mark.parametrize("estimator", ["path", "report"])
def test_mesh_light_smooth_normals_twosided_agree_with_mitsuba(estimator):
    """Two lights (one a mesh), a smooth-normal mesh, a two-sided floor, mirror and glass spheres."""
    scene_file = SCENES.parent / "tests" / "data" / "two_lights.xml"
    scene = tracer.load_scene(scene_file)
    opts = dict(REPORT) if estimator == "report" else dict(spp=SPP)
    ours = np.stack([render(scene, estimator, seed=2000 + k, max_depth=4, **opts).image for k in range(PASSES)])
    from validation.mitsuba_render import render_passes
    ref = render_passes(scene_file, PASSES, SPP, seed=7, max_depth=4)
    result = welch_test(ours, ref, alpha=ALPHA)
    assert result.passed, result.summary()
