"""Mitsuba's `constant` emitter (a uniform environment): rays that leave the scene see its radiance, and
shadow rays are sent to it (a uniform direction, chosen like any light) with multiple importance sampling.
mitsuba_scenes/constant_environment.xml (the sky, an area light, diffuse, gold and glass) rendered by the
path estimator against Mitsuba: Welch's t-test per 4x4 block and channel, Bonferroni-corrected,
family-wise false-positive rate ALPHA per comparison; the same test failing when the sky's shadow-ray
density forgets the choice among the lights. The report estimator refuses the scene."""
import numpy as np
import pytest

import tracer
from tracer import SceneError
from tracer.geometry import SceneGeometry
from tracer.rendering import render
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 3 comparisons: < 0.3% in all
SCENE = "constant_environment.xml"


def tracer_passes(max_depth: int) -> np.ndarray:
    return plugin_passes(SCENE, "path", max_depth, 5000)


@pytest.mark.slow
@pytest.mark.parametrize("max_depth", [2, 5])
def test_constant_environment_agrees_with_mitsuba(max_depth):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(tracer_passes(max_depth), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_when_the_light_choice_is_forgotten(monkeypatch):
    monkeypatch.setattr(SceneGeometry, "environment_pdf", lambda self, d: 1.0 / (4.0 * np.pi))
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=2)
    result = compare_passes(tracer_passes(2), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()


def test_report_estimator_refuses_the_environment():
    scene = tracer.load_scene(SCENES / SCENE, width=4, height=4)
    assert scene.estimator_refusals("path") == []
    (line,) = scene.estimator_refusals("report")
    assert "constant" in line and "--estimator path" in line
    with pytest.raises(SceneError, match="--estimator path"):
        render(scene, "report", spp=1, max_depth=2)


def test_one_environment_only(tmp_path):
    path = write_scene(tmp_path, '<emitter type="constant"/>\n    <emitter type="constant"/>')
    (error,) = scene_errors(path)
    assert f"{path.name}:11:" in error and "only one environment" in error
