"""`validate mitsuba-tests`: Mitsuba's render-test protocol (src/render/tests/test_renders.py) on synthetic
images (a correct image passes, a biased one fails, the Sidak level and the 99.75% rule as Mitsuba computes
them), and the command end to end on a miniature mitsuba-data of our own: a scene with a Mitsuba reference made
as Mitsuba makes its references (the `moment` integrator's mean and second moment)."""
import os
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from scipy.stats import norm

from validation.suites import mitsuba_tests as mt

from .test_xml_features import mi  # noqa: F401  (the fixture)

P = 48 * 48                         # the pixels of most of Mitsuba's tests


def _synthetic(seed: int = 0, shape=(48, 48)) -> tuple[np.ndarray, np.ndarray]:
    """A reference and its per-sample variance (XYZ) whose uniform detectable bias is about 1.5%."""
    rng = np.random.default_rng(seed)
    ref = rng.uniform(0.2, 1.0, shape + (3,)).astype(np.float32)
    var = (ref * rng.uniform(0.05, 0.3, shape + (1,))).astype(np.float32) ** 2
    return ref, var


def _noisy(ref, var, spp, rng, scale=1.0):
    """An image of a renderer whose mean is scale x ref: the reference plus the noise of spp samples."""
    return (scale * ref + rng.normal(size=ref.shape) * np.sqrt(var / spp)).astype(np.float32)


def test_sample_budget_and_sidak_level_as_mitsuba():
    assert [mt.sample_count(n) for n in (48 * 48, 32 * 32, 480 * 480, 64 * 512)] == [868, 1953, 8, 61]
    assert mt.sidak_level(P) == 1.0 - (1.0 - 0.01) ** (1.0 / P)
    assert mt.sidak_level(P) == pytest.approx(0.01 / P, rel=0.01)        # ~ Bonferroni for small levels


def test_p_values_are_mitsubas_float32_formula():
    """p = 2 (1 - Phi(z)) agrees with the exact tail where float32 resolves it, and is exactly 0 where
    float32's 1 - Phi rounds to 0 (beyond z ~ 5.4): Mitsuba's rule then rejects at any level."""
    z = np.linspace(0, 5, 501, dtype=np.float32)
    p = mt.p_values(z, 1, np.zeros_like(z), np.ones_like(z))
    assert p.dtype == np.float32
    assert np.allclose(p, 2 * norm.sf(z.astype(np.float64)), rtol=0, atol=2.5e-7)
    far = mt.p_values(np.float32([6.0, 8.0, 40.0]), 1, np.zeros(3), np.ones(3))
    assert np.all(far == 0)
    floored = mt.p_values(np.float32([0.01]), 1, np.zeros(1), np.zeros(1))    # var 0 floored at 1e-4: z = 1
    assert floored[0] == pytest.approx(2 * norm.sf(1.0), abs=1e-6)


def test_the_rule_counts_accepted_channels_over_three():
    """With 400 pixels, 99.75% leaves 0.0075 x 400 = 3 rejected (pixel, channel) tests: 3 pass, 4 fail."""
    ref = np.full((20, 20, 3), 0.5, np.float32)
    var = np.full_like(ref, 0.01)
    for rejected, passes in ((0, True), (3, True), (4, False)):
        image = ref.copy()
        image.reshape(-1)[:rejected * 7:7] = 5.0                          # spread over pixels and channels
        v = mt.verdict(image, 1000, ref, var)
        assert v.passed is passes and v.rejected == pytest.approx(rejected / 3 / 400)
    assert mt.verdict(ref, 1000, ref, var).alpha == mt.sidak_level(400)


def test_a_correct_image_passes_and_a_biased_one_fails():
    """The false-positive rate on correct images (Gaussian noise of the reference's variance, 200 images) is
    measured 0/200; images 3% too bright or too dark (twice the detectable bias) fail every time."""
    ref, var = _synthetic()
    spp = mt.sample_count(P)
    bias = mt.detectable_bias(spp, ref, var)
    assert 0.005 < bias < 0.015, bias
    rng = np.random.default_rng(1)
    correct = [mt.verdict(_noisy(ref, var, spp, rng), spp, ref, var) for _ in range(200)]
    assert sum(not v.passed for v in correct) == 0
    assert max(v.rejected for v in correct) < 1 - mt.ACCEPT
    for scale in (1.03, 0.97):
        wrong = [mt.verdict(_noisy(ref, var, spp, rng, scale), spp, ref, var) for _ in range(20)]
        assert not any(v.passed for v in wrong), scale
        assert min(v.rejected for v in wrong) > 1 - mt.ACCEPT


def test_detectable_bias_is_where_the_rule_turns():
    """A noise-free image wrong by the detectable bias, or a little more, fails; a little less passes."""
    ref, var = _synthetic(seed=2)
    spp = mt.sample_count(P)
    bias = mt.detectable_bias(spp, ref, var)
    assert mt.verdict(ref * np.float32(1 + 0.98 * bias), spp, ref, var).passed
    assert not mt.verdict(ref * np.float32(1 + 1.02 * bias), spp, ref, var).passed
    black = np.zeros_like(ref)
    assert mt.detectable_bias(spp, black, var) == np.inf              # no bias of black is detectable


def test_xyz_is_mitsubas_conversion(mi):
    image = np.random.default_rng(3).uniform(0, 2, (5, 7, 3)).astype(np.float32)
    theirs = mi.Bitmap(image, mi.Bitmap.PixelFormat.RGB).convert(mi.Bitmap.PixelFormat.XYZ, mi.Struct.Type.Float32,
                                                                  False)
    assert np.allclose(mt.to_xyz(image), np.array(theirs), rtol=1e-6, atol=1e-7)


# ---- the command on a miniature mitsuba-data ------------------------------------------------------------------
SCENE = """<scene version="3.0.0">
    <default name="spp" value="16"/>
    <default name="integrator" value="path"/>
    <integrator type="moment"><integrator type="$integrator"><integer name="max_depth" value="3"/></integrator>
    </integrator>
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 0, -4" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
            <rfilter type="box"/></film>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
    </sensor>
    <shape type="sphere"><float name="radius" value="1"/>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.7, 0.5, 0.3"/></bsdf></shape>
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="90"/><translate y="3"/></transform>
        <emitter type="area"><rgb name="radiance" value="4, 4, 4"/></emitter></shape>
    <emitter type="constant"><rgb name="radiance" value="0.2"/></emitter>
</scene>
"""


def _write_rgb(path: Path, xyz: np.ndarray) -> None:
    rgb = (xyz.reshape(-1, 3) @ np.linalg.inv(mt.SRGB_TO_XYZ.astype(np.float64)).T).reshape(xyz.shape)
    OpenEXR.File({"type": OpenEXR.scanlineimage}, {"RGB": rgb.astype(np.float32)}).write(str(path))


def _miniature_data(root: Path, mi) -> Path:
    """tests/scenes/tiny/{test_sphere_path.xml, test_sphere_ptracer.xml} and refs/test_sphere_ref_rgb{,_var}.exr:
    Mitsuba's mean and per-sample variance at 32,000 spp, from the moment integrator, as Mitsuba's references
    (a moment cannot wrap Mitsuba's ptracer: that scene has the ptracer alone)."""
    folder = root / "tests" / "scenes" / "tiny"
    (folder / "refs").mkdir(parents=True)
    (folder / "test_sphere_path.xml").write_text(SCENE)
    (folder / "test_sphere_ptracer.xml").write_text(SCENE.replace('<integrator type="moment">', "").replace(
        "</integrator>\n    </integrator>", "</integrator>"))
    scene = mi.load_file(str(folder / "test_sphere_path.xml"), spp=32000)
    scene.integrator().render(scene, seed=12345, spp=32000)
    parts = scene.sensors()[0].film().bitmap(raw=False).split()
    mean, m2 = (np.array(parts[k][1], np.float32) for k in (1, 2))
    _write_rgb(folder / "refs" / "test_sphere_ref_rgb.exr", mean)
    _write_rgb(folder / "refs" / "test_sphere_ref_rgb_var.exr", m2 - mean * mean)
    return root


@pytest.mark.slow
def test_the_command_on_a_miniature_mitsuba_data(tmp_path, mi, monkeypatch, capsys):
    """The tracer and Mitsuba pass the test of a scene the tracer renders; the scene's ptracer test is refused
    by the tracer (its constant environment) with Mitsuba's own verdict beside it (Mitsuba renders it: a pass or a
    fail, never an error; its ptracer draws other random numbers than its path, so its pixel test is its own); a tracer 5% too bright
    fails; a second run renders nothing again."""
    root = _miniature_data(tmp_path / "data", mi)
    monkeypatch.chdir(tmp_path)
    report = tmp_path / "reports" / "mitsuba_tests.md"
    assert mt.report(root, report, "validate mitsuba-tests MITSUBA_DATA_DIR", cache=tmp_path / "cache") == 0
    out = capsys.readouterr().out
    assert "pass     tiny/test_sphere_path.xml: " in out and "Mitsuba: pass" in out
    assert ("refused  tiny/test_sphere_ptracer.xml: tests/scenes/tiny/test_sphere_ptracer.xml:4: "
            "<integrator type=\"$integrator\">: ptracer's image differs from path's here: emitter 'constant'") in out
    text = report.read_text()
    assert "| tiny/test_sphere_path.xml | path | 256 | 7812 |" in text
    assert "| the tracer passes | 1 |" in text and "| Mitsuba's render failed |" not in text
    assert str(tmp_path) not in text and "mitsuba-renderer/mitsuba-data" in text
    assert report.with_suffix(".json").is_file()

    def must_not_render(*args):
        raise AssertionError("rendered again")

    correct = mt.tracer_render
    monkeypatch.setattr(mt, "tracer_render", must_not_render)
    monkeypatch.setattr(mt, "mitsuba_render", must_not_render)
    outcomes, _ = mt.run(root, cache=tmp_path / "cache")
    assert [o.tracer for o in outcomes] == ["pass", "refused"] and outcomes[0].mitsuba == "pass"
    assert outcomes[1].mitsuba in ("pass", "fail")

    monkeypatch.setattr(mt, "tracer_render", lambda test, spp: mt.Render(correct(test, spp).xyz * np.float32(1.05), 1))
    assert mt.report(root, None, "", run_mitsuba=False, cache=tmp_path / "wrong") == 1
    outcomes, _ = mt.run(root, run_mitsuba=False, cache=tmp_path / "wrong")
    assert outcomes[0].tracer == "fail" and outcomes[0].tracer_rejected > 0.5
    assert outcomes[0].detectable_bias < 0.05 / 2


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("MITSUBA_DATA"), reason="set MITSUBA_DATA to a copy of mitsuba-data")
def test_the_rgb_render_tests_of_mitsuba_data():
    tests, missing = mt.render_tests(Path(os.environ["MITSUBA_DATA"]))
    assert len(tests) == 41 and not missing
