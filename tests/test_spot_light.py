"""Mitsuba's `spot` emitter: a point light along to_world's +z with full intensity within beam_width and a
linear falloff in angle to 0 at cutoff_angle. mitsuba_scenes/spot_lights.xml (two spots, one with the
default beam width and one spectral, a point light, an area light) rendered by both estimators against
Mitsuba: Welch's t-test per 4x4 block and channel, Bonferroni-corrected, family-wise false-positive rate
ALPHA per comparison; the same test failing with a hard-edged cone."""
import numpy as np
import pytest

from tracer.lights import PointLight
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 3 comparisons: < 0.3% in all
SCENE = "spot_lights.xml"


def tracer_passes(estimator: str, max_depth: int) -> np.ndarray:
    return plugin_passes(SCENE, estimator, max_depth, 9800)


@pytest.mark.slow
@pytest.mark.parametrize("estimator, max_depth", [("path", 5), ("report", 3)])
def test_spot_lights_agree_with_mitsuba(estimator, max_depth):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(tracer_passes(estimator, max_depth), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_with_a_hard_edged_cone(monkeypatch):
    cone = PointLight.cone

    def hard(self):
        axis, cos_cutoff, cos_beam, cutoff, inv_width = cone(self)
        return axis, cos_cutoff, cos_cutoff, cutoff, inv_width   # full intensity up to the cutoff

    monkeypatch.setattr(PointLight, "cone", hard)
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=2)
    result = compare_passes(tracer_passes("path", 2), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()


@pytest.mark.parametrize("body, words", [
    ('<emitter type="spot"><float name="beam_width" value="30"/></emitter>', "beam_width < cutoff_angle"),
    ('<emitter type="spot"><transform name="to_world"><scale value="2"/></transform></emitter>', "rotation"),
    ('<emitter type="spot"><texture type="checkerboard" name="texture"/></emitter>', "texture"),
])
def test_bad_spot_is_refused(tmp_path, body, words):
    (error,) = scene_errors(write_scene(tmp_path, body))
    assert words in error
