"""Mitsuba's `thinlens` sensor (tracer.camera): mitsuba_scenes/thinlens.xml, spheres in and out of focus,
against Mitsuba: Welch's t-test per 4x4 block and channel, Bonferroni-corrected, family-wise false-positive
rate ALPHA; the same test failing with the rays leaving from the lens's centre (a pinhole aimed through
the focal plane)."""
import dataclasses

import pytest

from validation.verdict.protocol import ALPHA
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import HEADER, write_scene

SCENE = "thinlens.xml"


def compared(seed: int, edit=None):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=3)
    return compare_passes(plugin_passes(SCENE, "path", 3, seed, edit), ref, ALPHA)


def test_thinlens_agrees_with_mitsuba():
    result = compared(10100)
    assert result.verdict == "agree", result.summary()


def test_fails_as_a_pinhole():
    def pinhole(scene):
        scene.camera = dataclasses.replace(scene.camera, aperture_radius=0.0)

    result = compared(10200, pinhole)
    assert result.verdict == "disagree", result.summary()


@pytest.mark.parametrize("extra, words", [
    ('<float name="focus_distance" value="3"/>', "needs aperture_radius"),
    ('<float name="aperture_radius" value="-1"/>', "must be positive"),
    ('<float name="aperture_radius" value="0.1"/><transform name="to_world"><scale value="2"/></transform>',
     "may not scale"),
])
def test_bad_thinlens_is_refused(tmp_path, extra, words):
    header = HEADER.replace('<sensor type="perspective">', f'<sensor type="thinlens">{extra}')
    (error,) = scene_errors(write_scene(tmp_path, "", header=header))
    assert words in error
