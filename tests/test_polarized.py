"""Mitsuba's `pplastic` and `polarizer` as its RGB (unpolarized) variants render them (materials.pplastic,
materials.polarizer). pplastic's sampling follows its pdf: Pearson's chi-square test (tests/chi2.py) at
level LEVEL family-wise over CONFIGS (Sidak), failing when the sampler's lobe weight differs from the pdf's.
mitsuba_scenes/polarized.xml against Mitsuba: Welch's t-test per 4x4 block and channel, Bonferroni-corrected,
family-wise false-positive rate ALPHA; the same test failing without pplastic's (1 - F) transmission factors
and with a polarizer passing all of its transmittance."""
from dataclasses import replace

import drjit as dr
import numpy as np
import pytest

import tracer.materials.pplastic as pplastic
from tracer.jit import Array3f, Bool, Float
from tracer.materials.microfacet import microfacet
from validation.verdict.protocol import ALPHA
from validation.verdict.stats import compare_passes

from .bsdf_properties import albedo, assert_weight_is_eval_over_pdf, reciprocity, upper_pairs
from .chi2 import chi2_sphere, sidak
from .conftest import PASSES, SIZE, SPP, mitsuba_passes, plugin_passes
from .microfacet_cases import direction
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

SCENE = "polarized.xml"
LEVEL = 0.01
CONFIGS = [(("beckmann", 0.1, None, True), 0.4, (30.0, 20.0)),
           (("ggx", 0.5, 0.1, True), 0.7, (75.0, 40.0)),
           (("ggx", 0.3, None, False), 0.5, (10.0, 0.0))]


def _params(distr, weight: float) -> pplastic.PPlasticParams:
    ggx, a_u, a_v, visible = distr
    return pplastic.PPlasticParams(microfacet(ggx == "ggx", Float(a_u), None if a_v is None else Float(a_v), visible),
                                   Float(1.5), Float(weight), Array3f(0.9), Array3f(0.5, 0.3, 0.2))


def _chi2(distr, weight: float, angles, sample_weight: float | None = None):
    p, ps = _params(distr, weight), _params(distr, weight if sample_weight is None else sample_weight)
    wi = Array3f(*(float(x) for x in direction(*angles)))

    def sample(u1, u2, u3):
        bs, w = pplastic.sample(ps, wi, u1, (u2, u3), Bool(True))
        return bs.wo, (w.x != 0) | (w.y != 0) | (w.z != 0)

    return chi2_sphere(sample, lambda d: pplastic.pdf(p, wi, d, Bool(True)), samples=500_000)


@pytest.mark.parametrize("distr, weight, angles", CONFIGS)
def test_pplastic_sampling_follows_its_pdf(distr, weight, angles):
    result = _chi2(distr, weight, angles)
    assert result.passes(sidak(LEVEL, len(CONFIGS))), str(result)


def test_chi2_rejects_a_sampler_of_another_lobe_weight():
    result = _chi2(CONFIGS[0][0], 0.4, CONFIGS[0][2], sample_weight=0.6)
    assert not result.passes(sidak(LEVEL, len(CONFIGS))), str(result)


@pytest.mark.parametrize("distr, weight, angles", CONFIGS)
def test_pplastic_weight_is_eval_over_pdf(distr, weight, angles):
    wi, _ = upper_pairs(4000, 1)
    assert_weight_is_eval_over_pdf(pplastic, _params(distr, weight), wi)


def test_pplastic_is_reciprocal():
    wi, wo = upper_pairs(4000, 2)
    forward, backward = reciprocity(pplastic, _params(CONFIGS[1][0], 0.5), wi, wo)
    assert np.count_nonzero(forward) > 1000 and np.allclose(backward, forward, rtol=2e-3, atol=1e-5)


def test_pplastic_white_furnace():
    """A white pplastic (diffuse and specular reflectance 1) reflects at most what it receives, at normal to
    grazing incidence (the mean sample weight; bound 1 + 4.5 standard errors; the same bound fails on the
    smooth plastic without its exit Fresnel factor: tests/test_bsdf_contract.py)."""
    for distr, _, _ in CONFIGS:
        p = replace(_params(distr, 0.5), diffuse_reflectance=Array3f(1.0), specular_reflectance=Array3f(1.0))
        for theta in (0.0, 60.0, 85.0):
            mean, error = albedo(pplastic, p, np.repeat(direction(theta)[:, None], 50_000, axis=1))
            assert np.all(mean <= 1.0 + 4.5 * error) and np.all(mean > 0.1), (distr, theta, mean, error)


def compared(seed: int, edit=None):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=4)
    return compare_passes(plugin_passes(SCENE, "path", 4, seed, edit), ref, ALPHA)


def test_polarized_scene_agrees_with_mitsuba():
    result = compared(9100)
    assert result.verdict == "agree", result.summary()


def _clear_polarizers(scene):
    for s in scene.shapes:
        if s.bsdf.kind == "polarizer":
            s.bsdf = replace(s.bsdf, reflectance=tuple(2 * x for x in s.bsdf.reflectance))


def test_fails_with_a_polarizer_passing_all_its_transmittance():
    result = compared(9200, _clear_polarizers)
    assert result.verdict == "disagree", result.summary()


def test_fails_without_the_transmission_factors(monkeypatch):
    evaluate = pplastic.eval

    def no_fresnel(p, wi, wo, active):      # the base seen without the interface: rho cos / pi
        value = evaluate(replace(p, diffuse_reflectance=Array3f(0.0)), wi, wo, active)
        base = p.diffuse_reflectance * (wo.z * dr.inv_pi)
        return dr.select(active & (wi.z > 0) & (wo.z > 0), value + base, 0.0)

    monkeypatch.setattr(pplastic, "eval", no_fresnel)
    result = compared(9300)
    assert result.verdict == "disagree", result.summary()


@pytest.mark.parametrize("body, words", [
    ('<shape type="rectangle"><bsdf type="pplastic"><float name="eta" value="1.4"/>'
     '<float name="int_ior" value="1.5"/></bsdf></shape>', "either eta or int_ior"),
    ('<shape type="rectangle"><bsdf type="pplastic"><float name="int_ior" value="1"/>'
     '<float name="ext_ior" value="1"/></bsdf></shape>', "must be positive and differ"),
    ('<shape type="rectangle"><bsdf type="polarizer"><rgb name="transmittance" value="1.5"/></bsdf></shape>',
     "transmittance must lie in [0, 1]"),
    ('<shape type="rectangle"><bsdf type="polarizer"><float name="thetta" value="1"/></bsdf></shape>', "thetta"),
])
def test_bad_polarized_bsdf_is_refused(tmp_path, body, words):
    (error,) = scene_errors(write_scene(tmp_path, body))
    assert words in error
