"""The calibration's parts: counting verdicts, the scene reports' null cells, the report's summary of
disagreeing runs."""
import numpy as np
import pytest

from validation.suites import calibration
from validation.suites.calibration import ALPHAS, SWEEP, Cell, run_cell, verdicts
from validation.reports.scene_report import Config, _disagreeing


def passes(rng, shift: float = 0.0, repetitions: int = 3) -> np.ndarray:
    """Block means (repetitions, passes, 4, 4, 3) of a unit-mean renderer, shifted by `shift`."""
    return (1.0 + shift + rng.normal(0, 0.05, (repetitions, 8, 4, 4, 3))).astype(np.float32)


def test_verdicts_count_disagreements_at_every_level():
    rng = np.random.default_rng(3)
    same = verdicts(passes(rng), passes(rng))
    shifted = verdicts(passes(rng, 0.2), passes(rng))
    assert same["new_0.001"] == 0                     # (at 0.1, a null comparison in ten disagrees)
    for alpha in ALPHAS:
        assert shifted[f"new_{alpha:g}"] == 3          # a shift of 4 standard deviations per pass
        assert shifted[f"inconclusive_{alpha:g}"] == 0


def test_the_sweep_setting_is_the_reports():
    c = Config()
    assert (SWEEP.passes, SWEEP.size, SWEEP.old) == (c.passes, c.sweep_size, False)


@pytest.mark.slow
def test_a_sweep_cell_renders_in_the_reports_configuration_and_is_cached(tmp_path, monkeypatch):
    cell = Cell("cornell_box", "path", 1, 2, 1)
    data = run_cell(cell, tmp_path, SWEEP)
    assert data["test"].shape == data["ref"].shape == (1, SWEEP.passes, SWEEP.size // 4, SWEEP.size // 4, 3)
    assert "old" not in data                       # no many-sample reference: the reports use none
    assert not np.array_equal(data["test"], data["ref"])     # independent seeds
    monkeypatch.setattr(calibration, "_blocks", None)         # a second call renders nothing
    again = run_cell(cell, tmp_path, SWEEP)
    assert np.array_equal(again["test"], data["test"])


def test_a_reports_summary_names_each_disagreeing_run():
    rows = [{"test": "agree", "key": "a", "min_p": 0.01}, {"test": "disagree", "key": "b", "min_p": 1.6e-7}]
    assert _disagreeing(rows) == "1 of 2 (b: smallest p 1.6e-07)"
    assert _disagreeing(rows[:1]) == "0 of 1"


def test_cross_compares_repetitions_and_every_run_with_every_run():
    rng = np.random.default_rng(4)
    tracer, mitsuba = ({"test": passes(rng, shift), "ref": passes(rng, shift)} for shift in (0.2, 0.0))
    c = calibration._cross(tracer, mitsuba)
    assert c["n"] == 3 and c["new_0.001"] == 3
    assert c["all_pairs"]["n"] == 36 and c["all_pairs"]["new_0.001"] == 36
    assert [d["repetition"] for d in c["disagreements"]] == [0, 1, 2]
    assert c["disagreements"][0]["all_runs"][0] == pytest.approx(1.2, abs=0.01)
    table = calibration._cross_table([{"scene": "s"} | c] * 2, ("scene",))
    assert table[-1].startswith("| all | 6 | 6/6 |") and "72/72" in table[-1]


def normal_repetition(tmp_path, sd1: float = 0.4):
    """A calibration_equivalence.Repetition whose atoms are normal passes (standard deviation sd1 at 1 spp,
    falling as 1/sqrt(spp)); records the atoms rendered."""
    from validation.suites.calibration_equivalence import Repetition

    rendered = []

    def render(side, stage, j, seed):
        rendered.append((side, stage, j))
        return np.random.default_rng([seed, j]).normal(1, sd1 / np.sqrt(2 ** j), (16, 4, 4, 3))
    return Repetition(tmp_path / "r0.npz", render), rendered


def test_a_pass_of_m_spp_is_composed_of_the_atoms_of_its_binary_digits(tmp_path):
    rep, rendered = normal_repetition(tmp_path)
    passes = rep.passes("test", 2, 5)        # 5 = 1 + 4: atoms 0 and 2, weighted 1 and 4
    assert rendered == [("test", 2, 0), ("test", 2, 2)]
    assert np.allclose(passes, (rep.data["test-2-0"] + 4 * rep.data["test-2-2"]) / 5)
    again, rendered_again = normal_repetition(tmp_path)     # read back from the cache, nothing rendered
    assert np.allclose(again.passes("test", 2, 5), passes) and rendered_again == []


def test_the_equivalence_sequence_is_the_checks(tmp_path):
    """The replay plans its stages as the check does (check.sequential): a noisy pilot goes on to a planned
    stage that decides; a test side 20% too dark disagrees."""
    from validation.suites.calibration_equivalence import PILOT, sequence
    from validation.verdict.stats import Margin

    rep, rendered = normal_repetition(tmp_path)
    honest = sequence(rep, 0.05, Margin(0.04, 0.4))
    assert honest.verdict == "equivalent" and honest.stage >= 2 and honest.spent > PILOT
    assert {stage for _, stage, _ in rendered} == set(range(1, honest.stage + 1))
    assert sequence(rep, 0.05, Margin(0.04, 0.4), scale=0.8).verdict == "disagree"


def test_the_equivalence_section_replaces_its_predecessor_and_keeps_the_rest(tmp_path, monkeypatch):
    from validation.suites import calibration_equivalence as ce

    rows = [{"renderer": r, "scene": s, "alpha": ce.ALPHA, "bias": k, "n": 2, "equivalent": 1, "disagree": 1,
             "inconclusive": 0, "spent_equivalent": [4], "spent_disagree": [20], "spent_inconclusive": [],
             "stages": [1, 2]} for r in ce.RENDERERS for s in ce.SCENES for k in ce.BIASES]
    monkeypatch.setattr(ce, "measure", lambda repetitions, **_: rows)
    monkeypatch.setattr(ce, "faults", lambda: [{"fault": "f", "spp": 256, "faulty": "disagree", "correct": "equivalent",
                                                "faulty_mean": -0.05, "correct_detectable": [0.01] * 3}])
    out = tmp_path / "calibration.md"
    out.write_text("# Calibration\n\n## Null\n\nkept\n\n## Time per check\n\nkept too\n")
    ce.update(out, 2)
    ce.update(out, 2)
    text = out.read_text()
    assert text.count(ce.SECTION) == 1 and text.index("## Null") < text.index(ce.SECTION) < text.index("## Time")
    assert "kept too" in text and "| mitsuba | project's 3 | 1 | 3/6 [" in text and "| 1024 (1024) | 5120 (5120) | - |" in text
    assert "| f | disagree / equivalent | -5.00% |" in text and "| path | caustic | 2 | 1 / 1 / 0 |" in text


def test_mitsubas_criterion_passes_its_reference_and_fails_a_dim_image():
    """Mitsuba's render-test criterion (validation.suites.mitsuba_criterion): the reference itself passes, 10% too dark
    fails where the variance is small, and the variance floor keeps a black reference from failing on noise."""
    from validation.suites.mitsuba_criterion import mitsuba_passes

    rng = np.random.default_rng(5)
    ref = rng.uniform(0.5, 1.0, (16, 16, 3))
    var = np.full_like(ref, 0.01)
    noisy = ref + rng.normal(0, np.sqrt(0.01 / 1000), ref.shape)     # an honest 1000-spp render
    assert mitsuba_passes(noisy, ref, var, 1000)
    assert not mitsuba_passes(noisy * 0.9, ref, var, 1000)
    assert mitsuba_passes(np.full_like(ref, 1e-4), np.zeros_like(ref), np.zeros_like(ref), 1000)


def test_cached_repetitions_resume_and_extend(tmp_path):
    from validation.suites.calibration import cached_repetitions

    calls = []

    def one(r):
        calls.append(r)
        if r == 3:
            raise KeyboardInterrupt       # interrupted during the fourth repetition
        return {"test": np.full(2, r, np.float32)}

    path = tmp_path / "study.npz"
    with pytest.raises(KeyboardInterrupt):
        cached_repetitions(path, 5, "study", one)
    assert calls == [0, 1, 2, 3] and len(np.load(path)["seconds"]) == 3       # the three done are kept
    calls.clear()
    first = cached_repetitions(path, 2, "study", one)                           # fewer: nothing rendered
    assert calls == [] and first["test"].tolist() == [[0, 0], [1, 1]]
    done = cached_repetitions(path, 3, "study", lambda r: {"test": np.full(2, 9, np.float32)})
    assert done["test"][:, 0].tolist() == [0, 1, 2] and done["seconds"].shape == (3,)
    more = cached_repetitions(path, 4, "study", lambda r: {"test": np.full(2, 10 * r, np.float32)})
    assert more["test"][:, 0].tolist() == [0, 1, 2, 30]
