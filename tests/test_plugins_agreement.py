"""The loader's features rendered, against Mitsuba on the same XML: mitsuba_scenes/mesh_formats.xml (an
<include>d file of spectral reflectances, PLY and serialized meshes found through <path>, a top-level light
used by <ref>, flip_normals, a two-sided wall, a camera given by its focal length). Welch's t-test per 4x4
block and channel, Bonferroni-corrected, family-wise false-positive rate ALPHA per comparison, as in
tests/test_agreement.py; and the same test failing when the light's spectrum is weighted by D65 as a
reflectance's is."""
import numpy as np
import pytest

from tracer import spectra
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SIZE, SPP, mitsuba_passes, plugin_passes

from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 3 comparisons: < 0.3% in all
SCENE = "mesh_formats.xml"


def tracer_passes(estimator: str, max_depth: int) -> np.ndarray:
    return plugin_passes(SCENE, estimator, max_depth, 3000)


@pytest.mark.slow
@pytest.mark.parametrize("estimator, max_depth", [("path", 6), ("report", 3)])
def test_mesh_formats_agree_with_mitsuba(estimator, max_depth):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(tracer_passes(estimator, max_depth), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_when_radiance_is_weighted_by_d65_like_a_reflectance(monkeypatch):
    def d65_everywhere(text, emitter, unbounded=False):      # every spectrum in the scene is a wavelength:value list
        return spectra.list_to_srgb(*spectra.parse_pairs(text), bounded=not emitter, illuminant=True)

    monkeypatch.setattr(spectra, "to_rgb", d65_everywhere)
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=6)
    result = compare_passes(tracer_passes("path", 6), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()
