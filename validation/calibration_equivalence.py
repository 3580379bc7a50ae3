"""Equivalence calibrated both ways: the sequential check with a margin (validation.check.run, TOST in
validation.stats) on null comparisons and on renderers scaled by 1 - k x margin (k = 0.5, 1, 2: the example
renderer's --scale), from one set of renders.

Each repetition renders, per stage of the sequence (samples per pass x4 from stage to stage), PASSES passes
of Mitsuba's `path` on each side with fresh seeds. A renderer scaled by s renders s times an unbiased
renderer's passes, so the test side's block means times s are exactly its passes: every bias is measured on
the same renders, and the null comparisons are the renders themselves. The sequence is then replayed as
`validate check --margin` decides it (stage levels alpha / stages; stop at equivalent or disagree).

The grid is reduced to what this takes to render: Mitsuba against Mitsuba, the check's 32 x 32 at 16 passes,
on the room, the Cornell box and the caustic scene, with stages of 4, 16 and 64 spp per pass: 16 times less
than the check's default stages (64, 256, 1024), so standard errors 4 (SCALE) times larger, and margins 4 times
larger to match: the image margin 4% here is 1% at the default budget, block margins 40% and 80% are 10% and
20%. The rates depend on the margins only through margin / standard error, so the sequence is the check's
with --margin 1% B at its defaults, but on passes of 4 to 64 samples, which are more skewed than the
default's (the harder case for the t approximation). Renders are cached per scene in .cache/calibration
(keyed by the scene's content and the design).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from . import protocol
from .calibration import CACHE, cached_repetitions, interval
from .check import stages as plan_stages
from .renderers import MitsubaRenderer
from .scenefile import plan
from .stats import Margin, block_means, compare

SCENES = {"room": "mitsuba_scenes/hexagon_room.xml", "cornell_box": "mitsuba_scenes/cornell_box.xml",
          "caustic": "mitsuba_scenes/caustic.xml"}
MAX_DEPTH = {"room": 4, "cornell_box": -1, "caustic": -1}
STAGES = (4, 16, 64)
SCALE = 4                              # the check's default stages have 16 x the samples: standard errors / 4
BIASES = (0.0, 0.5, 1.0, 2.0)          # multiples of the margin by which the test side is too dark
IMAGE_MARGIN = 0.01 * SCALE             # 1% at the default stages
BLOCK_MARGINS = (0.1 * SCALE, 0.2 * SCALE)   # candidates for protocol.BLOCK_MARGIN (10%, 20% at the default)
ALPHAS = (1e-3, 0.05)
SEED = 70_000


@dataclass(frozen=True)
class Outcome:
    verdict: str
    stage: int          # 1-based stage that decided (the last if none did)
    spent: int          # samples per pixel per side over the stages run (passes x spp summed)


def renders(scene: str, repetitions: int, cache: Path = CACHE) -> dict[str, np.ndarray]:
    """Block means of both sides at every stage: test and ref (R, stages, K, rows, columns, 3), seconds (R,);
    cached after every repetition, so that an interrupted run resumes and a larger one extends it."""
    scene_plan = plan(SCENES[scene], size=protocol.SIZE, max_depth=MAX_DEPTH[scene])
    key = scene_plan.content_key(stages=STAGES, passes=protocol.PASSES, seed=SEED, design="equivalence")
    path = cache / f"equivalence-{scene}-{key}.npz"
    renderer = MitsubaRenderer()

    def one(r: int) -> dict[str, np.ndarray]:
        return {name: np.stack([block_means(renderer.passes(scene_plan, protocol.PASSES, spp,
                                                           SEED + 1000 * r + 100 * s + side),
                                           protocol.BLOCK).astype(np.float32) for s, spp in enumerate(STAGES)])
                for name, side in (("test", 0), ("ref", 50))}

    return cached_repetitions(path, repetitions, f"equivalence {scene}", one)


def sequence(test: np.ndarray, ref: np.ndarray, alpha: float, margin: Margin, scale: float = 1.0) -> Outcome:
    """One repetition's (stages, K, rows, columns, 3) passes replayed as the check decides with a margin."""
    level = alpha / len(STAGES)
    spent = 0
    for s, spp in enumerate(STAGES):
        c = compare(test[s] * scale, ref[s], level, margin)
        spent += protocol.PASSES * spp
        if c.verdict != "inconclusive":
            break
    return Outcome(c.verdict, s + 1, spent)


def measure(repetitions: int, cache: Path = CACHE) -> list[dict]:
    """Per scene, alpha, block margin and bias: how many sequences ended equivalent, disagree, inconclusive,
    and the budget each verdict took."""
    assert list(plan_stages(STAGES[0], STAGES[-1])) == list(STAGES)
    rows = []
    for scene in SCENES:
        data = renders(scene, repetitions, cache)
        for alpha in ALPHAS:
            for block in BLOCK_MARGINS:
                margin = Margin(IMAGE_MARGIN, block)
                for k in BIASES:
                    outcomes = [sequence(t, r, alpha, margin, 1 - k * IMAGE_MARGIN)
                                for t, r in zip(data["test"], data["ref"])]
                    rows.append({"scene": scene, "alpha": alpha, "block_margin": block, "bias": k, "n": len(outcomes)}
                                | {v: sum(o.verdict == v for o in outcomes) for v in ("equivalent", "disagree", "inconclusive")}
                                | {f"spent_{v}": [o.spent for o in outcomes if o.verdict == v]
                                   for v in ("equivalent", "disagree", "inconclusive")}
                                | {"seconds": float(np.median(data["seconds"]))})
    return rows


def faults(spp: int = 256) -> list[dict]:
    """The injected faults (validation.faults) under `validate check --margin 1%` at the default block margin,
    one stage of `spp`: the verdict on the faulty and on the correct tracer, with the faulty one's image mean."""
    from .faults import FAULTS
    from .power import measure as check_fault

    margin = Margin(IMAGE_MARGIN / SCALE, protocol.BLOCK_MARGIN)
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
    if not spent:
        return "-"
    counts = {s: spent.count(s) for s in sorted(set(spent))}
    return ", ".join(f"{n} at {s}" for s, n in counts.items())


def markdown(rows: list[dict], repetitions: int) -> list[str]:
    pooled: dict[tuple, dict] = {}
    for r in rows:
        p = pooled.setdefault((r["alpha"], r["block_margin"], r["bias"]), {"n": 0, "equivalent": 0, "disagree": 0,
                                                                             "inconclusive": 0, "spent_equivalent": [],
                                                                             "spent_disagree": []})
        for k in p:
            p[k] += r[k]
    lines = [
        SECTION, "",
        f"`validate check --margin` replayed on renders of Mitsuba against Mitsuba (validation/"
        f"calibration_equivalence.py): {repetitions} repetitions per scene ({', '.join(SCENES)}), {protocol.PASSES} "
        f"passes per side, {protocol.SIZE} x {protocol.SIZE}, TOST on the image means and every block, stage "
        f"levels alpha / {len(STAGES)}. **A reduced grid**: stages of {', '.join(map(str, STAGES))} spp per pass, "
        f"{SCALE ** 2} times fewer than the check's default {', '.join(str(s * SCALE ** 2) for s in STAGES)}, with "
        f"margins {SCALE} times wider to match (standard errors are {SCALE} times larger): an image margin of "
        f"{IMAGE_MARGIN:.0%} here is the default budget's 1%, and the block margins are quoted at the default "
        "budget. The passes here (4 to 64 samples) are more skewed than the default's. The test side is scaled "
        "by 1 - k x margin (k = 0: a null comparison; k = 1: too dark by exactly the margin; the example "
        "renderer's `--scale`), so every row comes from the same renders. A false alarm is `disagree` at k = 0 "
        "(should be at most alpha); a false \"equivalent\" is `equivalent` at k = 1 (at most alpha); power is "
        "`disagree` at k = 2 and `equivalent` at k = 0. Clopper-Pearson 95% intervals. The budget is the samples "
        "per pixel each side rendered over the stages the verdict took (16 passes x spp, summed, at this "
        "grid's spp), with how many verdicts took it.", ""]
    for alpha in ALPHAS:
        lines += [f"Pooled over the scenes, alpha {alpha:g}:", "",
                  "| block margin (default budget) | bias (x margin) | equivalent | disagree | inconclusive | "
                  "budget of equivalent | budget of disagree |", "|---:|---:|---|---|---:|---|---|"]
        for (a, block, k), p in pooled.items():
            if a == alpha:
                lines.append(f"| {block / SCALE:.0%} | {k:g} | {_rate(p['equivalent'], p['n'])} | "
                             f"{_rate(p['disagree'], p['n'])} | {p['inconclusive']}/{p['n']} | "
                             f"{_budget(p['spent_equivalent'])} | {_budget(p['spent_disagree'])} |")
        lines.append("")
    lines += [f"Per scene at alpha {ALPHAS[-1]:g} and the default block margin ({protocol.BLOCK_MARGIN:.0%}): "
              "equivalent / disagree / inconclusive at each bias:", "",
              "| scene | " + " | ".join(f"k = {k:g}" for k in BIASES) + " | seconds per repetition |",
              "|---|" + "---|" * len(BIASES) + "---:|"]
    for scene in SCENES:
        cells = [r for r in rows if r["scene"] == scene and r["alpha"] == ALPHAS[-1]
                 and abs(r["block_margin"] / SCALE - protocol.BLOCK_MARGIN) < 1e-9]
        if cells:
            lines.append(f"| {scene} | " + " | ".join(f"{c['equivalent']} / {c['disagree']} / {c['inconclusive']}"
                                                     for c in cells) + f" | {cells[0]['seconds']:.0f} |")
    return lines


SECTION = "## Equivalence: false alarms, false \"equivalent\" and power"


def update(out: Path, repetitions: int) -> Path:
    """Measures (cached renders) and writes this section into `out` (reports/calibration.md), replacing an
    earlier one and keeping every other section; its rows go to calibration_equivalence.json beside it."""
    from .provenance import replace_section, write_json

    rows, injected = measure(repetitions), faults()
    write_json(out.with_name("calibration_equivalence.json"), {"sequences": rows, "faults": injected})
    return replace_section(out, SECTION, markdown(rows, repetitions) + [""] + fault_table(injected),
                           before="## Time per check")


def fault_table(rows: list[dict]) -> list[str]:
    lines = [f"The injected faults (validation/faults.py) under `--margin {IMAGE_MARGIN / SCALE:.0%}` (block margin "
             f"{protocol.BLOCK_MARGIN:.0%}), one stage of 16 x {rows[0]['spp'] if rows else 0} "
             "Mitsuba samples per pass (the branching estimator: 1/8 as many camera rays), 32 x 32: the verdict on "
             "the faulty tracer / on the correct one, and the faulty tracer's image mean against Mitsuba's:", "",
             "| fault | faulty / correct | faulty image mean | correct: detectable bias of the image mean (RGB) |",
             "|---|---|---:|---|"]
    for r in rows:
        lines.append(f"| {r['fault']} | {r['faulty']} / {r['correct']} | {r['faulty_mean']:+.2%} | "
                     + "/".join(f"{x:.2%}" for x in r["correct_detectable"]) + " |")
    return lines
