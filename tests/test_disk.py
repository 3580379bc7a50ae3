"""Mitsuba's `disk`: the unit disk of a rectangle's plane (intersection masked by x^2 + y^2 <= 1, area
pi |e1 x e2|, uniform light sampling by the concentric map), flip_normals. mitsuba_scenes/disks.xml (a disk
light, an elliptical tilted two-sided disk, a mirror disk) rendered by both estimators against Mitsuba:
Welch's t-test per 4x4 block and channel, Bonferroni-corrected, family-wise false-positive rate ALPHA per
comparison; the same test failing when the disks are their bounding squares."""
import numpy as np
import pytest

import tracer
from tracer.shapes import Rectangle
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP, mitsuba_passes, plugin_passes

from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 3 comparisons: < 0.3% in all
SCENE = "disks.xml"


def tracer_passes(estimator: str, max_depth: int, squares: bool = False) -> np.ndarray:
    def as_squares(scene):
        scene.shapes = [Rectangle(r.to_world, r.bsdf, r.radiance, r.name) if isinstance(r, Rectangle) else r
                        for r in scene.shapes]
    return plugin_passes(SCENE, estimator, max_depth, 9500, as_squares if squares else None)


@pytest.mark.slow
@pytest.mark.parametrize("estimator, max_depth", [("path", 6), ("report", 4)])
def test_disks_agree_with_mitsuba(estimator, max_depth):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(tracer_passes(estimator, max_depth), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_when_disks_are_squares():
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=6)
    result = compare_passes(tracer_passes("path", 6, squares=True), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()


def test_disk_area_and_light():
    s = tracer.load_scene(SCENES / SCENE)
    light = next(r for r in s.rectangles if r.name == "light")
    assert light.disk and light.area == pytest.approx(np.pi * 0.25 ** 2)
    assert np.allclose(light.normal, [0, -1, 0], atol=1e-12)          # flipped to face the room
