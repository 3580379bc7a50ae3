"""`validate bench --against TREE`: this checkout's tracer against another's (an earlier commit checked out
elsewhere), the room's and the Cornell box's path renders, A/B interleaved.

Each round runs one child process per checkout and scene (bench.measure: a warm-up render, then
bench.REPEATS timed ones, render time without compilation), the checkout that goes first alternating from
round to round, so that a drift of the machine's speed weighs on both alike. Both checkouts' tracers are
driven by this checkout's benchmark code; each child reports which `tracer` package it imported. Each render
is timed in wall seconds and in the process's CPU seconds (all its threads): on a machine shared with other
work the CPU seconds move far less with the load than the wall time.
"""
from __future__ import annotations

import os
import statistics
import subprocess
from pathlib import Path

from .bench import ROOM, ROOT, _tracer, measure

CORNELL_BOX = ROOT / "mitsuba_scenes" / "cornell_box.xml"
# The configurations of the side-by-side section (room) and the specialisation section (Cornell box).
JOBS = {"hexagon_room": _tracer("path", scene=ROOM, spp=64, max_depth=5),
        "cornell_box": _tracer("path", scene=CORNELL_BOX, spp=16, max_depth=6)}


def _commit(tree: Path) -> str:
    """The tree's commit, and whether its tracer differs from it (a change not yet committed)."""
    run = subprocess.run(["git", "-C", str(tree), "log", "-1", "--format=%h"], capture_output=True, text=True)
    dirty = subprocess.run(["git", "-C", str(tree), "status", "--porcelain", "--", "tracer"], capture_output=True,
                           text=True).stdout.strip()
    return (run.stdout.strip() or "unknown") + (" with uncommitted changes" if dirty else "")


def against(progress, tree: Path, rounds: int) -> dict:
    """Render seconds of JOBS by this checkout ("this") and by `tree` ("other"), `rounds` children each,
    interleaved; per scene the medians over every timed render and their ratio this / other."""
    tree = Path(tree).resolve()
    if not (tree / "tracer" / "__init__.py").is_file():
        from tracer.errors import UserError

        raise UserError(f"validate bench: --against {tree}: no tracer package there (a checkout of this repository)")
    roots = {"this": None, "other": tree}
    rows: dict = {}
    for scene, job in JOBS.items():
        seconds: dict[str, list[float]] = {"this": [], "other": []}
        cpu: dict[str, list[float]] = {"this": [], "other": []}
        loads, rays = [os.getloadavg()[0]], 0
        for k in range(rounds):
            order = ["this", "other"] if k % 2 == 0 else ["other", "this"]
            for name in order:
                progress(f"against {tree.name}: {scene}, round {k + 1}, {name}")
                result = measure(job, tracer_root=roots[name])
                expected = (tree if roots[name] else ROOT) / "tracer"
                if Path(result["tracer_package"]) != expected.resolve():
                    raise RuntimeError(f"the {name} child imported {result['tracer_package']}, not {expected}")
                seconds[name] += result["seconds"]
                cpu[name] += result["cpu_seconds"]
                rays = result["rays"] if name == "this" else rays
            loads.append(os.getloadavg()[0])
        rows[scene] = {"seconds": seconds, "cpu_seconds": cpu, "rays": rays, "load": [min(loads), max(loads)]}
        for key, runs in (("wall", seconds), ("cpu", cpu)):
            this, other = statistics.median(runs["this"]), statistics.median(runs["other"])
            rows[scene][key] = {"this": this, "other": other, "ratio": this / other}
    return {"commits": {"this": _commit(ROOT), "other": _commit(tree)}, "rounds": rounds,
            "rows": rows}


def markdown(section: dict | None) -> list[str]:
    """The A/B section of the report (nothing where no run measured it)."""
    if not section:
        return []
    c = section["commits"]
    lines = ["## Against an earlier commit", "",
             f"The path renders of the room (600 x 600, 64 spp, max_depth 5) and the Cornell box (600 x 600, 16 spp, "
             f"max_depth 6) by this commit's tracer ({c['this']}) and by {c['other']}'s, both driven by this "
             f"commit's benchmark (`validate bench --against TREE --rounds {section['rounds']}`): "
             f"{section['rounds']} rounds, each a process per commit and scene (a warm-up render, then 3 timed), the "
             "commit that goes first alternating; render time without compilation, in wall seconds and in the "
             "process's CPU seconds (all its threads; the steadier figure on a loaded machine), medians over every "
             "timed render, the fastest and slowest in brackets. Ratio: this commit's over the earlier one's (below "
             "1: faster now).", "",
             f"| scene | timed in | {c['this']} [s] | {c['other']} [s] | ratio | renders (each) | load (1-min average) |",
             "|---|---|---:|---:|---:|---:|---|"]
    for scene, r in section["rows"].items():
        for key, label, runs in (("wall", "wall", r["seconds"]), ("cpu", "CPU", r["cpu_seconds"])):
            x = r[key]
            lines.append(f"| {scene} | {label} | {x['this']:.3f} ({min(runs['this']):.3f}–{max(runs['this']):.3f}) "
                         f"| {x['other']:.3f} ({min(runs['other']):.3f}–{max(runs['other']):.3f}) "
                         f"| **{x['ratio']:.3f}** | {len(runs['this'])} | {r['load'][0]:.1f}–{r['load'][1]:.1f} |")
    return lines + [""]
