"""The microfacet BSDFs in scenes: roughconductor, roughdielectric and roughplastic read from XML with
Mitsuba's parameters and refusals, and mitsuba_scenes/roughconductor.xml, roughdielectric.xml and
roughplastic.xml rendered by both estimators against Mitsuba (Welch's t-test per 4x4 block and channel,
Bonferroni-corrected, family-wise false-positive rate ALPHA per comparison, as tests/test_agreement.py);
each scene's test also fails on a realistic mistake in its BSDF."""
import drjit as dr
import numpy as np
import pytest

import tracer
from tracer.materials import roughconductor, roughdielectric, roughplastic
from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

DEPTHS = {"path": 6, "report": 4}


def bsdf_of(tmp_path, inner: str):
    path = write_scene(tmp_path, f'<shape type="sphere">{inner}</shape>')
    return tracer.load_scene(path).spheres[0].bsdf


def test_parameters_are_read_as_mitsuba_reads_them(tmp_path):
    b = bsdf_of(tmp_path, '<bsdf type="roughconductor"><string name="material" value="Au"/>'
                          '<string name="distribution" value="GGX"/><float name="alpha" value="0.3"/>'
                          '<boolean name="sample_visible" value="false"/></bsdf>')
    assert (b.kind, b.distribution, b.alpha_u, b.alpha_v, b.sample_visible) == ("roughconductor", "ggx", 0.3, 0.3,
                                                                                 False)
    assert np.allclose(b.eta, tracer.ior.CONDUCTORS["Au"][0])
    b = bsdf_of(tmp_path, '<bsdf type="roughdielectric"><string name="int_ior" value="water"/>'
                          '<rgb name="specular_transmittance" value="0.5"/></bsdf>')
    assert (b.distribution, b.alpha_u, b.sample_visible, b.int_ior, b.ext_ior) == ("beckmann", 0.1, True, 1.333,
                                                                                   1.000277)
    assert b.specular_transmittance == (0.5, 0.5, 0.5)
    b = bsdf_of(tmp_path, '<bsdf type="roughplastic"><float name="alpha_u" value="0.2"/>'
                          '<float name="alpha_v" value="0.2"/><boolean name="nonlinear" value="true"/></bsdf>')
    assert (b.alpha_u, b.alpha_v, b.nonlinear, b.int_ior) == (0.2, 0.2, True, 1.49)


@pytest.mark.parametrize("inner, message", [
    ('<bsdf type="roughconductor"><string name="distribution" value="phong"/></bsdf>', "invalid distribution"),
    ('<bsdf type="roughconductor"><float name="alpha_u" value="0.2"/></bsdf>', "both alpha_u and alpha_v"),
    ('<bsdf type="roughdielectric"><float name="alpha" value="0.2"/><float name="alpha_u" value="0.2"/>'
     '<float name="alpha_v" value="0.2"/></bsdf>', "either alpha or alpha_u"),
    ('<bsdf type="roughplastic"><float name="alpha_u" value="0.2"/><float name="alpha_v" value="0.1"/></bsdf>',
     "nor by Mitsuba"),
    ('<bsdf type="roughdielectric"><float name="int_ior" value="1.2"/><float name="ext_ior" value="1.2"/></bsdf>',
     "must be positive and differ"),
    ('<bsdf type="roughplastic"><texture type="checkerboard" name="alpha"/></bsdf>',
     "<texture type=\"checkerboard\"> as 'alpha'"),
])
def test_refusals(tmp_path, inner, message):
    path = write_scene(tmp_path, f'<shape type="sphere">{inner}</shape>')
    errors = scene_errors(path)
    assert len(errors) == 1 and message in errors[0], errors


def compare(scene: str, estimator: str, seed: int):
    depth = DEPTHS[estimator]
    ref = mitsuba_passes(scene, PASSES, SPP, width=SIZE, height=SIZE, max_depth=depth)
    return compare_passes(plugin_passes(scene, estimator, depth, seed), ref, ALPHA)


SCENES = ["roughconductor.xml", "roughdielectric.xml", "roughplastic.xml"]


@pytest.mark.slow
@pytest.mark.parametrize("estimator", ["path", "report"])
@pytest.mark.parametrize("scene", SCENES)
def test_agrees_with_mitsuba(scene, estimator):
    result = compare(scene, estimator, 5000)
    assert result.verdict == "agree", result.summary()


def _exiting_as_entering(honest):
    """Every facet treated as lit from outside: rays leaving the glass refract with the entering index."""
    return lambda cos_i, eta: honest(dr.abs(cos_i), eta)


@pytest.mark.slow
@pytest.mark.parametrize("scene, module, name, fault", [
    # eta and k swapped in the conductor's Fresnel term
    ("roughconductor.xml", roughconductor, "fresnel_conductor",
     lambda honest: lambda cos_i, eta, k: honest(cos_i, k, eta)),
    # the wrong side of a dielectric: rays leaving it refracted as if entering
    ("roughdielectric.xml", roughdielectric, "fresnel", _exiting_as_entering),
    # the coating's transmittance left out of the diffuse base (T = 1 at every angle)
    ("roughplastic.xml", roughplastic, "coating", lambda honest: lambda ggx, alpha, eta: (
        np.ones(roughplastic.TRANSMITTANCE_RES, np.float32), honest(ggx, alpha, eta)[1])),
])
def test_fails_on_a_realistic_mistake(monkeypatch, scene, module, name, fault):
    monkeypatch.setattr(module, name, fault(getattr(module, name)))
    result = compare(scene, "path", 5000)
    assert result.verdict == "disagree", result.summary()
