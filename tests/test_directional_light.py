"""Mitsuba's `directional` emitter: irradiance arriving along one direction from infinitely far (shadow
rays leave the scene, MIS weight 1). mitsuba_scenes/directional_lights.xml (two directional lights, one by
direction and one by to_world with a spectral irradiance, and an area light) rendered by both estimators
against Mitsuba: Welch's t-test per 4x4 block and channel, Bonferroni-corrected, family-wise
false-positive rate ALPHA per comparison; the same test failing with the light reversed."""
import numpy as np
import pytest

from validation.verdict.stats import compare_passes

from .conftest import PASSES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 3 comparisons: < 0.3% in all
SCENE = "directional_lights.xml"


def tracer_passes(estimator: str, max_depth: int, reverse: bool = False) -> np.ndarray:
    def reversed_lights(scene):
        for light in scene.directional_lights:
            light.direction = -light.direction
    return plugin_passes(SCENE, estimator, max_depth, 9600, reversed_lights if reverse else None)


@pytest.mark.slow
@pytest.mark.parametrize("estimator, max_depth", [("path", 5), ("report", 3)])
def test_directional_lights_agree_with_mitsuba(estimator, max_depth):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(tracer_passes(estimator, max_depth), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_with_the_light_reversed():
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=2)
    result = compare_passes(tracer_passes("path", 2, reverse=True), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()


def test_direction_and_to_world_together_are_refused(tmp_path):
    path = write_scene(tmp_path, '<emitter type="directional"><vector name="direction" x="0" y="-1" z="0"/>'
                                 '<transform name="to_world"><rotate x="1" angle="10"/></transform></emitter>')
    (error,) = scene_errors(path)
    assert "either direction or to_world" in error
