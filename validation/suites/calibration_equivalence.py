"""Equivalence calibrated both ways: the staged check with a margin (validation.verdict.check.sequential: a pilot stage,
then stages whose samples per pass it plans from the stage before; TOST in validation.verdict.stats) on null
comparisons and on renderers scaled by 1 - k x margin (k = 0.5, 1, 2: the example renderer's --scale).

The renderer under test is Mitsuba's `path` (a null comparison in the strict sense) or the tracer's `path`
(a false alarm only if the tracer is unbiased); the reference is always Mitsuba's `path`. A renderer scaled
by s renders s times an unbiased renderer's passes, so the test side's block means times s are exactly its
passes: every bias is measured on the same renders.

The samples per pass of a planned stage depend on the stage before, so a repetition's passes are rendered on
demand in dyadic atoms: per side and stage, 16 passes at 2^j spp for each j a plan needs; a pass of m spp is
the spp-weighted mean of the atoms of m's binary digits (with a box filter, as these scenes use, exactly the
mean of m independent samples per pixel, as one pass of m would be). Every
atom is cached (.cache/calibration, one file per repetition, written atomically after each atom): an
interrupted run resumes, a larger one extends it.

The grid is reduced to what this machine renders: the check's 32 x 32 at 16 passes, on the room, the
Cornell box and the caustic scene, with a pilot of PILOT = 4 spp per pass and at most 512: 16 (SCALE^2) times
fewer samples than the check's defaults (64, up to 8192), so standard errors 4 times larger, and margins 4
times larger to match (the image margin 4% here is the default budget's 1%, the block margin 80% its 20%).
The rates depend on the margins only through margin / standard error, so the sequence is the check's with
--margin 1% at its defaults, on passes of 4 to 512 samples, more skewed than the default's 64 to 8192 (the
harder case for the t approximation).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from ..verdict import protocol
from .calibration import CACHE, interval
from ..verdict.check import sequential
from ..verdict.renderers import MitsubaRenderer, TracerRenderer
from ..verdict.scenefile import plan
from ..verdict.stats import Margin, block_means, compare

SCENES = {"room": "mitsuba_scenes/hexagon_room.xml", "cornell_box": "mitsuba_scenes/cornell_box.xml",
          "caustic": "mitsuba_scenes/caustic.xml"}
MAX_DEPTH = {"room": 4, "cornell_box": -1, "caustic": -1}
RENDER_TEST = "tests/scenes/bsdf_spheres/test_arealight_path.xml"   # in mitsuba-renderer/mitsuba-data: Mitsuba's
# render-test scene of the rows, at its own 48 x 48 and depth; its image mean is noisy, so the pilot rarely
# decides and the planned stage does: the regime where a false "equivalent" at the margin can happen
RENDERERS = ("mitsuba", "path")         # the renderer under test; the reference is Mitsuba's path
SCALE = 4                               # the check's default budget has SCALE^2 x the samples: standard errors / 4
PILOT = protocol.SPP // SCALE ** 2      # the pilot's spp per pass
MAX_SPP = protocol.MAX_SPP // SCALE ** 2
BIASES = (0.0, 0.5, 1.0, 2.0)           # multiples of the margin by which the test side is too dark
MARGIN = Margin(protocol.CI_MARGIN * SCALE, protocol.BLOCK_MARGIN * SCALE)   # --margin 1% 20% at the defaults
ALPHA = 0.05                            # a level whose rates these repetitions can resolve
SEED = 70_000


@dataclass(frozen=True)
class Outcome:
    verdict: str
    stage: int          # 1-based stage that decided (or the last run)
    spent: int          # samples per pass summed over the stages run (x passes: per pixel and side)


class Repetition:
    """One repetition's passes of both sides, rendered on demand in dyadic atoms and cached in `path`."""

    def __init__(self, path: Path, render):
        self.path, self.render = path, render     # render(side, stage, j, seed) -> (K, rows, columns, 3)
        self.data = dict(np.load(path)) if path.exists() else {}

    def passes(self, side: str, stage: int, m: int) -> np.ndarray:
        """Block means of PASSES passes at m spp: the atoms of m's binary digits, weighted by their spp."""
        return sum(self.atom(side, stage, j) * 2 ** j for j in range(m.bit_length()) if m >> j & 1) / m

    def atom(self, side: str, stage: int, j: int) -> np.ndarray:
        name = f"{side}-{stage}-{j}"
        if name not in self.data:
            seed = 100 * stage + 20 * j + (50_000 if side == "ref" else 0)   # 20 apart: 16 passes' seeds each
            self.data[name] = self.render(side, stage, j, seed)
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.path.with_suffix(".tmp.npz")
            np.savez(tmp, **self.data)
            tmp.replace(self.path)
        return self.data[name]


def _plan(scene: str, mitsuba_data: Path | None):
    if scene == "arealight":
        return plan(mitsuba_data / RENDER_TEST, size=None)
    return plan(SCENES[scene], size=protocol.SIZE, max_depth=MAX_DEPTH[scene])


def cells(mitsuba_data: Path | None = None) -> list[tuple[str, str]]:
    """(renderer under test, scene): both renderers on the project's scenes; with a copy of mitsuba-data,
    Mitsuba on its render-test scene too (a strict null comparison: whether the tracer agrees with Mitsuba there
    is for the render tests, reports/mitsuba_tests.md)."""
    return [(r, s) for r in RENDERERS for s in SCENES] + ([("mitsuba", "arealight")] if mitsuba_data else [])


def repetition(scene: str, renderer: str, r: int, cache: Path = CACHE, mitsuba_data: Path | None = None) -> Repetition:
    scene_plan = _plan(scene, mitsuba_data)
    key = scene_plan.content_key(passes=protocol.PASSES, seed=SEED, renderer=renderer, design="atoms")
    sides = {"test": MitsubaRenderer() if renderer == "mitsuba" else TracerRenderer(renderer), "ref": MitsubaRenderer()}

    def render(side: str, stage: int, j: int, seed: int) -> np.ndarray:
        passes = sides[side].passes(scene_plan, protocol.PASSES, 2 ** j, SEED + 1_000_000 * r + seed)
        return block_means(passes, protocol.BLOCK).astype(np.float32)

    return Repetition(cache / f"equivalence-{scene}-{renderer}-{key}" / f"r{r}.npz", render)


def sequence(rep: Repetition, alpha: float, margin: Margin, scale: float = 1.0) -> Outcome:
    """One repetition replayed as `validate check --margin` decides it (check.sequential), the test side scaled."""
    def decide(stage: int, spp: int, level: float):
        return compare(rep.passes("test", stage, spp) * scale, rep.passes("ref", stage, spp), level, margin)

    seq = sequential(decide, PILOT, MAX_SPP, alpha, margin)
    return Outcome(seq.comparison.verdict, seq.stage, seq.spent)


def measure(repetitions: int, cache: Path = CACHE, mitsuba_data: Path | None = None,
            render_test_repetitions: int | None = None) -> list[dict]:
    """Per renderer, scene and bias: how many sequences ended equivalent, disagree, inconclusive, and the
    budget each verdict took; repetition by repetition over every cell, so that an interrupted run leaves
    the cells balanced (the render-test scene's cell: `render_test_repetitions`, default `repetitions`)."""
    grid = cells(mitsuba_data)
    wanted = {c: render_test_repetitions or repetitions if c[1] == "arealight" else repetitions for c in grid}
    outcomes: dict[tuple, list[Outcome]] = {(c, k): [] for c in grid for k in BIASES}
    for r in tqdm(range(max(wanted.values())), desc="equivalence repetitions", unit="repetition"):
        for renderer, scene in (c for c in grid if r < wanted[c]):
            rep = repetition(scene, renderer, r, cache, mitsuba_data)
            for k in BIASES:
                outcomes[(renderer, scene), k].append(sequence(rep, ALPHA, MARGIN, 1 - k * MARGIN.image))
    return [{"renderer": renderer, "scene": scene, "alpha": ALPHA, "bias": k, "n": len(o)}
            | {v: sum(x.verdict == v for x in o) for v in ("equivalent", "disagree", "inconclusive")}
            | {f"spent_{v}": [x.spent for x in o if x.verdict == v] for v in ("equivalent", "disagree", "inconclusive")}
            | {"stages": [x.stage for x in o]}
            for ((renderer, scene), k), o in outcomes.items()]


def faults(spp: int = 256) -> list[dict]:
    """The injected faults (validation.suites.faults) under `validate check --margin 1%` at the default block margin,
    one stage of `spp`: the verdict on the faulty and on the correct tracer, with the faulty one's image mean."""
    from .faults import FAULTS
    from .power import measure as check_fault

    margin = Margin(protocol.CI_MARGIN, protocol.BLOCK_MARGIN)
    rows = []
    for fault in tqdm(FAULTS.values(), desc="faults with a margin"):
        cell = check_fault(fault, spp, margin)
        rows.append({"fault": fault.name, "spp": spp, "faulty": cell.faulty.verdict, "correct": cell.correct.verdict,
                     "faulty_mean": cell.faulty.comparison.relative_mean_difference,
                     "correct_detectable": [float(x) for x in cell.correct.comparison.detectable_image]})
    return rows


def _rate(k: int, n: int) -> str:
    lo, hi = interval(k, n)
    return f"{k}/{n} [{lo:.1%}, {hi:.1%}]"


def _budget(spent: list[int]) -> str:
    """Samples per pixel a side at the default budget (x SCALE^2), as median and largest."""
    if not spent:
        return "-"
    scaled = [protocol.PASSES * s * SCALE ** 2 for s in spent]
    return f"{np.median(scaled):.0f} ({max(scaled)})"


def _pool(rows: list[dict]) -> dict:
    out = {"n": 0, "equivalent": 0, "disagree": 0, "inconclusive": 0, "spent_equivalent": [], "spent_disagree": [],
           "spent_inconclusive": []}
    for r in rows:
        for k in out:
            out[k] += r[k]
    return out


def markdown(rows: list[dict]) -> list[str]:
    lines = [
        SECTION, "",
        f"`validate check --margin {MARGIN.image / SCALE:.0%}` (block margin {MARGIN.block / SCALE:.0%}) replayed as "
        f"it decides (validation/suites/calibration_equivalence.py): a pilot stage, then stages whose samples per pass it "
        f"plans from the stage before, at most 3, each at level alpha / 3 (alpha {ALPHA:g}: a level whose rates "
        f"these repetitions can resolve). Repetitions per scene and renderer under test (n in the per-scene table): "
        f"Mitsuba's path, or the tracer's path, against Mitsuba's path, on the project's {', '.join(SCENES)} at "
        f"{protocol.SIZE} x {protocol.SIZE}, and (Mitsuba only: a strict null comparison) on "
        f"`arealight`, Mitsuba's render-test scene {RENDER_TEST} of mitsuba-renderer/mitsuba-data at its own "
        f"48 x 48, whose noisy image mean the pilot rarely decides; {protocol.PASSES} passes a side. "
        f"**A reduced grid**: a pilot of {PILOT} spp per pass and "
        f"at most {MAX_SPP}, {SCALE ** 2} times fewer than the check's defaults ({protocol.SPP}, up to "
        f"{protocol.MAX_SPP}), with margins {SCALE} times wider to match (standard errors are {SCALE} times larger); "
        "its passes are more skewed than the default's. The test side is scaled by 1 - k x margin (k = 0: a null "
        "comparison; k = 1: too dark by exactly the margin; the example renderer's `--scale`), so every row of a "
        "renderer comes from the same renders. A false alarm is `disagree` at k = 0 (at most alpha); a false "
        "\"equivalent\" is `equivalent` at k = 1 (at most alpha); the power curve is `disagree` at k = 0.5, 1, 2 "
        "and `equivalent` at k = 0. Clopper-Pearson 95% intervals. Budget: the samples per pixel each side "
        "rendered over the stages the verdict took (passes x spp, summed), quoted at the default budget "
        f"(x {SCALE ** 2}): median (largest).", "",
        "| renderer under test | scenes | bias (x margin) | equivalent | disagree | inconclusive | budget of "
        "equivalent | budget of disagree | budget of inconclusive |", "|---|---|---:|---|---|---:|---|---|---|"]
    groups = [(renderer, "project's 3", lambda r, x=renderer: r["renderer"] == x and r["scene"] in SCENES)
              for renderer in RENDERERS]
    if any(r["scene"] == "arealight" for r in rows):
        groups.append(("mitsuba", "arealight", lambda r: r["scene"] == "arealight"))
    for renderer, label, chosen in groups:
        for k in BIASES:
            p = _pool([r for r in rows if chosen(r) and r["bias"] == k])
            lines.append(f"| {renderer} | {label} | {k:g} | {_rate(p['equivalent'], p['n'])} | "
                         f"{_rate(p['disagree'], p['n'])} | {p['inconclusive']}/{p['n']} | "
                         f"{_budget(p['spent_equivalent'])} | {_budget(p['spent_disagree'])} | "
                         f"{_budget(p['spent_inconclusive'])} |")
    lines += ["", "Per scene: equivalent / disagree / inconclusive at each bias:", "",
              "| renderer under test | scene | n | " + " | ".join(f"k = {k:g}" for k in BIASES) + " |",
              "|---|---|---:|" + "---|" * len(BIASES)]
    for renderer, scene in dict.fromkeys((r["renderer"], r["scene"]) for r in rows):
        cells = [r for r in rows if r["renderer"] == renderer and r["scene"] == scene]
        if cells:
            lines.append(f"| {renderer} | {scene} | {cells[0]['n']} | " + " | ".join(
                f"{c['equivalent']} / {c['disagree']} / {c['inconclusive']}" for c in cells) + " |")
    return lines


SECTION = "## Equivalence: false alarms, false \"equivalent\" and power"


def update(out: Path, repetitions: int, mitsuba_data: Path | None = None,
           render_test_repetitions: int | None = None) -> Path:
    """Measures (cached renders) and writes this section into `out` (reports/calibration.md), replacing an
    earlier one and keeping every other section; its rows go to calibration_equivalence.json beside it."""
    from ..reports.provenance import replace_section, write_json

    rows = measure(repetitions, mitsuba_data=mitsuba_data, render_test_repetitions=render_test_repetitions)
    injected = faults()
    write_json(out.with_name("calibration_equivalence.json"), {"sequences": rows, "faults": injected})
    command = (f"validate calibrate --only equivalence --equivalence-repetitions {repetitions}"
               + (f" --mitsuba-data MITSUBA_DATA_DIR --render-test-repetitions {render_test_repetitions or repetitions}"
                  if mitsuba_data else ""))
    return replace_section(out, SECTION, markdown(rows) + ["", f"Generated by `{command}` (renders cached in "
                                                                 ".cache/calibration)."] + [""] + fault_table(injected),
                           before="## Time per check")


def fault_table(rows: list[dict]) -> list[str]:
    lines = [f"The injected faults (validation/suites/faults.py) under `--margin {protocol.CI_MARGIN:.0%}` (block margin "
             f"{protocol.BLOCK_MARGIN:.0%}), one stage of 16 x {rows[0]['spp'] if rows else 0} "
             "Mitsuba samples per pass (the branching estimator: 1/8 as many camera rays), 32 x 32: the verdict on "
             "the faulty tracer / on the correct one, and the faulty tracer's image mean against Mitsuba's:", "",
             "| fault | faulty / correct | faulty image mean | correct: detectable bias of the image mean (RGB) |",
             "|---|---|---:|---|"]
    for r in rows:
        lines.append(f"| {r['fault']} | {r['faulty']} / {r['correct']} | {r['faulty_mean']:+.2%} | "
                     + "/".join(f"{x:.2%}" for x in r["correct_detectable"]) + " |")
    return lines
