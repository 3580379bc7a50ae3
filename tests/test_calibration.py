"""The calibration's parts: counting verdicts, the scene reports' null cells, the report's summary of
disagreeing runs."""
import numpy as np
import pytest

from validation import calibration
from validation.calibration import ALPHAS, SWEEP, Cell, run_cell, verdicts
from validation.report import Config, _disagreeing


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
