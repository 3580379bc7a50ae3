"""Smooth conductors as Mitsuba's `conductor`: the exact Fresnel reflectance of a complex index, its named
materials, eta and k given as RGB or spectra, a specular reflectance; and mitsuba_scenes/conductors.xml
rendered by both estimators against Mitsuba (Welch's t-test per 4x4 block and channel, Bonferroni-corrected,
family-wise false-positive rate ALPHA per comparison), the same test failing on a perfect mirror."""
import numpy as np
import pytest

import tracer
from tracer.materials import conductor
from tracer.materials.fresnel import fresnel_conductor
from tracer.ior import CONDUCTORS
from tracer.jit import Array3f, Float
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import mi  # noqa: F401  (the fixture)
from .test_xml_loader import write_scene

from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 3 comparisons: < 0.3% in all


def test_named_conductors_are_mitsubas(mi):
    for name, (eta, k) in CONDUCTORS.items():
        params = mi.traverse(mi.load_dict({"type": "conductor", "material": name}))
        assert np.allclose(eta, np.ravel(params["eta.value"]), rtol=1e-6, atol=1e-7), name
        assert np.allclose(k, np.ravel(params["k.value"]), rtol=1e-6, atol=1e-7), name


def test_spectral_eta_and_k_are_mitsubas(tmp_path, mi):
    eta, k = "400:1.6, 550:0.9, 700:0.25", "400:1.9, 550:2.6, 700:3.9"
    path = write_scene(tmp_path, f'<shape type="sphere"><bsdf type="conductor"><spectrum name="eta" value="{eta}"/>'
                                 f'<spectrum name="k" value="{k}"/></bsdf></shape>')
    ours = tracer.load_scene(path).spheres[0].bsdf
    params = mi.traverse(mi.load_string(f'<bsdf version="3.0.0" type="conductor"><spectrum name="eta" value="{eta}"/>'
                                        f'<spectrum name="k" value="{k}"/></bsdf>'))
    assert np.allclose(ours.eta, np.ravel(params["eta.value"]), rtol=2e-6)
    assert np.allclose(ours.k, np.ravel(params["k.value"]), rtol=2e-6)


def test_fresnel_conductor_is_mitsubas(mi):
    import drjit as dr
    rng = np.random.default_rng(5)
    cos = np.concatenate([[1.0, 1e-4, 0.5], rng.uniform(0, 1, 40)]).astype(np.float32)
    eta = rng.uniform(0.05, 4, (len(cos), 3)).astype(np.float32)
    k = rng.uniform(0, 6, (len(cos), 3)).astype(np.float32)
    ours = fresnel_conductor(Float(cos), Array3f(*(Float(eta[:, c]) for c in range(3))),
                                  Array3f(*(Float(k[:, c]) for c in range(3)))).numpy().T   # (n, 3)
    ref = np.array([[mi.fresnel_conductor(float(c), dr.scalar.Complex2f(float(e), float(kk)))
                     for e, kk in zip(eta[i], k[i])] for i, c in enumerate(cos)])
    assert np.allclose(ours, ref, rtol=2e-5, atol=1e-6)


def test_perfect_mirror_reflects_everything():
    cos = Float(np.linspace(1e-4, 1, 50, dtype=np.float32))
    f = np.asarray(fresnel_conductor(cos, Array3f(0.0), Array3f(1.0)).numpy())
    assert np.all(f == 1.0)


def tracer_passes(estimator: str, max_depth: int) -> np.ndarray:
    return plugin_passes("conductors.xml", estimator, max_depth, 4000)


@pytest.mark.slow
@pytest.mark.parametrize("estimator, max_depth", [("path", 6), ("report", 4)])
def test_conductors_agree_with_mitsuba(estimator, max_depth):
    ref = mitsuba_passes("conductors.xml", PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(tracer_passes(estimator, max_depth), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_on_perfect_mirrors(monkeypatch):
    monkeypatch.setattr(conductor, "fresnel_conductor", lambda cos_i, eta, k: Array3f(1.0))
    ref = mitsuba_passes("conductors.xml", PASSES, SPP, width=SIZE, height=SIZE, max_depth=6)
    result = compare_passes(tracer_passes("path", 6), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()
