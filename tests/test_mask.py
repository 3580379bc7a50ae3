"""Mitsuba's `mask`: mitsuba_scenes/mask.xml (a diffuse panel of opacity 0.35 in front of a sphere, a
two-sided gold panel of opacity 0.6) rendered by both estimators against Mitsuba (Welch's t-test per 4x4
block and channel, Bonferroni-corrected, family-wise false-positive rate ALPHA per comparison), and the same
test failing when the opacity is ignored (each panel scatters every ray)."""
import numpy as np
import pytest

import tracer
from tracer.materials import tables
from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 3 comparisons: < 0.3% in all
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

SCENE = "mask.xml"


def tracer_passes(estimator: str, max_depth: int) -> np.ndarray:
    return plugin_passes(SCENE, estimator, max_depth, 7000)


def test_opacity_and_nested_bsdf_are_read():
    veil = next(s.bsdf for s in tracer.load_scene(SCENES / SCENE).rectangles if s.name == "gold_veil")
    assert (veil.kind, veil.twosided, veil.opacity) == ("conductor", True, 0.6)


def test_opacity_outside_the_unit_interval_is_refused(tmp_path):
    path = write_scene(tmp_path, '<shape type="rectangle"><bsdf type="mask"><float name="opacity" value="1.5"/>'
                                 '<bsdf type="diffuse"/></bsdf></shape>')
    (error,) = scene_errors(path)
    assert "opacity must lie in [0, 1]" in error


def test_a_textured_opacity_in_a_mask_with_opacity_is_refused(tmp_path):
    path = write_scene(tmp_path, '<shape type="rectangle"><bsdf type="mask">\n<texture type="checkerboard" '
                                 'name="opacity"/>\n<bsdf type="mask"><bsdf type="diffuse"/></bsdf></bsdf></shape>')
    (error,) = scene_errors(path)
    assert "scene.xml:" in error and "textured opacity" in error


def test_report_estimator_refuses_a_masked_dielectric(tmp_path):
    path = write_scene(tmp_path, '<shape type="rectangle"><bsdf type="mask"><bsdf type="dielectric"/></bsdf></shape>')
    (line,) = tracer.load_scene(path).estimator_refusals("report")
    assert "'mask' of 'dielectric'" in line


@pytest.mark.slow
@pytest.mark.parametrize("estimator, max_depth", [("path", 5), ("report", 4)])
def test_mask_agrees_with_mitsuba(estimator, max_depth):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(tracer_passes(estimator, max_depth), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_when_the_opacity_is_ignored(monkeypatch):
    monkeypatch.setattr(tables.MaterialTables, "opacity", lambda self, surf, active: 1.0 + 0.0 * tables.Float(surf.material))
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=5)
    result = compare_passes(tracer_passes("path", 5), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()
