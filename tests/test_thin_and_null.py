"""Mitsuba's `thindielectric` and `null`: mitsuba_scenes/thin_and_null.xml (a thin glass pane in front of a
sphere, a null panel that blocks shadow rays while sampled rays pass through it) rendered by both estimators
against Mitsuba (Welch's t-test per 4x4 block and channel, Bonferroni-corrected, family-wise false-positive
rate ALPHA per comparison), and the same test failing on a pane without its internal reflections and on a
null surface that absorbs."""
import numpy as np
import pytest

from tracer.jit import Array3f
from tracer.materials import null, thindielectric
from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 4 comparisons: < 0.4% in all
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

SCENE = "thin_and_null.xml"


def tracer_passes(estimator: str, max_depth: int) -> np.ndarray:
    return plugin_passes(SCENE, estimator, max_depth, 6000)


def test_slab_reflectance_sums_the_internal_reflections():
    r = np.array([0.0, 0.04, 0.3, 1.0])
    series = r + sum((1 - r) ** 2 * r ** (2 * k + 1) for k in range(200))
    assert np.allclose(thindielectric.slab_reflectance(r), series)


def test_a_transmittance_above_1_is_refused(tmp_path):
    path = write_scene(tmp_path, '<shape type="rectangle"><bsdf type="thindielectric">\n'
                                 '<rgb name="specular_transmittance" value="1.5"/>\n</bsdf></shape>')
    (error,) = scene_errors(path)
    assert "specular_transmittance must lie in [0, 1]" in error


@pytest.mark.slow
@pytest.mark.parametrize("estimator, max_depth", [("path", 5), ("report", 4)])
def test_thin_and_null_agree_with_mitsuba(estimator, max_depth):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(tracer_passes(estimator, max_depth), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_without_the_internal_reflections(monkeypatch):
    monkeypatch.setattr(thindielectric, "slab_reflectance", lambda r: r)
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=5)
    result = compare_passes(tracer_passes("path", 5), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()


@pytest.mark.slow
def test_fails_when_null_absorbs(monkeypatch):
    sample = null.sample
    monkeypatch.setattr(null, "sample", lambda *args: (sample(*args)[0], Array3f(0.0)))
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=5)
    result = compare_passes(tracer_passes("path", 5), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()
