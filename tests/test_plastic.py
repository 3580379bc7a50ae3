"""Mitsuba's smooth `plastic`: a Fresnel-weighted specular layer over a diffuse base (linear and nonlinear
internal scattering, tinted specular layer, named IOR), sampled with Mitsuba's component probability and
combined with shadow rays by MIS. mitsuba_scenes/plastic.xml rendered by the path estimator against
Mitsuba: Welch's t-test per 4x4 block and channel, Bonferroni-corrected, family-wise false-positive rate
ALPHA per comparison; the same test failing without the (1 - F) factors of the diffuse layer."""
import numpy as np
import pytest

import tracer
from tracer.materials import plastic
from tracer.materials.fresnel import fresnel_diffuse_reflectance
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import mi  # noqa: F401  (the fixture)

from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 3 comparisons: < 0.3% in all
SCENE = "plastic.xml"


def tracer_passes(max_depth: int) -> np.ndarray:
    return plugin_passes(SCENE, "path", max_depth, 9000)


@pytest.mark.slow
@pytest.mark.parametrize("max_depth", [2, 5])
def test_plastic_agrees_with_mitsuba(max_depth):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(tracer_passes(max_depth), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_without_the_interface_transmission(monkeypatch):
    diffuse = plastic.diffuse_layer
    monkeypatch.setattr(plastic, "diffuse_layer",
                        lambda albedo, fdr, nl, inv_eta2, f_i, f_o: diffuse(albedo, fdr, nl, inv_eta2, 0.0, 0.0))
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=2)
    result = compare_passes(tracer_passes(2), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()


@pytest.mark.parametrize("eta", [1 / 1.49, 1.49, 0.8, 2.4, 1.0001])
def test_diffuse_fresnel_reflectance_is_mitsubas(eta, mi):
    # Mitsuba evaluates the fit in float32: equal to its rounding (the fit cancels near eta = 1)
    assert fresnel_diffuse_reflectance(eta) == pytest.approx(mi.fresnel_diffuse_reflectance(eta), abs=5e-7)


def test_report_estimator_refuses_plastic():
    (line,) = tracer.load_scene(SCENES / SCENE).estimator_refusals("report")
    assert "plastic" in line and "--estimator path" in line
