"""`python -m validation.benchmark.suites`: the suites on the runner (validation/suites/runner.py) timed with one
and two local workers, the runner's cost per task, and from those figures, on paper, mitsuba-data's scenes at
their native resolution on 10 and 100 machines; written to reports/suites.md.

Reduced grids (labelled in the report), so that a run fits in minutes: calibrate's null grid on the room at
up to 16 spp per pass (2 repetitions per cell), coverage on four of mitsuba-data's docs scenes. Each
configuration starts from an empty cache, so every unit renders."""
from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from ..reports.provenance import environment, write_json, write_text
from ..suites import calibration as cal
from ..suites import coverage
from ..suites.runner import LOCAL, NONE, Unit, cores, session
from ..verdict import protocol

COVERAGE_SCENES = ("integrator_depth_1.xml", "integrator_depth_2.xml", "shape_cylinder_onesided.xml",
                   "shape_sphere_light_analytic.xml")
MACHINES = (10, 100)
CORES_PER_MACHINE = 2       # as this machine; a worker per core


def overhead(n: int = 200) -> dict[str, float]:
    """Seconds per task of n trivial units (each returns the core count) in this process and on two workers."""
    out = {}
    for where, workers in ((NONE, None), (LOCAL, 2)):
        with session(where, workers, quiet=True) as runner:
            units = [Unit(f"noop-{i}", cores, ()) for i in range(n)]
            runner.run(units[:4], "warm-up")
            start = time.perf_counter()
            runner.run(units, "no-op")
            out[where] = (time.perf_counter() - start) / n
    return out


def _arrays(folder: Path) -> dict:
    out = {}
    for f in sorted(folder.glob("*.npz")):
        with np.load(f) as z:
            out[f.name] = {k: z[k] for k in z.files if k not in ("seconds", "meta")}
    return out


def _same(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(np.array_equal(a[n][k], b[n][k]) for n in a for k in a[n])


def calibrate(tmp: Path) -> dict:
    cells = [c for c in cal.grid(2) if c.scene == "room" and c.spp <= 16]
    units = sum(len(cal.cell_units(c, cal.CHECK, tmp / "x.npz")) for c in cells)
    out = {"cells": len(cells), "units": units}
    for workers in (1, 2):
        start = time.perf_counter()
        with session(LOCAL, workers, quiet=True) as runner:
            started = time.perf_counter()
            cal.run_cells([(c, cal.CHECK) for c in cells], runner, tmp / f"calibrate{workers}")
            out[f"suite_{workers}"] = time.perf_counter() - started
        out[f"total_{workers}"] = time.perf_counter() - start
    out["identical"] = _same(_arrays(tmp / "calibrate1"), _arrays(tmp / "calibrate2"))
    return out


def cover(data: Path, tmp: Path) -> dict:
    root = data
    paths = [root / "docs/scenes" / name for name in COVERAGE_SCENES]
    out = {"units": len(paths)}
    verdicts = {}
    for workers in (1, 2):
        os.environ["VALIDATE_CACHE"] = str(tmp / f"coverage{workers}")
        start = time.perf_counter()
        with session(LOCAL, workers, quiet=True) as runner:
            started = time.perf_counter()
            outcomes = coverage.survey(root, True, runner, paths)
            out[f"suite_{workers}"] = time.perf_counter() - started
        out[f"total_{workers}"] = time.perf_counter() - start
        verdicts[workers] = [(o.scene, o.verdict) for o in outcomes]
        out[f"unit_seconds_{workers}"] = [o.seconds for o in outcomes]
    del os.environ["VALIDATE_CACHE"]
    out["verdicts"] = verdicts[1]
    out["identical"] = verdicts[1] == verdicts[2] and _same(_arrays(tmp / "coverage1"), _arrays(tmp / "coverage2"))
    return out


def on_paper(data: Path | None, per_task: float) -> dict | None:
    """mitsuba-data's scenes the tracer renders (reports/mitsuba_scenes.json), each checked at its native
    resolution: its seconds at 32 pixels scaled by the ratio of pixels (an overestimate: loading and compiling
    do not grow with the pixels), then spread over workers."""
    from ..verdict.scenefile import plan

    rows = json.loads(Path("reports/mitsuba_scenes.json").read_text())
    checked = [r for r in rows if r["verdict"] in ("agree", "disagree", "inconclusive")]
    if data is None or not checked:
        return None
    seconds = []
    for r in checked:
        native = plan(data / r["scene"], size=None)
        small = plan(data / r["scene"], size=protocol.SIZE)
        seconds.append(r["seconds"] * native.width * native.height / (small.width * small.height))
    total, longest = sum(seconds), max(seconds)
    out = {"scenes": len(checked), "total": total, "longest": longest}
    for m in MACHINES:
        workers = m * CORES_PER_MACHINE
        out[f"machines_{m}"] = max(total / workers, longest) + len(checked) * per_task / workers
    return out


def markdown(over: dict, cal_: dict, cov: dict | None, paper: dict | None, command: str) -> str:
    lines = ["# The suites on the runner", "",
             f"Generated by `{command}`. **This machine has {cores()} cores and was shared with other work while it "
             "ran** (its load was not controlled): the times below are what one run saw.", "",
             "## Wall time with one and two local workers", "",
             "Reduced grids (each from an empty cache: every unit renders):", "",
             "| suite | units | 1 worker [s] | 2 workers [s] | speed-up | results identical (bit for bit) |",
             "|---|---:|---:|---:|---:|---|",
             f"| `validate calibrate`'s null grid, room only, spp per pass <= 16, 2 repetitions per cell ({cal_['cells']} "
             f"cells) | {cal_['units']} | {cal_['suite_1']:.1f} | {cal_['suite_2']:.1f} | "
             f"{cal_['suite_1'] / cal_['suite_2']:.2f} | {'yes' if cal_['identical'] else 'NO'} |"]
    if cov:
        lines.append(f"| `validate coverage` on {cov['units']} docs scenes ({', '.join(COVERAGE_SCENES)}) | "
                     f"{cov['units']} | {cov['suite_1']:.1f} | {cov['suite_2']:.1f} | {cov['suite_1'] / cov['suite_2']:.2f} | "
                     f"{'yes' if cov['identical'] else 'NO'} (verdicts and references) |")
    lines += ["", f"Starting and stopping the local cluster added {cal_['total_1'] - cal_['suite_1']:.1f} s (1 worker) "
              f"and {cal_['total_2'] - cal_['suite_2']:.1f} s (2 workers) to the calibration run; a worker's first "
              "unit also pays for importing the tracer and Mitsuba and compiling their kernels.", "",
              "## The runner's cost per task", "",
              f"200 trivial units (each returns a number): {over[NONE] * 1e3:.2f} ms per task in this process "
              f"(`--scheduler none`), {over[LOCAL] * 1e3:.2f} ms per task on a local cluster of two workers (Dask's "
              "scheduling, the transfer of the result, the progress bar). A calibration unit renders for a second or "
              "more, so the runner's share is below a percent."]
    if paper:
        lines += ["", "## On paper: mitsuba-data at native resolution on 10 and 100 machines", "",
                  f"From reports/mitsuba_scenes.json: the {paper['scenes']} scenes the tracer renders, each checked "
                  "(16 passes a side) in the seconds that report measured at 32 pixels on the longer side, scaled "
                  "by the ratio of the scene's own film's pixels to those (an overestimate: loading and compiling do "
                  f"not grow with the pixels). In all {paper['total'] / 3600:.1f} core-hours, the longest scene "
                  f"{paper['longest'] / 60:.1f} min. With {CORES_PER_MACHINE} cores (workers) per machine, a scene "
                  "a unit: wall time = max(total / workers, longest unit) + units x cost per task / workers:", "",
                  "| machines | workers | wall time (on paper) |", "|---:|---:|---:|"]
        lines += [f"| {m} | {m * CORES_PER_MACHINE} | {paper[f'machines_{m}'] / 60:.1f} min |" for m in MACHINES]
        lines += ["", "At 100 machines the longest scene bounds the wall time: a scene a unit leaves most workers idle; "
                  "splitting a scene's check into blocks of passes (its 16 passes as units of their own) would "
                  "lower that bound."]
    lines += ["", "## Machine and versions", ""] + environment(command)
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m validation.benchmark.suites", description=__doc__)
    p.add_argument("--mitsuba-data", type=Path, metavar="DIR", help="a copy of mitsuba-renderer/mitsuba-data: adds "
                   "coverage and the on-paper figures")
    p.add_argument("--output", "-o", type=Path, default=Path("reports/suites.md"))
    args = p.parse_args(argv)
    command = "python -m validation.benchmark.suites" + (" --mitsuba-data MITSUBA_DATA_DIR" if args.mitsuba_data else "")
    with tempfile.TemporaryDirectory(prefix="suites-bench-") as tmp:
        over = overhead()
        print("overhead", over, flush=True)
        cov = cover(args.mitsuba_data, Path(tmp)) if args.mitsuba_data else None
        print("coverage", cov, flush=True)
        cal_ = calibrate(Path(tmp))
        print("calibrate", cal_, flush=True)
    paper = on_paper(args.mitsuba_data, over[LOCAL])
    write_json(args.output.with_suffix(".json"), {"overhead": over, "calibrate": cal_, "coverage": cov, "paper": paper})
    print(write_text(args.output, markdown(over, cal_, cov, paper, command)))


if __name__ == "__main__":
    main()
