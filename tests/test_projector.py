"""Lights whose intensity varies with direction: Mitsuba's `projector` (an image, or a colour, projected
through a perspective frustum of the image's aspect: intensity E pi / cos^3) and a `spot` with a `texture`.
mitsuba_scenes/projector.xml against Mitsuba: Welch's t-test per 4x4 block and channel, Bonferroni-corrected,
family-wise false-positive rate ALPHA per comparison; the same test failing with the image mirrored (a sign
of the projection) and with the projector's intensity missing its 1 / cos^3."""
import drjit as dr
import numpy as np
import pytest

from tracer.jit import vec3
from tracer.lights import PointLight
from validation.verdict.protocol import ALPHA  # per comparison; one agreement test: ALPHA
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import scene_errors
from .test_xml_loader import write_scene

SCENE = "projector.xml"


def compared(seed: int, edit=None):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=3)
    return compare_passes(plugin_passes(SCENE, "path", 3, seed, edit), ref, ALPHA)


def test_projectors_and_a_textured_spot_agree_with_mitsuba():
    result = compared(8100)
    assert result.verdict == "agree", result.summary()


def _mirrored(scene):
    for light in scene.point_lights:
        if light.projection is not None:
            light.frame = light.frame * np.array([-1.0, 1.0, 1.0])   # the image's u runs the other way


@pytest.mark.parametrize("fault", ["mirrored", "no cos^3"])
def test_fails_with_a_wrong_projection(monkeypatch, fault):
    if fault == "mirrored":
        result = compared(8200, _mirrored)
    else:
        profile = PointLight.profile

        def flat(self, ref):
            value = profile(self, ref)
            if self.projection is None:
                return value
            d = ref - vec3(self.position)
            cos = dr.dot(vec3(self.frame[:, 2]), d) * dr.rsqrt(dr.squared_norm(d))
            return value * cos * cos * cos

        monkeypatch.setattr(PointLight, "profile", flat)
        result = compared(8300)
    assert result.verdict == "disagree", result.summary()


@pytest.mark.parametrize("body, words", [
    ('<emitter type="projector"><float name="fov" value="30"/><string name="focal_length" value="20mm"/></emitter>',
     "either fov or focal_length"),
    ('<emitter type="projector"><transform name="to_world"><scale value="2"/></transform></emitter>', "rotation"),
    ('<emitter type="projector"><texture type="checkerboard" name="irradiance"/></emitter>', "bitmap"),
    ('<emitter type="spot"><texture type="checkerboard" name="texture"/></emitter>', "bitmap"),
])
def test_bad_projection_is_refused(tmp_path, body, words):
    (error,) = scene_errors(write_scene(tmp_path, body))
    assert words in error
