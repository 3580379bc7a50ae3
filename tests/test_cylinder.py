"""Mitsuba's `cylinder`: the open tube (p0, p1, radius, to_world), its outward normal, flip_normals, one-sided
and two-sided materials on it, rays that start on it. mitsuba_scenes/cylinders.xml rendered by both
estimators against Mitsuba: Welch's t-test per 4x4 block and channel, Bonferroni-corrected, family-wise
false-positive rate ALPHA per comparison; the same test failing when flip_normals is ignored."""
import numpy as np
import pytest

from validation.verdict.stats import compare_passes

from .conftest import PASSES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 3 comparisons: < 0.3% in all
SCENE = "cylinders.xml"


def tracer_passes(estimator: str, max_depth: int, unflip: bool = False) -> np.ndarray:
    def unflipped(scene):
        for c in scene.cylinders:
            c.flipped = False
    return plugin_passes(SCENE, estimator, max_depth, 9700, unflipped if unflip else None)


@pytest.mark.slow
@pytest.mark.parametrize("estimator, max_depth", [("path", 6), ("report", 4)])
def test_cylinders_agree_with_mitsuba(estimator, max_depth):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(tracer_passes(estimator, max_depth), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_when_flip_normals_is_ignored():
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=6)
    result = compare_passes(tracer_passes("path", 6, unflip=True), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()


@pytest.mark.parametrize("body, words", [
    ('<shape type="cylinder"><transform name="to_world"><scale x="2"/></transform></shape>', "circular"),
    ('<shape type="cylinder"><point name="p1" x="0" y="0" z="0"/></shape>', "p0 != p1"),
    ('<shape type="cylinder"><emitter type="area"/></shape>', "area emitters"),
])
def test_bad_cylinder_is_refused(tmp_path, body, words):
    (error,) = scene_errors(write_scene(tmp_path, body))
    assert words in error
