"""Mitsuba's `twosided` around any BSDF without transmission, with one BSDF for both sides or a front and a
back one: mitsuba_scenes/twosided.xml (panels of a diffuse front and a gold back seen from either side, a
two-sided mirror) rendered by both estimators against Mitsuba (Welch's t-test per 4x4 block and channel,
Bonferroni-corrected, family-wise false-positive rate ALPHA per comparison), and the same test failing when
the back shows the front's BSDF."""
import numpy as np
import pytest

import tracer
from tracer.materials import tables
from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 3 comparisons: < 0.3% in all
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import line_of, write_scene

SCENE = "twosided.xml"


def tracer_passes(estimator: str, max_depth: int) -> np.ndarray:
    return plugin_passes(SCENE, estimator, max_depth, 5000)


def test_front_and_back_are_read():
    scene = tracer.load_scene(SCENES / SCENE)
    duo = next(s.bsdf for s in scene.rectangles if s.name == "front_panel")
    assert (duo.kind, duo.twosided, duo.back.kind) == ("diffuse", True, "conductor")
    mirror = next(s.bsdf for s in scene.rectangles if s.name == "mirror_panel")
    assert (mirror.kind, mirror.twosided, mirror.back) == ("conductor", True, None)


@pytest.mark.parametrize("inner", ['<bsdf type="dielectric"/>',
                                   '<bsdf type="twosided"><bsdf type="diffuse"/></bsdf>'])
def test_what_twosided_cannot_wrap_is_refused(tmp_path, inner):
    path = write_scene(tmp_path, f'<shape type="rectangle"><bsdf type="twosided">\n{inner}\n</bsdf></shape>')
    (error,) = scene_errors(path)
    assert f"scene.xml:{line_of(path, inner)}:" in error and "twosided" in error


@pytest.mark.slow
@pytest.mark.parametrize("estimator, max_depth", [("path", 5), ("report", 4)])
def test_twosided_agrees_with_mitsuba(estimator, max_depth):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(tracer_passes(estimator, max_depth), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_when_the_back_shows_the_front(monkeypatch):
    monkeypatch.setattr(tables.MaterialTables, "back", lambda self, material, active: material)
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=5)
    result = compare_passes(tracer_passes("path", 5), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()
