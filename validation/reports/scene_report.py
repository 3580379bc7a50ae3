"""`reports/<scene>/README.md`: the report's tables reproduced and the tracer measured against Mitsuba.

Table 1: N = 8, 16, 64 at M = 8, report depth 2. Table 2: report depth 1, 2, 3 at N = 16, M = 8. Both
with one camera ray per pixel (the report's setting), timed, with RMSE and SSIM against Mitsuba.
Then error against render time (one curve per estimator, Mitsuba's `path` included), error against
depth, image panels, and the machine, versions and command that produced it all.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from . import convergence, plots
from ..verdict.check import REPORT_REFERENCE_SPP
from .provenance import environment, write_text
from ..verdict.references import Reference, reference
from .sweep import RunSpec, image_path, sweep

SWEEP_DEPTH = 4                       # max_depth of the convergence sweep: the report's depth 2
DEPTHS = (2, 3, 4, 5, 6, -1)          # depth sweep (max_depth); -1 is unbounded
REPORT_MAX_DEPTH = 5                  # the branching estimator is not swept beyond report depth 3


@dataclass(frozen=True)
class Config:
    size: int = 600           # tables and images (the report's 600 x 600)
    sweep_size: int = 128     # convergence and depth sweeps
    ref_passes: int = 16
    ref_spp: int = 32         # per pass, at `size`
    sweep_ref_spp: int = 256  # per pass, at `sweep_size`
    spp_max: int = 256        # path and Mitsuba convergence sweep: spp 1, 2, 4, ... spp_max
    report_spp_max: int = 8
    depth_spp: int = 64       # path and Mitsuba in the depth sweep
    passes: int = 8           # independent images per sweep run (for the check's test)

    @staticmethod
    def quick(size: int = 64) -> "Config":
        return Config(size=size, sweep_size=32, ref_spp=32, sweep_ref_spp=64, spp_max=64, report_spp_max=4,
                      depth_spp=16)


def table1(c: Config) -> list[RunSpec]:
    return [RunSpec("report", 4, 1, c.size, 1, n, 8) for n in (8, 16, 64)]


def table2(c: Config) -> list[RunSpec]:
    return [RunSpec("report", d + 2, 1, c.size, 1, 16, 8) for d in (1, 2, 3)]


def _powers(top: int) -> list[int]:
    return [2 ** k for k in range(int(np.log2(top)) + 1)]


def convergence_runs(c: Config) -> dict[str, list[RunSpec]]:
    runs = {e: [RunSpec(e, SWEEP_DEPTH, s, c.sweep_size, c.passes) for s in _powers(c.spp_max)]
            for e in ("path", "mitsuba")}
    runs["report"] = [RunSpec("report", SWEEP_DEPTH, s, c.sweep_size, c.passes, 16, 8)
                      for s in _powers(c.report_spp_max)]
    return runs


def depth_runs(c: Config) -> dict[str, list[RunSpec]]:
    runs = {e: [RunSpec(e, d, c.depth_spp, c.sweep_size, c.passes) for d in DEPTHS] for e in ("path", "mitsuba")}
    runs["report"] = [RunSpec("report", d, 1, c.sweep_size, c.passes, 16, 8)
                      for d in DEPTHS if 2 <= d <= REPORT_MAX_DEPTH]
    return runs


def _fmt(x: float, digits: int = 4) -> str:
    return f"{x:.{digits}g}"


def _table(rows: list[dict], first: str, value) -> list[str]:
    lines = [f"| {first} | rays | time [s] (compile) | RMSE | rel. MSE | SSIM | bias (R, G, B) |",
             "|---|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        bias = ", ".join(f"{r[f'bias_{c}']:+.3g}" for c in "rgb")
        lines.append(f"| {value(r)} | {r['rays'] / 1e6:.1f} M | {r['seconds']:.2f} ({r['compile_seconds']:.2f}) "
                     f"| {_fmt(r['rmse'])} | {_fmt(r['rel_mse'])} | {r['ssim']:.4f} | {bias} |")
    return lines


def _convergence_section(by_key, runs, out: Path) -> list[str]:
    curves = {specs[0].label: [by_key[s.key] for s in specs] for specs in runs.values()}
    fits = {label: convergence.fit([r["render_seconds"] for r in rows], [r["rmse"] for r in rows])
            for label, rows in curves.items()}
    target = convergence.common_error({label: [r["rmse"] for r in rows] for label, rows in curves.items()})
    plots.error_vs_time(curves, fits, target, out / "error_vs_time.png")
    lines = ["![RMSE and SSIM against render time](error_vs_time.png)", "",
             f"Fitted slope of log RMSE against log render time (about -1/2 for an unbiased estimator), and the "
             f"render time the fit needs to reach the RMSE every curve reached ({_fmt(target)}):", "",
             "| estimator | spp swept | slope | seconds to RMSE " + _fmt(target) + " | check (runs that agree) |",
             "|---|---|---:|---:|---|"]
    for label, rows in curves.items():
        verdicts = ", ".join(f"{sum(r['test'] == v for r in rows)} {v}" for v in ("agree", "disagree", "inconclusive")
                             if any(r["test"] == v for r in rows))
        fit = fits[label]
        slope, reach = ((f"{fit.slope:.3f}", f"{fit.seconds_to_reach(target):.3g}") if fit.meaningful else
                        (f"({fit.slope:.2f}: no fit)", "–"))
        lines.append(f"| {label} | {rows[0]['spp']}..{rows[-1]['spp']} | {slope} | {reach} | {verdicts} |")
    lines += ["", "A slope is shown only where the fit means something: at least 3 points, r² ≥ 0.9 and a slope "
              "between -1 and 0 (an unbiased estimator's RMSE falls as time^-1/2; steeper slopes come from fixed "
              "costs or the reference's own noise, not from convergence)."]
    return lines


def _depth_section(by_key, runs, ref_at, c: Config, out: Path) -> list[str]:
    means = {d: float(ref_at(d, c.sweep_size).mean.mean()) for d in DEPTHS}
    finite = [d for d in DEPTHS if d > 0]
    total = means[-1] or float("inf")    # a black scene: every share 0
    share = [(means[d] - (means[d - 1] if d - 1 in means else 0.0)) / total for d in finite]
    labels = [str(d) for d in finite]
    curves = {specs[0].label: [(str(s.max_depth), by_key[s.key]["rmse"]) for s in specs] for specs in runs.values()}
    plots.error_vs_depth(labels, share, curves, out / "error_vs_depth.png")
    lines = ["![Error against depth](error_vs_depth.png)", "",
             "Mean radiance of Mitsuba's reference at each max_depth (the report's depth D = max_depth D + 2), as a "
             "share of the unbounded image; the first bar holds everything up to max_depth 2 (direct light):", "",
             "| max_depth | report depth | mean radiance | share of unbounded |", "|---:|---:|---:|---:|"]
    lines += [f"| {d} | {d - 2 if d > 0 else '-'} | {means[d]:.4f} | {means[d] / total:.1%} |" for d in DEPTHS]
    if means[-1] == 0:
        lines += ["", "Mitsuba's image is black at every depth: nothing to converge to, every RMSE is 0."]
    lines += ["", "RMSE, render time and the check's verdict per estimator and depth:", "",
              "| estimator | max_depth | spp | render s | RMSE | SSIM | test |", "|---|---:|---:|---:|---:|---:|---|"]
    for specs in runs.values():
        for s in specs:
            r = by_key[s.key]
            lines.append(f"| {s.label} | {s.max_depth} | {s.spp} | {r['render_seconds']:.3g} | {_fmt(r['rmse'])} "
                         f"| {r['ssim']:.4f} | {r['test']} ({r['rejected']} rejected) |")
    return lines


def _images_section(scene_file: Path, spec: RunSpec, ref: Reference, out: Path) -> list[str]:
    image = np.load(image_path(scene_file, spec))
    plots.side_by_side(image, ref.mean, f"tracer report, N={spec.direct}, M={spec.indirect}, spp=1", out / "images.png")
    return ["![tracer, reference, difference](images.png)", "",
            f"Left: the tracer's report estimator (N = {spec.direct}, M = {spec.indirect}, report depth "
            f"{spec.max_depth - 2}, one ray per pixel). Middle: Mitsuba's reference. Right: their signed difference "
            "(red: tracer brighter), colour scale clipped at the 99th percentile of its magnitude."]


def generate(scene_file: str | Path, out: Path | None = None, config: Config = Config(),
             command: str | None = None) -> Path:
    """Runs (or resumes) every run the report needs and writes `out/README.md` with its figures."""
    scene_file = Path(scene_file)
    out = out or Path("reports") / scene_file.stem
    out.mkdir(parents=True, exist_ok=True)

    @lru_cache(maxsize=None)
    def ref_at(max_depth: int, size: int) -> Reference:
        spp = config.ref_spp if size == config.size else config.sweep_ref_spp
        return reference(scene_file, max_depth, size, config.ref_passes, spp)

    conv, depth = convergence_runs(config), depth_runs(config)
    specs = table1(config) + table2(config) + [s for runs in (conv, depth) for ss in runs.values() for s in ss]
    by_key = {r["key"]: r for r in sweep(scene_file, specs, ref_at, out / "runs.csv")}
    main_ref = ref_at(SWEEP_DEPTH, config.size)
    lines = [f"# {scene_file.stem}: the tracer against Mitsuba 3", "",
             f"Generated by `{command or 'validate report ' + str(scene_file)}`. Depth is Mitsuba's `max_depth` "
             "(path segments; -1 unbounded); the report's depth D is max_depth D + 2. Ground truth: Mitsuba's `path` "
             f"on the same XML, {config.ref_passes} passes x {config.ref_spp} spp = {config.ref_passes * config.ref_spp} "
             f"spp at {config.size} x {config.size} (rendered in {main_ref.seconds:.0f} s at max_depth {SWEEP_DEPTH}), "
             f"{config.ref_passes * config.sweep_ref_spp} spp at {config.sweep_size} x {config.sweep_size} for the sweeps. "
             "RMSE and relative MSE are on linear radiance with the reference's own variance subtracted; SSIM on "
             "sRGB-encoded images. Times are wall-clock seconds per image; compile time (Dr.Jit kernel generation, "
             "or for Mitsuba a warm-up render's extra time) is shown apart.", "",
             f"## Table 1: shadow rays N at M = 8, report depth 2 (max_depth 4), {config.size} x {config.size}, spp 1", ""]
    lines += _table([by_key[s.key] for s in table1(config)], "N", lambda r: r["direct"])
    lines += ["", f"## Table 2: report depth D at N = 16, M = 8, {config.size} x {config.size}, spp 1", ""]
    lines += _table([by_key[s.key] for s in table2(config)], "D (max_depth)",
                    lambda r: f"{r['max_depth'] - 2} ({r['max_depth']})")
    lines += ["", "## Images", ""] + _images_section(scene_file, table1(config)[1], main_ref, out)
    lines += ["", f"## Error against run time (max_depth {SWEEP_DEPTH}, {config.sweep_size} x {config.sweep_size}, "
              f"{config.passes} images per point)", ""]
    lines += _convergence_section(by_key, conv, out)
    lines += ["", f"## Error against depth ({config.sweep_size} x {config.sweep_size})", ""]
    lines += _depth_section(by_key, depth, ref_at, config, out)
    checked = [r for r in by_key.values() if r["test"]]
    mitsuba_rows = [r for r in checked if r["estimator"] == "mitsuba"]
    tracer_rows = [r for r in checked if r["estimator"] != "mitsuba"]
    lines += ["", "The check: `validate check`'s test (validation/verdict/stats.py `compare`): each run's passes against as many "
              f"Mitsuba passes at the same samples per pass (the branching estimator: {REPORT_REFERENCE_SPP} per camera "
              "ray), Welch's test per 4 x 4 block and channel and on the image mean, Bonferroni-corrected, family-wise "
              "alpha 1e-3: a "
              "correct renderer disagrees in about one run in a thousand; the rates measured in this configuration "
              f"({config.passes} passes, {config.sweep_size} x {config.sweep_size}) are in reports/calibration.md. "
              f"Runs that disagree: the tracer's {_disagreeing(tracer_rows)}; Mitsuba against its own reference, "
              f"{_disagreeing(mitsuba_rows)}.", "",
              "## Machine and versions", ""] + environment(command or " ".join(sys.argv))
    lines += ["", "All rows: `runs.csv` / `runs.json` beside this file; the images as data, the plots and the "
              "tables in [index.html](index.html)."]
    text = "\n".join(lines) + "\n"
    write_text(out / "README.md", text)
    _viewer(out, scene_file, table1(config)[1], main_ref, conv, depth, by_key, text)
    return out / "README.md"


def _disagreeing(rows: list[dict]) -> str:
    """'k of n' runs whose check disagrees, with each one's smallest p."""
    bad = [r for r in rows if r["test"] == "disagree"]
    return f"{len(bad)} of {len(rows)}" + "".join(f" ({r['key']}: smallest p {float(r['min_p']):.2g})" for r in bad)


def _viewer(out: Path, scene_file: Path, spec: RunSpec, ref: Reference, conv: dict, depth: dict, by_key: dict,
            markdown: str) -> None:
    """index.html beside README.md: the tracer's image and the reference as data, error against time and
    depth as interactive plots, the Markdown's tables; and the index of every report."""
    from ..viewer import Plot, Series, write_index, write_viewer

    def series(runs: dict, x: str) -> list[Series]:
        return [Series(specs[0].label, [by_key[s.key][x] if x != "max_depth" else str(s.max_depth) for s in specs],
                       [by_key[s.key]["rmse"] for s in specs],
                       hover=[f"{s.spp} spp, {by_key[s.key]['test']}" for s in specs]) for specs in runs.values()]

    plots = [Plot("RMSE against render time", "render time per image [s]", "RMSE", series(conv, "render_seconds"),
                  log_x=True, log_y=True),
             Plot("RMSE against depth", "max_depth", "RMSE", series(depth, "max_depth"), log_y=True)]
    image = np.load(image_path(scene_file, spec))
    write_viewer(out, f"{scene_file.stem}: the tracer against Mitsuba 3",
                 {f"tracer report N={spec.direct} M={spec.indirect}": image, "Mitsuba": ref.mean},
                 compare=(f"tracer report N={spec.direct} M={spec.indirect}", "Mitsuba"), plots=plots,
                 tables=[("Tables", markdown)], intro=markdown.split("\n")[2])
    write_index(out.parent)
