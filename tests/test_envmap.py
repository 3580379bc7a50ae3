"""Mitsuba's `envmap` emitter: radiance by direction equal to Mitsuba's (bilinear, periodic in phi, turned and
scaled), a sampling density that integrates to 1 and matches the directions drawn, and
mitsuba_scenes/environment_map.xml rendered by the path estimator against Mitsuba: Welch's t-test per 4x4
block and channel, Bonferroni-corrected, family-wise false-positive rate ALPHA per comparison; the same
test failing when the density used for MIS and shadow rays is not the one sampled."""
import numpy as np
import pytest

import tracer
from tracer.geometry import SceneGeometry
from tracer.lights.envmap import EnvmapKernel
from tracer.jit import Array3f, Float
from validation.verdict.stats import compare_passes

from .conftest import PASSES, SCENES, SIZE, SPP, mitsuba_passes, plugin_passes
from .test_xml_features import mi, scene_errors  # noqa: F401  (mi: the fixture)
from .test_xml_loader import write_scene

from validation.verdict.protocol import ALPHA  # family-wise false-positive rate of one comparison; 3 comparisons: < 0.3% in all
SCENE = "environment_map.xml"


def directions(n: int, seed: int) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return np.concatenate([d / np.linalg.norm(d, axis=1, keepdims=True), np.eye(3), -np.eye(3)])


def array3(d: np.ndarray) -> Array3f:
    return Array3f(*(Float(d[:, k].astype(np.float32)) for k in range(3)))


@pytest.fixture(scope="module")
def geo():
    return SceneGeometry(tracer.load_scene(SCENES / SCENE, width=4, height=4))


def test_radiance_is_mitsubas(geo, mi):
    em = mi.load_dict({"type": "envmap", "filename": str(SCENES / "textures" / "sky.exr"), "scale": 1.5,
                       "to_world": mi.ScalarTransform4f().rotate([0, 1, 0], 70)})
    d = directions(500, 1)
    ours = np.asarray(geo.envmap.radiance(array3(d)).numpy()).T
    ref = []
    for v in d:
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*(-v.astype(np.float32)))
        ref.append(np.array(em.eval(si)))
    assert np.allclose(ours, np.array(ref), rtol=2e-5, atol=1e-6)


def test_density_integrates_to_one_and_is_the_sampled_one(geo):
    n = 200_000
    rng = np.random.default_rng(2)
    uniform = array3(directions(n, 3)[:n])
    assert 4 * np.pi * np.asarray(geo.envmap.pdf(uniform).numpy()).mean() == pytest.approx(1.0, abs=0.01)
    d = geo.envmap.sample(Float(rng.random(n, np.float32)), Float(rng.random(n, np.float32)))
    ratio = np.asarray(geo.envmap.radiance(d).numpy()).T / np.asarray(geo.envmap.pdf(d).numpy())[:, None]
    integral = 4 * np.pi * np.asarray(geo.envmap.radiance(uniform).numpy()).T.mean(0)
    assert np.allclose(ratio.mean(0), integral, rtol=0.01)   # E[L / p] over the samples = integral of L


def tracer_passes(max_depth: int) -> np.ndarray:
    return plugin_passes(SCENE, "path", max_depth, 6000)


@pytest.mark.slow
@pytest.mark.parametrize("max_depth", [2, 5])
def test_environment_map_agrees_with_mitsuba(max_depth):
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=max_depth)
    result = compare_passes(tracer_passes(max_depth), ref, ALPHA)
    assert result.verdict == "agree", result.summary()


@pytest.mark.slow
def test_fails_when_the_density_is_not_the_sampled_one(monkeypatch):
    monkeypatch.setattr(EnvmapKernel, "pdf", lambda self, d: Float(1.0 / (4.0 * np.pi)))
    ref = mitsuba_passes(SCENE, PASSES, SPP, width=SIZE, height=SIZE, max_depth=2)
    result = compare_passes(tracer_passes(2), ref, ALPHA)
    assert result.verdict == "disagree", result.summary()


@pytest.mark.parametrize("body, words", [
    ('<emitter type="envmap"><string name="filename" value="sky.hdr"/></emitter>', "only OpenEXR"),
    ('<emitter type="envmap"><string name="filename" value="gone.exr"/></emitter>', "not found"),
    ('<emitter type="envmap"><string name="filename" value="x.exr"/>'
     '<transform name="to_world"><scale value="2"/></transform></emitter>', "rotation"),
])
def test_bad_envmap_is_refused(tmp_path, body, words):
    (tmp_path / "x.exr").write_bytes(b"not an image")
    (error,) = scene_errors(write_scene(tmp_path, body))
    assert words in error


def test_report_estimator_refuses_it():
    scene = tracer.load_scene(SCENES / SCENE, width=4, height=4)
    (line,) = scene.estimator_refusals("report")
    assert "envmap" in line and "--estimator path" in line
