"""Area lights on spheres (Mitsuba's `area` emitter on a `sphere`): emission outward, shadow rays to points
uniform on the sphere (pdf 1 / (4 pi r^2), back-facing ones unlit), MIS with BSDF sampling.
mitsuba_scenes/sphere_lights.xml rendered by both estimators against Mitsuba: Welch's t-test per 4x4 block
and channel, Bonferroni-corrected, family-wise false-positive rate ALPHA per comparison; the same test
failing when the light's area is taken as pi r^2."""
import numpy as np
import pytest

import tracer
from tracer.shapes import Sphere
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP, mitsuba_passes, plugin_passes

from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 3 comparisons: < 0.3% in all
SCENE = "sphere_lights.xml"


def tracer_passes(estimator: str, max_depth: int) -> np.ndarray:
    return plugin_passes(SCENE, estimator, max_depth, 9900)


@pytest.mark.slow
@pytest.mark.parametrize("estimator, max_depth", [("path", 6), ("report", 4)])
def test_sphere_lights_agree_with_mitsuba(estimator, max_depth):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(tracer_passes(estimator, max_depth), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_with_the_wrong_area(monkeypatch):
    monkeypatch.setattr(Sphere, "area", property(lambda self: np.pi * self.radius ** 2))
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=6)
    result = compare_passes(tracer_passes("path", 6), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()


def test_sphere_lights_are_black_spheres():
    s = tracer.load_scene(SCENES / SCENE)
    lights = [x for x in s.spheres if x.radiance is not None]
    assert [x.name for x in s.emitters] == ["warm_light", "cool_light"] == [x.name for x in lights]
    assert all(x.bsdf.reflectance == (0.0, 0.0, 0.0) for x in lights)
    assert lights[1].radius == pytest.approx(0.08) and np.allclose(lights[1].center, [-0.5, 0.3, 0.5])
