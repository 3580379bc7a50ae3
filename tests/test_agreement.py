"""Both estimators against Mitsuba's `path` integrator on the same XML, through `validate check`'s function
(validation.verdict.check): equal-budget Welch tests per 4x4 block and channel and on the image means,
Bonferroni-corrected, family-wise false-positive rate ALPHA per comparison (measured: reports/calibration.md)
— and the same check shown to disagree on a wrong image and on the report code's estimator bug.

A failing comparison writes ours, the reference, their difference and the rejected blocks under
out/test-agreement/ (the check's --output images).
"""
from pathlib import Path

import pytest

from validation.verdict.check import Settings, check
from validation.suites.faults import FAULTS
from validation.verdict.protocol import ALPHA
from validation.verdict.renderers import ExternalRenderer, TracerRenderer

from .conftest import ROOT, SCENES

pytestmark = pytest.mark.slow
OUT = ROOT / "out" / "test-agreement"
REPORT = TracerRenderer("report", direct=4, indirect=4)
SETTINGS = Settings(alpha=ALPHA)     # 16 passes of 64 spp (report: 2 camera rays), 32 x 32


def verdict(scene_file: Path, renderer, max_depth: int, settings: Settings = SETTINGS):
    return check(scene_file, renderer, max_depth, settings=settings, output=OUT)


@pytest.mark.parametrize("estimator", ["path", "report"])
@pytest.mark.parametrize("max_depth", [2, 3, 4, 5])
def test_hexagon_room_agrees_with_mitsuba(estimator, max_depth):
    renderer = REPORT if estimator == "report" else TracerRenderer("path")
    result = verdict(SCENES / "hexagon_room.xml", renderer, max_depth)
    assert result.verdict == "agree", result.line()


@pytest.mark.parametrize("max_depth", [6, -1])
def test_cornell_box_path_agrees_with_mitsuba(max_depth):
    result = verdict(SCENES / "cornell_box.xml", TracerRenderer("path"), max_depth)
    assert result.verdict == "agree", result.line()


def test_uniform_hemisphere_sampling_agrees_with_mitsuba():
    renderer = TracerRenderer("report", direct=4, indirect=4, hemisphere="uniform")
    result = verdict(SCENES / "hexagon_room.xml", renderer, 3)
    assert result.verdict == "agree", result.line()


@pytest.mark.parametrize("estimator", ["path", "report"])
def test_mesh_light_smooth_normals_twosided_agree_with_mitsuba(estimator):
    """Two lights (one a mesh), a smooth-normal mesh, a two-sided floor, mirror and glass spheres."""
    renderer = REPORT if estimator == "report" else TracerRenderer("path")
    result = verdict(ROOT / "tests" / "data" / "two_lights.xml", renderer, 4)
    assert result.verdict == "agree", result.line()


def test_disagrees_on_a_deliberately_wrong_image(monkeypatch):
    """The tracer's path estimator with its image 5% too bright."""
    import tracer.rendering

    correct = tracer.rendering.render

    def too_bright(*args, **kwargs):
        result = correct(*args, **kwargs)
        result.image *= 1.05
        return result

    monkeypatch.setattr(tracer.rendering, "render", too_bright)
    result = verdict(SCENES / "hexagon_room.xml", TracerRenderer("path"), 3)
    assert result.verdict == "disagree", result.line()


def test_disagrees_on_the_report_codes_double_cosine():
    """The report's code weights cosine-sampled directions by the cosine a second time."""
    with FAULTS["double_cosine"].inject():
        result = verdict(SCENES / "hexagon_room.xml", REPORT, 3)
    assert result.verdict == "disagree", result.line()


@pytest.mark.parametrize("scale, expected", [(1.0, "agree"), (0.98, "disagree")])
def test_external_renderer_example(scale, expected):
    """examples/mitsuba_renderer.py as an external renderer: honest, and 2% too dark."""
    import sys

    command = (f"{sys.executable} {ROOT / 'examples' / 'mitsuba_renderer.py'} {{scene}} -o {{output}} "
               f"--spp {{spp}} --seed {{seed}} {{defines}} --scale {scale}")
    one_stage = Settings(passes=8, spp=64, max_spp=64)    # at the full alpha (stages would split it)
    result = verdict(SCENES / "hexagon_room.xml", ExternalRenderer(command), 4, one_stage)
    assert result.verdict == expected, result.line()
