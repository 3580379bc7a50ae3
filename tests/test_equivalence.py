"""What "agree" means: the bias a comparison could have missed (its detectable bias), equivalence within a
margin (TOST), the stages of a sequential check, and checks on Mitsuba's own render-test scenes (a `moment`
integrator, refusals before any pass)."""
import os
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from tracer.scene import SceneError
from validation import cli
from validation.verdict.check import next_spp, sequential, stages
from validation.verdict.scenefile import plan
from validation.verdict.stats import POWER, Margin, compare

from .conftest import ROOT, SCENES

MITSUBA_DATA = Path(os.environ["MITSUBA_DATA"]) if os.environ.get("MITSUBA_DATA") else None   # a copy of
# mitsuba-renderer/mitsuba-data
RENDER_TEST = "tests/scenes/bsdf_spheres/test_arealight_path.xml"


def normal_passes(seed: int, mean: float = 1.0, sd: float = 0.1, k: int = 16, shape=(8, 8, 3)) -> np.ndarray:
    return np.random.default_rng(seed).normal(mean, sd, (k, *shape))


def test_the_detectable_bias_is_detected_with_the_stated_power():
    """At a bias equal to the stated detectable bias of the image mean, the image-mean test rejects in about
    POWER of the comparisons (normal passes, alpha 0.05 for counts large enough to see it)."""
    alpha, sd = 0.05, 0.4
    detectable = np.median([compare(normal_passes(2 * i, sd=sd), normal_passes(2 * i + 1, sd=sd), alpha)
                            .detectable_image[0] for i in range(20)])
    hits = sum(compare(normal_passes(100 + 2 * i, 1 + detectable, sd), normal_passes(101 + 2 * i, sd=sd), alpha)
               .image_rejected[0] for i in range(300))
    assert stats.binomtest(hits, 300, POWER).pvalue > 1e-3, (hits, detectable)


def test_the_detectable_bias_falls_as_one_over_root_samples():
    z = normal_passes(1, 0.0, 1.0), normal_passes(2, 0.0, 1.0)     # the same noise, 4 times smaller
    wide, narrow = (compare(10 + sd * z[0], 10 + sd * z[1], 1e-3) for sd in (0.4, 0.1))
    assert narrow.detectable_block == pytest.approx(wide.detectable_block / 4, rel=0.01)
    assert narrow.detectable_image == pytest.approx(wide.detectable_image / 4, rel=0.01)
    assert "detectable bias (80% power): image mean" in narrow.summary()


def test_equivalent_within_the_margin_and_disagree_beyond_it():
    margin = Margin(0.01, 0.05)
    assert compare(normal_passes(3, sd=0.01), normal_passes(4, sd=0.01), 1e-3, margin).verdict == "equivalent"
    assert compare(normal_passes(3, 1.03, 0.01), normal_passes(4, sd=0.01), 1e-3, margin).verdict == "disagree"
    noisy = compare(normal_passes(3, sd=0.1), normal_passes(4, sd=0.1), 1e-3, margin)
    assert noisy.verdict == "inconclusive" and noisy.needed > 1


def test_a_bias_at_the_margin_is_rarely_called_equivalent():
    """TOST's level: at a bias exactly at the margin, 'equivalent' in at most about alpha of comparisons
    (alpha 0.05; 400 comparisons: 40 or more has probability below 1e-4 at exactly 0.05)."""
    margin = Margin(0.01, 0.5)
    equivalent = sum(compare(normal_passes(2 * i, 1.01, 0.02, shape=(2, 2, 3)), normal_passes(2 * i + 1, sd=0.02,
                     shape=(2, 2, 3)), 0.05, margin).verdict == "equivalent" for i in range(400))
    assert equivalent < 40


def test_equivalence_does_not_depend_on_the_units():
    """A block of radiance 1e-20 (numerical dust at a grazing light) is tested as one of radiance 1: the
    Welch degrees of freedom are computed in shares of the variance, whose squares would underflow, in float32
    passes too."""
    margin = Margin(0.01, 0.2)
    a, b = normal_passes(3, sd=0.02), normal_passes(4, sd=0.02)
    for scale in (1.0, 1e-20):
        tiny = [x.astype(np.float32) for x in (a, b)]
        tiny[0][:, 0, 0], tiny[1][:, 0, 0] = a[:, 0, 0] * scale, b[:, 0, 0] * scale
        c = compare(tiny[0], tiny[1], 1e-3, margin)
        assert c.equivalent_map.all() and c.verdict == "equivalent", scale


def test_black_images_are_equivalent():
    black = np.zeros((16, 4, 4, 3))
    assert compare(black, black, 1e-3, Margin(0.01, 0.1)).verdict == "equivalent"


def test_a_test_of_difference_escalates_in_at_most_three_stages_up_to_the_maximum():
    assert stages(64, 1024) == [64, 256, 1024] and stages(64, 8192) == [64, 724, 8192]
    assert stages(64, 64) == [64] and stages(64, 100) == [64, 80, 100] and stages(512, 64) == [512]


def staged_normal(bias: float, sd64: float = 0.05, shape=(2, 2, 3)):
    """`decide` for check.sequential on normal passes: 16 a side, standard deviation sd64 at 64 spp per pass
    falling as 1/sqrt(spp), the test side too dark by `bias`; records each stage's (spp, level)."""
    calls = []

    def decide(stage: int, spp: int, level: float):
        calls.append((spp, level))
        rng = np.random.default_rng([len(calls), spp, int(1e6 * bias)] + [id(calls) % 2**31])
        sd = sd64 * np.sqrt(64 / spp)
        return compare(rng.normal(1 - bias, sd, (16, *shape)), rng.normal(1, sd, (16, *shape)), level,
                       Margin(0.01, 0.2))
    return decide, calls


def test_the_stages_spend_the_level_and_no_more():
    """Whichever path the sequence takes, its stages' levels sum to at most alpha (Bonferroni spending)."""
    for bias in (0.0, 0.005, 0.01, 0.03):
        decide, calls = staged_normal(bias)
        seq = sequential(decide, 64, 8192, 0.05, Margin(0.01, 0.2))
        assert seq.stages == 3 and len(calls) == seq.stage <= 3
        assert sum(level for _, level in calls) <= 0.05 + 1e-12 and all(lv == 0.05 / 3 for _, lv in calls)
        assert seq.spent == sum(spp for spp, _ in calls) and all(spp <= 8192 for spp, _ in calls)


def test_the_second_stage_is_sized_for_an_unbiased_renderer():
    """The pilot (64 spp, 5% noise per pass: equivalence within 1% far out of reach) is undecided; the second
    stage runs at the spp the pilot planned (its needed_unbiased), rounded up to two digits."""
    decide, calls = staged_normal(0.0)
    pilot = decide(1, 64, 0.05 / 3)
    calls.clear()
    seq = sequential(decide, 64, 8192, 0.05, Margin(0.01, 0.2))
    assert calls[0][0] == 64 and seq.stage >= 2
    assert calls[1][0] == pytest.approx(64 * pilot.needed_unbiased, rel=0.25) and calls[1][0] > 64


def test_a_stage_is_planned_within_the_budget_and_only_where_it_can_decide():
    """next_spp: the second stage for an unbiased renderer, a later one for the measured difference, never
    fewer spp than the stage before, at most --max-spp, and none where the measured difference lies at or
    beyond the margin or a stage at --max-spp already fell short."""
    from types import SimpleNamespace

    c = SimpleNamespace(needed_unbiased=50.0, needed=float("inf"))
    assert next_spp(c, 64, 1, 8192) == 3200 and next_spp(c, 3200, 2, 8192) is None
    c = SimpleNamespace(needed_unbiased=1000.0, needed=3.0)
    assert next_spp(c, 64, 1, 8192) == 8192 and next_spp(c, 8192, 2, 8192) is None
    assert next_spp(c, 1000, 2, 8192) == 3000 and next_spp(SimpleNamespace(needed=0.5), 1000, 2, 8192) == 1000


def test_a_planned_stage_has_the_power_it_was_planned_for():
    """An unbiased renderer at the samples per pass a pilot planned is shown equivalent in about POWER of the
    comparisons: 10 pilots (16 normal passes a side, 5% noise at 64 spp, the check's stage level 1e-3 / 3), 40
    comparisons at each one's plan. Measured 0.79; a planner on the normal quantile instead of Student's t
    picks too few spp (0.58), one that plans no power (the TOST passing only where the measured difference
    stays 0) far fewer; a planner far above POWER overspends."""
    margin, level, sd64, shape = Margin(0.01, 0.2), 1e-3 / 3, 0.05, (2, 2, 3)
    rng = np.random.default_rng(11)
    shown = 0
    for _ in range(10):
        pilot = compare(rng.normal(1, sd64, (16, *shape)), rng.normal(1, sd64, (16, *shape)), level, margin)
        sd = sd64 / np.sqrt(pilot.needed_unbiased)
        shown += sum(compare(rng.normal(1, sd, (16, *shape)), rng.normal(1, sd, (16, *shape)), level, margin)
                     .verdict == "equivalent" for _ in range(40))
    assert 0.7 <= shown / 400 <= 0.95, shown


def test_the_planner_inverts_the_tost_for_its_power():
    """stats.spp_factor against simulation: one TOST of standard error 1, margin 5, level 1e-3: at the factor
    it returns, the TOST passes with probability POWER, for a true difference of 0 and of 2; a difference at
    the margin can never be shown within it."""
    from validation.verdict.stats import spp_factor

    rng = np.random.default_rng(5)
    q = stats.norm.isf(1e-3)
    for true in (0.0, 2.0):
        factor = spp_factor(np.array([true]), np.ones(1), np.array([np.inf]), np.array([5.0]), 1e-3)
        se = 1 / np.sqrt(factor)
        passed = np.mean(np.abs(rng.normal(true, se, 100_000)) + q * se < 5)
        assert passed == pytest.approx(POWER, abs=0.01), (true, factor)
    assert spp_factor(np.array([5.0]), np.ones(1), np.array([np.inf]), np.array([5.0]), 1e-3) == np.inf


def test_a_staged_check_calls_a_bias_at_the_margin_equivalent_at_most_at_alpha():
    """False "equivalent" of the whole sequence, planner included, at a bias equal to the margin: at most alpha
    (0.1, 300 sequences: 45 or more has probability below 1e-3 at a rate of exactly 0.1)."""
    false = 0
    for _ in range(300):
        decide, _ = staged_normal(0.01)
        false += sequential(decide, 64, 8192, 0.1, Margin(0.01, 0.2)).comparison.verdict == "equivalent"
    assert false < 45, false


def moment_scene(tmp_path: Path, integrator: str = "path") -> Path:
    """The stress suite's glass sphere with its integrator wrapped in `moment`, as Mitsuba's render tests."""
    text = (SCENES / "stress" / "glass_sphere.xml").read_text()
    start, end = text.index("<integrator"), text.index("</integrator>") + len("</integrator>")
    inner = text[start:end].replace('type="path"', f'type="{integrator}"')
    scene = tmp_path / "moment.xml"
    scene.write_text(text[:start] + f'<integrator type="moment">{inner}</integrator>' + text[end:])
    return scene


def test_a_moment_integrator_is_compared_through_the_integrator_it_wraps(tmp_path):
    scene_plan = plan(moment_scene(tmp_path), size=16)
    xml = scene_plan.mitsuba_xml()
    assert 'type="moment"' not in xml and '<integrator type="path">' in xml


def test_every_refusal_comes_before_any_pass(tmp_path, capsys):
    """A scene whose (wrapped) integrator the comparison cannot use is refused in one line, within 2 s and
    before the renderer under test is run once."""
    marker = tmp_path / "rendered"
    command = f"{sys.executable} -c \"open('{marker}', 'w')\" {{output}}"
    start = time.perf_counter()
    assert cli.main(["check", str(moment_scene(tmp_path, "prbvolpath")), "--renderer", command]) == 2
    assert time.perf_counter() - start < 2
    err = capsys.readouterr().err.strip()
    assert "prbvolpath" in err and "\n" not in err and not marker.exists()


def test_margin_arguments_are_refused_in_one_line(capsys):
    scene = str(SCENES / "hexagon_room.xml")
    for bad in ("150%", "one"):
        with pytest.raises(SystemExit) as e:
            cli.main(["check", scene, "--margin", bad])
        assert e.value.code == 2 and "margin" in capsys.readouterr().err
    assert cli.main(["check", scene, "--margin", "1%", "5%", "7%"]) == 2
    assert "one or two percentages" in capsys.readouterr().err


def test_a_parameter_inside_a_refused_element_is_not_called_unused(tmp_path):
    """-D depth=... names a parameter that a refused integrator uses: the refusal, not a follow-on error."""
    import tracer

    text = (SCENES / "stress" / "glass_sphere.xml").read_text()
    start, end = text.index("<integrator"), text.index("</integrator>") + len("</integrator>")
    scene = tmp_path / "refused.xml"
    scene.write_text(text[:start] + '<default name="depth" value="3"/><integrator type="prbvolpath">'
                     '<integer name="max_depth" value="$depth"/></integrator>' + text[end:])
    with pytest.raises(SceneError) as e:
        tracer.load_scene(scene, depth="4")
    assert "prbvolpath" in str(e.value) and "uses no parameter" not in str(e.value)


@pytest.mark.slow
def test_the_example_renderer_honours_the_film_size_on_any_scene(tmp_path):
    """examples/mitsuba_renderer.py on a scene that declares no <default> for the size, depth or spp."""
    import subprocess

    from tracer.imageio import read_exr

    scene = moment_scene(tmp_path)
    text = scene.read_text()
    for name, value in (("spp", "16"), ("width", "32"), ("height", "32"), ("max_depth", "-1")):
        text = text.replace(f'<default name="{name}" value="{value}"/>', "").replace(f"${name}", value)
    scene.write_text(text)
    out = tmp_path / "out.exr"
    subprocess.run([sys.executable, str(ROOT / "examples" / "mitsuba_renderer.py"), str(scene), "-o", str(out),
                    "--spp", "4", "-D", "width=12", "-D", "height=7", "-D", "max_depth=2", "-D", "spp=4"], check=True)
    assert read_exr(out).shape[:2] == (7, 12)


@pytest.mark.slow
@pytest.mark.skipif(MITSUBA_DATA is None, reason="needs a copy of mitsuba-renderer/mitsuba-data")
def test_a_render_test_scene_is_planned_and_loaded_by_mitsuba():
    scene_plan = plan(MITSUBA_DATA / RENDER_TEST, size=None)
    assert (scene_plan.width, scene_plan.height, scene_plan.max_depth) == (48, 48, 2)
    assert "PathIntegrator" in str(scene_plan.mitsuba_scene(4).integrator())


def test_ci_sets_the_margin_and_none_removes_it(monkeypatch, capsys):
    from validation.verdict import protocol
    from validation.cli import _check_margin

    monkeypatch.delenv("CI", raising=False)
    assert _check_margin(None) is None
    monkeypatch.setenv("CI", "true")
    assert _check_margin(None) == Margin(protocol.CI_MARGIN, protocol.BLOCK_MARGIN)
    assert "CI is set" in capsys.readouterr().out
    assert _check_margin([None]) is None and _check_margin([0.02, 0.3]) == Margin(0.02, 0.3)
