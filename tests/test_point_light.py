"""Mitsuba's `point` emitter: shadow rays to it (intensity / d^2, a delta light: MIS weight 1), chosen
uniformly among the lights. mitsuba_scenes/point_lights.xml (two point lights, one by position and one by
to_world with a spectral intensity, and an area light) rendered by both estimators against Mitsuba:
Welch's t-test per 4x4 block and channel, Bonferroni-corrected, family-wise false-positive rate ALPHA per
comparison; the same test failing when a point light's intensity falls off as 1/d."""
import drjit as dr
import numpy as np
import pytest

from tracer.integrators import direct
from tracer.lights import POINT_LIGHT
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 4 comparisons: < 0.4% in all
SCENE = "point_lights.xml"


def tracer_passes(estimator: str, max_depth: int) -> np.ndarray:
    return plugin_passes(SCENE, estimator, max_depth, 8000)


@pytest.mark.slow
@pytest.mark.parametrize("estimator, max_depth", [("path", 2), ("path", 5), ("report", 4)])
def test_point_lights_agree_with_mitsuba(estimator, max_depth):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(tracer_passes(estimator, max_depth), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_with_a_1_over_d_falloff(monkeypatch):
    sample = direct.sample_direct

    def one_over_d(geo, surf, bsdf, u_select, u1, u2, active):
        ds = sample(geo, surf, bsdf, u_select, u1, u2, active)
        ls = geo.sample_light(u_select, u1, u2)
        d = dr.norm(ls.y - surf.p)
        ds.value = dr.select(ls.prim == POINT_LIGHT, ds.value * d, ds.value)
        return ds

    monkeypatch.setattr(direct, "sample_direct", one_over_d)
    from tracer.integrators import path
    monkeypatch.setattr(path, "sample_direct", one_over_d)
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=2)
    result = compare_passes(tracer_passes("path", 2), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()


def test_position_and_to_world_together_are_refused(tmp_path):
    path = write_scene(tmp_path, '<emitter type="point"><point name="position" x="1" y="2" z="3"/>'
                                 '<transform name="to_world"><translate x="1"/></transform></emitter>')
    (error,) = scene_errors(path)
    assert "either position or to_world" in error
