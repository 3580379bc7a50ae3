"""The false-alarm rate of the agreement test, measured: null comparisons on a grid of scenes, renderers,
samples per pass and depths, in the configuration `validate check` uses.

A null comparison pits an unbiased renderer against itself with independent seeds (Mitsuba against
Mitsuba, the tracer's path estimator against itself, its branching estimator against itself), so every
rejection is a false alarm. Each repetition renders PASSES test passes and an equal-budget reference
(the check's design) with fresh seeds; the earlier test (`stats.welch_test`, against a many-sample
reference of OLD_REF_SPP per pass, as the reports used it) runs on the same test passes.

The scene reports' sweeps (validation.reports.scene_report) run the same test in another configuration: fewer passes
(8) on larger images (128 x 128: 16 times the blocks), the branching estimator at N = 16, M = 8. Their null
cells (SWEEP) measure the test there too, and pair the branching estimator's passes with Mitsuba's, as a
report does.

Rendered block means are cached per cell in .cache/calibration (keyed by the scene's content and the cell),
so the tables can be recomputed without rendering and an interrupted run resumes.
"""
from __future__ import annotations

import itertools
import time
from contextlib import nullcontext
from dataclasses import asdict, dataclass
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy import stats as sps
from tqdm import tqdm

from ..verdict import protocol
from .runner import NONE, Runner, Unit, session
from ..verdict.check import REPORT_REFERENCE_SPP
from ..verdict.renderers import MitsubaRenderer, TracerRenderer
from ..reports.scene_report import SWEEP_DEPTH, Config
from ..verdict.scenefile import plan
from ..verdict.stats import MIN_DISTINCT, MIN_NONZERO, block_means, compare, welch_test

CACHE = Path(".cache/calibration")
SCENES = {"room": "mitsuba_scenes/hexagon_room.xml", "caustic": "mitsuba_scenes/caustic.xml",
          "dark": "mitsuba_scenes/dark.xml"}
REPORT = dict(direct=4, indirect=4)
OLD_REF_SPP = 256
ALPHAS = (1e-3, 1e-2, 1e-1)     # family-wise levels at which the rates are measured


@dataclass(frozen=True)
class Setting:
    """How a cell's comparisons render: passes per side, the image's longer side, the branching estimator's
    N and M, and whether the earlier test's many-sample reference is rendered too."""
    passes: int = protocol.PASSES
    size: int = protocol.SIZE
    report: tuple[int, int] = (REPORT["direct"], REPORT["indirect"])
    old: bool = True


CHECK = Setting()    # validate check's
SWEEP = Setting(Config.passes, Config.sweep_size, (16, 8), old=False)   # the scene reports' sweeps'
SWEEP_SCENES = {"cornell_box": "mitsuba_scenes/cornell_box.xml", "room": SCENES["room"]}   # the reports' scenes
SWEEP_REPORT_SPP = 4    # the branching estimator's camera rays per pixel and pass in the sweep cells


@dataclass(frozen=True)
class Cell:
    scene: str
    renderer: str        # mitsuba | path | report
    spp: int             # per pass
    max_depth: int
    repetitions: int

    @property
    def name(self) -> str:
        return f"{self.scene}-{self.renderer}-spp{self.spp}-d{self.max_depth}"

    def make_renderer(self, setting: Setting = CHECK):
        if self.renderer == "mitsuba":
            return MitsubaRenderer()
        return TracerRenderer("report", *setting.report) if self.renderer == "report" else TracerRenderer("path")


def grid(repetitions: int = 12) -> list[Cell]:
    """The null cells; those at 256 spp per pass, the costliest, get half the repetitions."""
    cells = []
    for scene in SCENES:
        for renderer in ("mitsuba", "path", "report"):
            if renderer == "report":   # its cost grows as M^(max_depth - 2): spp 4 up to max_depth 3 only
                cells += [Cell(scene, renderer, s, d, repetitions) for d, s in ((2, 1), (2, 4), (3, 1), (3, 4), (5, 1))]
            else:
                cells += [Cell(scene, renderer, s, d, repetitions if s < 256 else repetitions // 2)
                          for d in (2, 3, -1) for s in (1, 4, 16, 64, 256)]
    return cells


def sweep_grid(repetitions: int = 24) -> list[Cell]:
    """The scene reports' null cells (setting SWEEP), per report scene at the sweeps' max_depth: Mitsuba at
    the samples per pass it renders against the branching estimator's SWEEP_REPORT_SPP, that estimator, and
    the tracer's path at 16 spp."""
    pairs = (("mitsuba", SWEEP_REPORT_SPP * REPORT_REFERENCE_SPP), ("report", SWEEP_REPORT_SPP), ("path", 16))
    return [Cell(scene, renderer, spp, SWEEP_DEPTH, repetitions) for scene in SWEEP_SCENES for renderer, spp in pairs]


def _blocks(renderer, scene_plan, passes: int, spp: int, seed: int) -> np.ndarray:
    return block_means(renderer.passes(scene_plan, passes, spp, seed), protocol.BLOCK).astype(np.float32)


def _plan(cell: Cell, setting: Setting):
    return plan({**SCENES, **SWEEP_SCENES}[cell.scene], size=setting.size, max_depth=cell.max_depth)


def cell_path(cell: Cell, cache: Path = CACHE, setting: Setting = CHECK) -> Path:
    """The cell's cache file, named by a key of the scene's content and the cell."""
    key = _plan(cell, setting).content_key(**asdict(cell), passes=setting.passes, old_ref_spp=OLD_REF_SPP,
                                           report=dict(zip(REPORT, setting.report)))
    return cache / f"{cell.name}-{key}.npz"


def render_old(cell: Cell, setting: Setting) -> np.ndarray:
    """A unit of the cell (on a worker): the earlier test's many-sample reference."""
    old_spp = 64 if cell.renderer == "report" else OLD_REF_SPP
    return _blocks(cell.make_renderer(setting), _plan(cell, setting), setting.passes, old_spp, protocol.SEED_REFERENCE)


def render_repetition(cell: Cell, setting: Setting, r: int) -> dict[str, np.ndarray]:
    """A unit of the cell (on a worker): repetition r's test and equal-budget reference passes, and its seconds."""
    renderer, scene_plan = cell.make_renderer(setting), _plan(cell, setting)
    base = protocol.SEED_NULL + 1000 * r
    start = time.perf_counter()
    test = _blocks(renderer, scene_plan, setting.passes, cell.spp, base)
    ref = _blocks(renderer, scene_plan, setting.passes, cell.spp, base + 500)
    return {"test": test, "ref": ref, "seconds": np.float64(time.perf_counter() - start)}


def cell_units(cell: Cell, setting: Setting, path: Path) -> list[Unit]:
    """The cell as units: its repetitions and (where setting.old) its many-sample reference; keyed by `path`."""
    units = [Unit(f"{path.stem}-old", render_old, (cell, setting))] if setting.old else []
    return units + [Unit(f"{path.stem}-r{r}", render_repetition, (cell, setting, r)) for r in range(cell.repetitions)]


def assemble(units: list[Unit], results: dict) -> dict[str, np.ndarray]:
    """A cell's arrays from its units' results: old (K, ...), test and ref (R, K, ...), seconds (R,)."""
    reps = [results[u.key] for u in units if u.fn is render_repetition]
    out = {"old": results[units[0].key]} if units[0].fn is render_old else {}
    return out | {k: np.stack([r[k] for r in reps]) for k in ("test", "ref", "seconds")}


def write_cell(path: Path, data: dict[str, np.ndarray]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, **data)
    tmp.replace(path)


def run_cells(cells: list[tuple[Cell, Setting]], runner: Runner | None = None,
              cache: Path = CACHE) -> dict[tuple[Cell, Setting], dict[str, np.ndarray]]:
    """Every cell's rendered block means (see run_cell): read from the cache, the others rendered as one suite
    (a unit per repetition), each cell written to the cache by this process once all its units have arrived."""
    data, pending = {}, {}
    for cell, setting in dict.fromkeys(cells):
        path = cell_path(cell, cache, setting)
        if path.exists():
            with np.load(path) as z:
                data[cell, setting] = dict(z)
        else:
            pending[cell, setting] = (path, cell_units(cell, setting, path))
    waiting = {k: {u.key for u in units} for k, (_, units) in pending.items()}
    owner = {u.key: k for k, (_, units) in pending.items() for u in units}
    arrived = {}

    def on_result(unit: Unit, result) -> None:
        arrived[unit.key] = result
        k = owner[unit.key]
        waiting[k].discard(unit.key)
        if not waiting[k]:
            path, units = pending[k]
            data[k] = assemble(units, arrived)
            write_cell(path, data[k])

    units = [u for _, us in pending.values() for u in us]
    if units:
        with (nullcontext(runner) if runner is not None else session(NONE)) as r:
            r.run(units, "calibration cells", on_result)
    return {k: data[k] for k in dict.fromkeys(cells)}


def run_cell(cell: Cell, cache: Path = CACHE, setting: Setting = CHECK) -> dict[str, np.ndarray]:
    """The cell's rendered block means: test (R, K, ...), equal-budget reference (R, K, ...), many-sample
    reference (K, ...; where setting.old), and seconds per repetition; cached."""
    return run_cells([(cell, setting)], None, cache)[cell, setting]


def rates(data: dict[str, np.ndarray]) -> dict:
    """Per cell: false alarms of the new test (disagree) and the old one, at each level of ALPHAS, and
    how often the new test was inconclusive."""
    out = {"n": len(data["test"]), "seconds": float(np.median(data["seconds"]))} | verdicts(data["test"], data["ref"])
    if "old" in data:
        for alpha in ALPHAS:
            out[f"old_{alpha:g}"] = sum(not welch_test(t, data["old"], alpha=alpha, block=1).passed for t in data["test"])
    return out


def verdicts(tests: np.ndarray, refs: np.ndarray) -> dict:
    """How many of the comparisons of tests[i] with refs[i] disagree, and how many are inconclusive, at each
    level of ALPHAS."""
    out = {}
    for alpha in ALPHAS:
        new = [compare(t, r, alpha) for t, r in zip(tests, refs)]
        out[f"new_{alpha:g}"] = sum(c.verdict == "disagree" for c in new)
        out[f"inconclusive_{alpha:g}"] = sum(c.verdict == "inconclusive" for c in new)
    return out


def measure_sweep(repetitions: int = 24, cache: Path = CACHE, runner: Runner | None = None) -> tuple[list[dict], list[dict]]:
    """The scene reports' null cells (rows as measure's) and, per scene, the branching estimator's test passes
    against Mitsuba's (repetition by repetition: independent renders), as a report compares them."""
    cells = sweep_grid(repetitions)
    rendered = run_cells([(cell, SWEEP) for cell in cells], runner, cache)
    data = {cell: rendered[cell, SWEEP] for cell in cells}
    rows = [asdict(cell) | rates(d) for cell, d in data.items()]
    cross = []
    for scene in SWEEP_SCENES:
        side = {cell.renderer: d for cell, d in data.items() if cell.scene == scene}
        cross.append({"scene": scene} | _cross(side["report"], side["mitsuba"]))
    return rows, cross


def check_cross_cells(cells: list[Cell]) -> list[tuple[Cell, Cell]]:
    """Each branching-estimator cell of `cells` with a Mitsuba cell of its own at REPORT_REFERENCE_SPP samples
    per camera ray, at the same depth."""
    return [(c, Cell(c.scene, "mitsuba", c.spp * REPORT_REFERENCE_SPP, c.max_depth, c.repetitions))
            for c in cells if c.renderer == "report"]


def measure_check_cross(cells: list[Cell], cache: Path = CACHE, runner: Runner | None = None) -> list[dict]:
    """The branching estimator against Mitsuba in the check's configuration (check_cross_cells)."""
    pairs = check_cross_cells(cells)
    data = run_cells([(c, CHECK) for pair in pairs for c in pair], runner, cache)
    return [asdict(cell) | _cross(data[cell, CHECK], data[mitsuba, CHECK]) for cell, mitsuba in pairs]


def _cross(report: dict[str, np.ndarray], mitsuba: dict[str, np.ndarray]) -> dict:
    """The branching estimator's cell against Mitsuba's: repetition by repetition (their test passes:
    independent renders), every run against every run (each cell's test and ref passes: 2R x 2R pairs that
    share runs), and the disagreements of the former."""
    pairs = list(itertools.product(_runs(report), _runs(mitsuba)))    # views of the runs, not copies
    return ({"n": len(report["test"]), "disagreements": _disagreements(report, mitsuba),
             "all_pairs": {"n": len(pairs)} | verdicts(*zip(*pairs))} | verdicts(report["test"], mitsuba["test"]))


def _runs(data: dict[str, np.ndarray]) -> np.ndarray:
    """A cell's runs: its test and ref passes (2R runs of independent seeds)."""
    return np.concatenate([data["test"], data["ref"]])


def _disagreements(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> list[dict]:
    """The comparisons of a's test passes with b's that disagree at protocol.ALPHA: their repetition, most
    rejected block and channel, p, each side's passes there (mean, standard deviation), and each side's mean
    and skewness there over the passes of all its runs (test and ref: 2R runs of independent seeds)."""
    out = []
    for r, (ta, tb) in enumerate(zip(a["test"], b["test"])):
        c = compare(ta, tb, protocol.ALPHA)
        if c.verdict != "disagree":
            continue
        at = (slice(None), *c.worst_block)
        every = [_runs(x).reshape(-1, *x["test"].shape[2:])[at] for x in (a, b)]    # all their passes
        out.append({"repetition": r, "block": [int(i) for i in c.worst_block], "p": c.min_p,
                    "passes": [[float(x[at].mean()), float(x[at].std(ddof=1))] for x in (ta, tb)],
                    "all_runs": [float(x.mean()) for x in every], "skewness": [float(sps.skew(x)) for x in every]})
    return out


def interval(k: int, n: int) -> tuple[float, float]:
    """Clopper-Pearson 95% interval of a binomial rate k / n."""
    lo = sps.beta.ppf(0.025, k, n - k + 1) if k > 0 else 0.0
    hi = sps.beta.ppf(0.975, k + 1, n - k) if k < n else 1.0
    return float(lo), float(hi)


def measure(cells: list[Cell], cache: Path = CACHE, runner: Runner | None = None) -> list[dict]:
    data = run_cells([(cell, CHECK) for cell in cells], runner, cache)
    return [asdict(cell) | rates(data[cell, CHECK]) for cell in cells]


def write_json(rows: list[dict], path: Path) -> None:
    from ..reports.provenance import write_json

    write_json(path, rows)


def _cell_table(rows: list[dict], alpha: float) -> list[str]:
    spps = sorted({r["spp"] for r in rows})
    lines = ["| scene | renderer | max_depth | " + " | ".join(f"spp {s}" for s in spps) + " |",
             "|---|---|---:|" + "---|" * len(spps)]
    keyed = {(r["scene"], r["renderer"], r["max_depth"], r["spp"]): r for r in rows}
    for scene, renderer, depth in dict.fromkeys((r["scene"], r["renderer"], r["max_depth"]) for r in rows):
        cells = []
        for s in spps:
            r = keyed.get((scene, renderer, depth, s))
            cells.append("" if r is None else f"{r[f'new_{alpha:g}']}/{r['n']} ({r[f'old_{alpha:g}']}/{r['n']})"
                         + (f", {r[f'inconclusive_{alpha:g}']} inc." if r[f"inconclusive_{alpha:g}"] else ""))
        lines.append(f"| {scene} | {renderer} | {depth} | " + " | ".join(cells) + " |")
    return lines


def _pooled(rows: list[dict]) -> list[str]:
    n = sum(r["n"] for r in rows)
    lines = ["| family-wise alpha | check: disagree | 95% interval | check: inconclusive | earlier test: fail | "
             "95% interval | cells whose check interval lies above alpha |", "|---:|---:|---|---:|---:|---|---:|"]
    for alpha in ALPHAS:
        new = sum(r[f"new_{alpha:g}"] for r in rows)
        old = sum(r[f"old_{alpha:g}"] for r in rows)
        inc = sum(r[f"inconclusive_{alpha:g}"] for r in rows)
        above = sum(interval(r[f"new_{alpha:g}"], r["n"])[0] > alpha for r in rows)
        lo, hi = interval(new, n)
        olo, ohi = interval(old, n)
        lines.append(f"| {alpha:g} | {new}/{n} = {new / n:.2%} | [{lo:.2%}, {hi:.2%}] | {inc}/{n} | {old}/{n} = "
                     f"{old / n:.2%} | [{olo:.2%}, {ohi:.2%}] | {above}/{len(rows)} |")
    return lines


def _sweep_section(rows: list[dict], cross: list[dict]) -> list[str]:
    """The scene reports' configuration: its null cells and the branching estimator against Mitsuba."""
    n, tests = sum(r["n"] for r in rows), (SWEEP.size // protocol.BLOCK) ** 2 * 3
    lines = [
        f"## False alarms in the scene reports' configuration: {n} null comparisons", "",
        "The scene reports (`validate report`) check every sweep run with the same test in another "
        f"configuration: {SWEEP.passes} passes per side at {SWEEP.size} x {SWEEP.size} ({tests} block tests, 16 "
        f"times the check's), max_depth {SWEEP_DEPTH} in the error-against-time sweep, the branching estimator "
        f"at N = {SWEEP.report[0]}, M = {SWEEP.report[1]} against Mitsuba at {REPORT_REFERENCE_SPP} samples per "
        f"pass per camera ray. Null comparisons there, on the reports' scenes, at max_depth {SWEEP_DEPTH}: "
        "each renderer against itself with independent seeds (disagree / comparisons, inconclusive ones "
        "named):", "",
        "| scene | renderer | spp per pass | " + " | ".join(f"alpha {a:g}" for a in ALPHAS) + " |",
        "|---|---|---:|" + "---|" * len(ALPHAS)]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['renderer']} | {r['spp']} | " + " | ".join(_rate(r, a) for a in ALPHAS) + " |")
    lines += ["", "Pooled:", "", "| family-wise alpha | check: disagree | 95% interval | check: inconclusive |",
              "|---:|---:|---|---:|"]
    for alpha in ALPHAS:
        k, inc = sum(r[f"new_{alpha:g}"] for r in rows), sum(r[f"inconclusive_{alpha:g}"] for r in rows)
        lo, hi = interval(k, n)
        lines.append(f"| {alpha:g} | {k}/{n} = {k / n:.2%} | [{lo:.2%}, {hi:.2%}] | {inc}/{n} |")
    lines += ["", f"The comparison a report makes, the branching estimator ({SWEEP_REPORT_SPP} camera rays per pixel "
              f"and pass) against Mitsuba ({SWEEP_REPORT_SPP * REPORT_REFERENCE_SPP} spp per pass), each "
              "repetition's test passes of the two cells above (independent renders; a false alarm only if both "
              "renderers are unbiased):", ""] + _cross_table(cross, ("scene",)) + ["", EVERY_RUN]
    found = [(r["scene"], d) for r in cross for d in r["disagreements"]]
    if found:
        lines += ["", f"Each of these comparisons that disagrees at alpha {protocol.ALPHA:g}, at its most rejected "
                  "block: the two sides' passes there (mean and standard deviation of the pass means), and each "
                  "side's mean and skewness there over the passes of all its runs in the two cells:", ""]
        lines += [f"- {scene}, repetition {d['repetition']}: block ({d['block'][0]}, {d['block'][1]}) "
                  f"{'RGB'[d['block'][2]]}, p = {d['p']:.2g}; branching estimator {d['passes'][0][0]:.4g} "
                  f"(sd {d['passes'][0][1]:.2g}), Mitsuba {d['passes'][1][0]:.4g} (sd {d['passes'][1][1]:.2g}); "
                  f"over all runs {d['all_runs'][0]:.4g} and {d['all_runs'][1]:.4g}, their passes' skewness "
                  f"{d['skewness'][0]:.2g} and {d['skewness'][1]:.2g}" for scene, d in found]
    return lines


EVERY_RUN = ("Every run against every run: each of the branching estimator's 2R runs (the cells' test and ref "
             "passes) against each of Mitsuba's, R the repetitions; the pairs share runs, so their count is no "
             "binomial sample, but their rate estimates the same false-alarm rate more finely than R pairs do.")


def _cross_table(rows: list[dict], keys: tuple[str, ...]) -> list[str]:
    """The branching estimator against Mitsuba: a row per cell (`keys` name it), repetition by repetition at
    each level of ALPHAS, then every run against every run."""
    lines = ["| " + " | ".join(k.replace("_", " ") for k in keys) + " | comparisons | "
             + " | ".join(f"alpha {a:g}" for a in ALPHAS) + " | every run against every run, at "
             + " / ".join(f"{a:g}" for a in ALPHAS) + " |",
             "|" + "---|" * len(keys) + "---:|" + "---|" * (len(ALPHAS) + 1)]
    pooled = _pool(rows) | {"all_pairs": _pool([r["all_pairs"] for r in rows])}
    for r, label in [(r, [str(r[k]) for k in keys]) for r in rows] + [(pooled, ["all"] + [""] * (len(keys) - 1))]:
        lines.append("| " + " | ".join(label) + f" | {r['n']} | " + " | ".join(_rate(r, a) for a in ALPHAS) + " | "
                     + " / ".join(_rate(r["all_pairs"], a) for a in ALPHAS) + " |")
    return lines


def _pool(rows: list[dict]) -> dict:
    """Counts (n, new_*, inconclusive_*) summed over rows."""
    return {k: sum(r[k] for r in rows) for k in rows[0] if k == "n" or k.startswith(("new_", "inconclusive_"))}


def _rate(row: dict, alpha: float) -> str:
    inc = row[f"inconclusive_{alpha:g}"]
    return f"{row[f'new_{alpha:g}']}/{row['n']}" + (f", {inc} inc." if inc else "")


def check_process_seconds() -> tuple[float, float]:
    """Wall seconds of `validate check` on the room as a user runs it: with an empty cache, then cached."""
    import os
    import subprocess
    import sys
    import tempfile

    scene = Path(SCENES["room"]).resolve()
    times = []
    with tempfile.TemporaryDirectory() as cwd:
        for _ in range(2):
            start = time.perf_counter()
            subprocess.run([sys.executable, "-m", "validation.cli", "check", str(scene)], cwd=cwd, check=True,
                           capture_output=True,
                           env=os.environ | {"PYTHONPATH": str(Path(__file__).resolve().parents[2])})
            times.append(time.perf_counter() - start)
    return times[0], times[1]


def report(out: Path, repetitions: int = 12, runner: Runner | None = None) -> Path:
    """Measures (or reads from the cache) the null grid and the power table; writes `out` and its JSON. Every
    cell not cached renders as one suite on `runner` (default: in this process)."""
    from . import power
    from ..reports.provenance import environment, write_text

    start = time.perf_counter()
    cells = grid(repetitions)
    run_cells([(c, CHECK) for c in cells] + [(c, SWEEP) for c in sweep_grid(2 * repetitions)]
              + [(c, CHECK) for pair in check_cross_cells(cells) for c in pair], runner)     # one suite
    rows = measure(cells)
    sweep_rows, cross = measure_sweep(2 * repetitions)
    check_cross = measure_check_cross(cells)
    cells = power.measure_all()
    seconds = [c.correct.seconds for c in cells]
    cold, warm = check_process_seconds()
    against = {"renderer": "report against mitsuba"}
    write_json([r | {"setting": "check"} for r in rows] + [r | {"setting": "sweep"} for r in sweep_rows]
               + [r | {"setting": "sweep"} | against for r in cross]
               + [r | {"setting": "check"} | against for r in check_cross], out.with_suffix(".json"))
    n = sum(r["n"] for r in rows)
    lines = [
        "# Calibration of `validate check`", "",
        f"Generated by `validate calibrate` in {time.perf_counter() - start:.0f} s (renders cached in "
        f".cache/calibration). The check's design and rules are in validation/verdict/stats.py (`compare`) and "
        "validation/verdict/check.py.", "",
        "## Design", "",
        "- **Equal budgets.** The renderer under test and Mitsuba render the same number of passes "
        f"({protocol.PASSES}) at the same samples per pass (the branching estimator: {REPORT_REFERENCE_SPP} Mitsuba "
        "samples per camera ray). A pixel estimate in rendering is heavy-tailed (caustics, small lights): with few samples against "
        "a many-sample reference, the passes that missed the rare bright paths have both a low mean and a low "
        "variance, and Welch's t is then far from t-distributed on the dark side. With equal budgets the two "
        "pass means are skewed alike and their difference is symmetric, so the test keeps its level (Jung, "
        "Hanika and Dachsbacher 2020 compare renderers with Welch's test at low, equal sample counts). The "
        "branching estimator traces many rays per camera ray, and where few camera rays see a small bright "
        "feature (a light's edge, its reflection), a side's pass means are skewed by how few they are: against "
        "Mitsuba at 32 samples per camera ray its passes were far more skewed than Mitsuba's, Welch's t with "
        "them, and the comparison disagreed on correct renders more often than alpha. Of 8, 16 and 32 samples "
        f"per camera ray, {REPORT_REFERENCE_SPP} makes the two sides skewed most alike (measured below).",
        "- **Welch's t-test** per 4 x 4 block and channel and on the image mean per channel, Bonferroni-corrected "
        "(half of alpha to the blocks, half to the image means), family-wise alpha 1e-3 per check. Differences "
        "below 1e-5 of a block's mean are not resolved: that is float32 round-off (a constant sky seen directly "
        "has no variance, and two renderers' lookups differ by 5e-7).",
        "- **Inconclusive, not disagree**, where the normal approximation cannot be trusted: a rejected block "
        "whose passes hold an outlier on either side (Grubbs' test at 1%), whose mean rests on fewer than "
        f"{MIN_NONZERO} non-black passes, or whose passes on one side take fewer than {MIN_DISTINCT} values "
        "while the other side's vary (a count of rare events, as the camera rays of a pass that see a few lit "
        "pixels). The check then repeats on fresh passes, at the geometric mean of its spp and --max-spp "
        f"({protocol.MAX_SPP}), then at --max-spp (each of the 3 stages at alpha / 3), and, if still undecided, "
        "says how many samples would settle it.",
        "",
        f"## False alarms: {n} null comparisons", "",
        "A null comparison pits an unbiased renderer against itself with independent seeds, in the check's "
        f"configuration ({protocol.PASSES} passes each, {protocol.SIZE} x {protocol.SIZE}, equal budgets), so "
        "every `disagree` is a false alarm. Scenes: `room` (mitsuba_scenes/hexagon_room.xml), `caustic` "
        "(mitsuba_scenes/caustic.xml: a glass sphere under a small light), `dark` (mitsuba_scenes/dark.xml: "
        "a few lit pixels). Renderers: Mitsuba's path, the tracer's path, its branching estimator (N = M = 4). "
        "The earlier test (Welch per block with a resolution floor, against a 16 x 256 spp reference of the "
        "same renderer, as the reports used it; 16 x 64 for the branching estimator) runs on the same test "
        "passes.", "",
        "Pooled over every cell, at three family-wise levels (the check's rates should lie at or below alpha; "
        "Clopper-Pearson 95% intervals):", ""] + _pooled(rows) + [
        "", "Per cell at the check's alpha 1e-3: check disagree / comparisons (earlier test's failures), and how "
        "often the check was inconclusive:", ""] + _cell_table(rows, 1e-3) + [
        "", "The same at family-wise alpha 0.1, where a calibrated test rejects about one comparison in ten — a "
        "finer view of its level than 1e-3 gives with these counts:", ""] + _cell_table(rows, 0.1) + [
        "", "## The branching estimator against Mitsuba", "",
        "The null comparisons above pit each renderer against itself. A check of the branching estimator "
        f"compares it with Mitsuba at {REPORT_REFERENCE_SPP} samples per pass per camera ray: each of its cells "
        "above against a Mitsuba cell of its own at the same depth (rendered alike, R repetitions), repetition by "
        "repetition (independent renders; a false alarm only if both renderers are unbiased):", ""] + \
        _cross_table(check_cross, ("scene", "max_depth", "spp")) + ["", EVERY_RUN, ""] + \
        _sweep_section(sweep_rows, cross) + [
        "", "## Power: injected faults", ""] + power.markdown(cells) + [
        "", "Each cell: the check's verdict on the faulty tracer / on the correct tracer, at that many Mitsuba "
        "samples per pass, without escalation (faults in validation/suites/faults.py; the branching estimator renders "
        f"spp / {REPORT_REFERENCE_SPP} camera rays per pass, at least 1).", "",
        "## Time per check", "",
        f"`validate check {SCENES['room']}` at its defaults (tracer path, 16 x 64 spp against Mitsuba's 16 x 64 "
        f"spp, 32 x 32), whole process: {cold:.1f} s with an empty reference cache, {warm:.1f} s with Mitsuba's "
        f"passes cached. Inside one process, a check in the power table took {np.median(seconds):.1f} s (median; "
        "references cached); seconds per null repetition (both sides rendered) are in calibration.json.", "",
        "## Machine and versions", ""] + environment(f"validate calibrate --repetitions {repetitions}")
    return write_text(out, "\n".join(lines) + "\n")


def cached_repetitions(path: Path, repetitions: int, desc: str,
                       render_one: Callable[[int], dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """`repetitions` repetitions of a study's renders, `render_one(r)` giving repetition r's arrays by name, with
    the seconds each took; written to `path` (atomically) after every repetition, so that an interrupted run
    resumes and a larger one extends it."""
    data = {k: list(v) for k, v in np.load(path).items()} if path.exists() else {"seconds": []}
    for r in tqdm(range(len(data["seconds"]), repetitions), desc=desc, unit="repetition"):
        start = time.perf_counter()
        for name, value in render_one(r).items():
            data.setdefault(name, []).append(value)
        data["seconds"].append(time.perf_counter() - start)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, **{k: np.stack(v) for k, v in data.items()})
        tmp.replace(path)
    return {k: np.stack(v[:repetitions]) for k, v in data.items()}
