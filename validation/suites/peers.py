"""reports/peers.md: the built-in peers (Cycles, LuxCoreRender), the tracer and Mitsuba against itself, checked
against Mitsuba on the project's scenes at max_depth 2, 3 and the scene's own, and the conversion mistakes
injected into the peers' adapters, each of which the check must catch.

    python -m validation.suites.peers [--scenes mitsuba_scenes/*.xml] [--output reports/peers.md]

The investigation of the disagreements, below a marker line, is kept when the tables are rewritten.
Resumable: each check's result is kept in the JSON beside the report as soon as it is decided, and a run
skips the checks the JSON already holds (delete it to start again).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from ..verdict.check import Settings, prepare, run
from ..verdict.peers import PeerRenderer
from ..verdict.peers.support import MISTAKES
from ..verdict.renderers import ExternalRenderer, RendererError, RendererUnsupported, TracerRenderer
from ..verdict.scenefile import ScenePlanError

ROOT = Path(__file__).resolve().parents[2]
MISTAKE_SCENES = ("cornell_box.xml", "hexagon_room.xml")
MITSUBA_LABEL = "Mitsuba (examples/mitsuba_renderer.py)"
NUMPY_LABEL = "examples/numpy_renderer.py"
MARKER = "<!-- the investigation below is written by hand; --write keeps it -->"
DATA_PREFIX = "mitsuba-data: "
HEADER = """# Peers: Cycles, LuxCoreRender, the tracer and Mitsuba itself, checked against Mitsuba

`python -m validation.suites.peers` (this page: `--write`): `validate check` at its defaults (16 passes x 64 spp
per side, 32 px on the longer side, family-wise alpha 1e-3) on every scene of `mitsuba_scenes/` at max_depth 2, 3
and the scene's own, for Blender's Cycles (bpy 5.0.1) and LuxCoreRender (pyluxcore 2.11.2) through the built-in
adapters (`--renderer cycles|luxcore`, README "Peers"), the tracer's `path` estimator, and Mitsuba 3.9.1 against
itself (`examples/mitsuba_renderer.py` reading `{scene_resolved}`, a process per pass) and the NumPy example
(`examples/numpy_renderer.py` reading `{scene_json}`) at each scene's own max_depth; then Cycles and LuxCore on the
scenes of mitsuba-renderer/mitsuba-data they can express (`--data`). Times were measured on a 2-core machine
shared with other work: they compare nothing, they say what a check cost here.
"""


def renderers(timeout: float | None = None) -> dict:
    mitsuba = (f"{sys.executable} {ROOT / 'examples' / 'mitsuba_renderer.py'} {{scene_resolved}} -o {{output}} "
               "--spp {spp} --seed {seed}")
    numpy = (f"{sys.executable} {ROOT / 'examples' / 'numpy_renderer.py'} {{scene_json}} --spp {{spp}} "
             "--seeds {seeds} --outputs {outputs}")
    return {"cycles": PeerRenderer.named("cycles", timeout), "luxcore": PeerRenderer.named("luxcore", timeout),
            "tracer": TracerRenderer("path"),
            "mitsuba": ExternalRenderer(mitsuba, name=MITSUBA_LABEL, jobs=2),
            "numpy": ExternalRenderer(numpy, name=NUMPY_LABEL, jobs=2)}


def depths(scene: Path, own_only: bool = False) -> list[int | None]:
    from ..verdict.scenefile import plan

    own = plan(scene).max_depth
    return [None] if own_only else [2, 3] + ([None] if own not in (2, 3) else [])


def name(scene: Path, data: Path | None) -> str:
    """A project scene by its file name; a scene of mitsuba-renderer/mitsuba-data by DATA_PREFIX and its path there."""
    if data is not None and scene.resolve().is_relative_to(data.resolve()):
        return DATA_PREFIX + str(scene.resolve().relative_to(data.resolve()))
    return scene.name


def one(scene: Path, renderer, depth: int | None, settings: Settings, data: Path | None = None) -> dict:
    """One check's row: the verdict, the image mean's difference, the detectable bias, the time; or why not."""
    start = time.perf_counter()
    row = {"scene": name(scene, data), "renderer": renderer.label, "max_depth": depth}
    try:
        p = prepare(scene, renderer, depth, None, settings)
        row["max_depth"] = p.max_depth
        r = run(p, renderer, settings)
    except RendererUnsupported as e:
        return row | {"verdict": "skipped", "note": str(e)}
    except (ScenePlanError, RendererError) as e:
        return row | {"verdict": "error", "note": str(e), "seconds": time.perf_counter() - start}
    c = r.comparison
    return row | {"verdict": r.verdict, "mean": c.relative_mean_difference, "rejected": c.rejected,
                  "tests": c.tests + 3, "detectable": max(float(x) for x in c.detectable_image),
                  "detectable_block": c.detectable_block, "seconds": r.seconds, "spp": r.spp, "stage": r.stage,
                  "note": r.note}


def _cell(r: dict | None) -> str:
    if r is None:
        return ""
    if r["verdict"] == "skipped":
        return "skipped"
    if r["verdict"] == "error":
        return "stopped: over the time limit" if "--timeout" in r["note"] else "refused by the check"
    stage = f", stage {r['stage']}" if r.get("stage", 1) > 1 else ""
    return (f"{r['verdict']} ({r['mean']:+.1%}; {r['rejected']}/{r['tests']}; ≤{r['detectable']:.1%}; "
            f"{r['seconds']:.0f} s{stage})")


def _table(plain: list[dict], names: dict) -> list[str]:
    """The verdicts as a Markdown table: a row per scene and max_depth, a column per renderer."""
    out = ["| scene | max_depth | " + " | ".join(names.values()) + " |", "|---|---:|" + "---|" * len(names)]
    for scene in sorted({r["scene"] for r in plain}):
        for depth in sorted({r["max_depth"] for r in plain if r["scene"] == scene and r["max_depth"] is not None},
                            key=lambda d: (d < 0, d)):
            cells = [_cell(next((r for r in plain if r["scene"] == scene and r["renderer"] == label and (
                r["max_depth"] == depth or r["max_depth"] is None and depth not in (2, 3))), None)) for label in names]
            if any(c not in ("", "skipped") for c in cells):
                out.append(f"| {scene} | {depth} | " + " | ".join(cells) + " |")
    return out


def report(rows: list[dict], findings: str) -> str:
    """The Markdown report from the JSON rows; `findings`: the investigation of every disagreement."""
    names = {"cycles": "Cycles", "luxcore": "LuxCore", "tracer path": "tracer", MITSUBA_LABEL: "Mitsuba",
             NUMPY_LABEL: "NumPy example"}
    plain = [r for r in rows if "mistake" not in r["renderer"]]
    ours = [r for r in plain if not r["scene"].startswith(DATA_PREFIX)]
    data = [r for r in plain if r["scene"].startswith(DATA_PREFIX)]
    out = [HEADER, "## Verdicts", "",
           "Each cell: the verdict (image mean's difference from Mitsuba; tests rejected / tests; the bias of the "
           "image mean the check detects with 80% power, worst channel; the check's time). Scenes that a peer "
           "cannot express are listed after the table.", ""]
    out += _table(ours, names)
    if data:
        out += ["", "### The scenes of mitsuba-renderer/mitsuba-data the peers can express", "",
                "The same checks on every scene of that repository that the tracer's loader reads and Cycles or "
                "LuxCore can express (paths in that repository).", ""]
        out += _table(data, names)
    scenes = sorted({r["scene"] for r in plain})
    refused = sorted({(r["scene"], r["note"]) for r in plain
                      if r["verdict"] == "error" and "--timeout" not in r["note"]})
    if refused:
        out += ["", "Refused by the check itself (for every renderer): " + "; ".join(f"{s}: {n}" for s, n in refused)]
    out += ["", "### What the peers cannot express (skipped before any pass)", "", "| scene | reason |", "|---|---|"]
    for scene in scenes:
        reasons = sorted({r["note"] for r in plain if r["scene"] == scene and r["verdict"] == "skipped"})
        if reasons:
            out.append(f"| {scene} | {'; '.join(reasons)} |")
    mistakes = [r for r in rows if "mistake" in r["renderer"]]
    out += ["", "## Injected conversion mistakes", "",
            "The adapters with one mistake each (`validate check SCENE --renderer PEER --mistake NAME`), at the "
            "scene's own max_depth. Caught: the check disagrees.", "",
            "| peer | mistake | scene | verdict |", "|---|---|---|---|"]
    for r in mistakes:
        peer, mistake = r["renderer"].split(" (mistake: ")
        out.append(f"| {names.get(peer, peer)} | {mistake.rstrip(')')}: {MISTAKES[mistake.rstrip(')')]} | "
                   f"{r['scene']} | {_cell(r)} |")
    caught = sum(r["verdict"] == "disagree" for r in mistakes)
    out += ["", f"Caught: {caught} of {len(mistakes)}.", "", findings.strip(), ""]
    return "\n".join(out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m validation.suites.peers", description=__doc__)
    ap.add_argument("--scenes", nargs="+", type=Path, default=sorted((ROOT / "mitsuba_scenes").glob("*.xml")))
    ap.add_argument("--output", type=Path, default=ROOT / "reports" / "peers.md")
    ap.add_argument("--only", nargs="+", choices=("cycles", "luxcore", "tracer", "mitsuba", "numpy",
                                                        "mistakes"))
    ap.add_argument("--own-depth", action="store_true", help="only at each scene's own max_depth")
    ap.add_argument("--data", type=Path, help="the mitsuba-renderer/mitsuba-data checkout the --scenes come from "
                    "(their rows name them by their path there)")
    ap.add_argument("--timeout", type=float, default=900.0,
                    help="the most one peer's call may take (seconds; default 900): a check whose samples per pass "
                         "rise past what a peer renders in that time is stopped and reported as such")
    ap.add_argument("--write", action="store_true", help="only write the Markdown from the JSON")
    args = ap.parse_args(argv)
    store = args.output.with_suffix(".json")
    rows = json.loads(store.read_text()) if store.is_file() else []
    if args.write:
        old = args.output.read_text() if args.output.is_file() else ""
        findings = MARKER + old.split(MARKER, 1)[1] if MARKER in old else MARKER + "\n"
        args.output.write_text(report(rows, findings))
        return 0
    done = {(r["scene"], r["renderer"], r.get("asked_depth")) for r in rows}
    settings = Settings()
    todo = []
    for label, renderer in renderers(args.timeout).items():
        if args.only and label not in args.only:
            continue
        for scene in args.scenes:
            todo += [(scene, renderer, d) for d in depths(scene, args.own_depth)]
    if not args.only or "mistakes" in args.only:
        for peer in ("cycles", "luxcore"):
            for mistake in MISTAKES:
                todo += [(ROOT / "mitsuba_scenes" / s, PeerRenderer.named(peer, args.timeout, mistake), None)
                         for s in MISTAKE_SCENES]
    for scene, renderer, depth in todo:
        if (name(scene, args.data), renderer.label, depth) in done:
            continue
        row = one(scene, renderer, depth, settings, args.data) | {"asked_depth": depth}
        row["note"] = row.get("note", "").replace(f"{ROOT}/", "")        # paths relative to the repository
        if args.data is not None:
            row["note"] = row["note"].replace(f"{args.data.resolve()}/", "")
        print(json.dumps(row), flush=True)
        rows.append(row)
        store.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
