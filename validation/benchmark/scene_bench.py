"""`validate bench --only scenes`: the tracer against Mitsuba on every scene the tracer renders, whole process.

The scenes: the project's own (mitsuba_scenes/*.xml), the Cornell box with its light cut into 16 x 16
rectangles (generated: a scene of many emitters), and, given a copy of mitsuba-renderer/mitsuba-data,
every scene of its docs/scenes, tests/scenes and scenes folders (validation.coverage.FOLDERS) that the
tracer loads. Each at its own resolution, spp and depth: `tracer render SCENE` against `mitsuba -m
llvm_ad_rgb SCENE`, each run a fresh process timed from start to exit (loading, BVH, compilation,
rendering, writing the EXR), the tracer's modules compiled to bytecode beforehand (as an installed package's
are). Per scene a warm-up run of each (filling Dr.Jit's kernel caches and the tracer's on-disk BVH cache, as a
user's earlier render of the scene would), then RUNS timed runs of each,
interleaved (the first renderer alternating), and the ratio of the medians.

A shared machine seldom has time for all of them, so the set can be capped: `globs` (fnmatch patterns on
the scene's name as the report writes it), `max_seconds` (no scene started after that much wall time; the
report lists those left out) and `scale` (every film's width and height multiplied by it: the report
labels such a run, whose timings weigh compilation more than a full-size run does).
"""
from __future__ import annotations

import compileall
import fnmatch
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ..verdict.scene_variants import write_variant

ROOT = Path(__file__).resolve().parents[2]
PROJECT = ROOT / "mitsuba_scenes"
RUNS = 3                 # timed runs of each renderer per scene
RENDERERS = ("tracer", "Mitsuba")


GENERATED = ROOT / ".cache" / "bench"    # where the generated scenes are written


def generated() -> list[tuple[str, Path]]:
    """The scenes the bench generates: the Cornell box with its light cut into 16 x 16 rectangles."""
    path = tiled_light_cornell_box(GENERATED, 16)
    return [(f"generated/{path.name}", path)]


def tiled_light_cornell_box(folder: Path, n: int = 16) -> Path:
    """The Cornell box with its light cut into n x n rectangles of the same radiance (the same image in
    expectation): a scene of n^2 emitters."""
    tile = ('<shape type="rectangle"><transform name="to_world"><scale x="{sx}" y="{sy}"/>'
            '<translate x="{x}" y="{y}"/><rotate x="1" angle="90"/><translate y="0.99"/></transform>'
            '<bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>'
            '<emitter type="area"><rgb name="radiance" value="18.387, 13.9873, 6.75357"/></emitter></shape>')
    sx, sy = 0.23 / n, 0.19 / n
    tiles = "".join(tile.format(sx=sx, sy=sy, x=-0.23 + sx * (2 * i + 1), y=-0.19 + sy * (2 * j + 1))
                    for i in range(n) for j in range(n))
    return light_replaced(PROJECT / "cornell_box.xml", tiles, folder, f"cornell_box_{n}x{n}_lights")


def light_replaced(scene: Path, shapes: str, folder: Path, name: str) -> Path:
    """`scene` with its `<shape type="rectangle" id="light">` element replaced by the XML `shapes`, written
    into `folder` as `name`."""
    text = scene.read_text()
    start = text.index('<shape type="rectangle" id="light">')
    end = text.index("</shape>", start) + len("</shape>")
    return write_variant(scene, text[:start] + shapes + text[end:], folder, name)


def candidates(mitsuba_data: Path | None, globs: list[str] | None = None) -> list[tuple[str, Path]]:
    """(name, path) of every scene the tracer loads: the project's, the generated ones, then mitsuba-data's
    (named relative to its folder), in file order; only those matching `globs` (select) are loaded."""
    import tracer
    from tracer.errors import UserError

    from ..suites.coverage import has_sensor, scene_files

    paths = [(f"mitsuba_scenes/{p.name}", p) for p in sorted(PROJECT.glob("*.xml"))] + generated()
    if mitsuba_data is not None:
        paths += [(str(p.relative_to(mitsuba_data)), p) for p in scene_files(mitsuba_data)]
    out = []
    for name, path in select(paths, globs):
        try:
            tracer.load_scene(path)
        except (tracer.SceneError, UserError):
            continue
        if has_sensor(path):
            out.append((name, path))
    return out


def select(scenes: list[tuple[str, Path]], globs: list[str] | None) -> list[tuple[str, Path]]:
    """The scenes whose name matches one of `globs` (all without)."""
    if not globs:
        return scenes
    return [(n, p) for n, p in scenes if any(fnmatch.fnmatch(n, g) for g in globs)]


def _settings(path: Path, scale: float) -> tuple[int, int, int, int]:
    """The scene's film width and height (scaled), spp and max_depth, as the tracer reads them."""
    import tracer

    scene = tracer.load_scene(path)
    w, h = scene.camera.width, scene.camera.height
    if scale != 1:
        w, h = max(1, round(w * scale)), max(1, round(h * scale))
    return w, h, scene.spp, scene.max_depth


def _commands(path: Path, width: int, height: int, scale: float, tmp: Path) -> dict[str, list[str]]:
    """The two command lines; scaled, the tracer takes --width/--height and Mitsuba a copy of the scene's XML
    with its film resized (validation.scenefile), its resources found beside the original (-a)."""
    tracer = [sys.executable, "-m", "tracer.cli", "render", str(path), "-o", str(tmp / "t.exr"), "--no-png",
              "--quiet"]
    scene = path
    if scale != 1:
        from ..verdict.scenefile import resized_xml

        tracer += ["--width", str(width), "--height", str(height)]
        scene = tmp / "scene.xml"
        scene.write_text(resized_xml(path, width, height))
    mitsuba = [str(Path(sys.executable).parent / "mitsuba"), "-m", "llvm_ad_rgb", "-a", str(path.parent.resolve()),
               "-o", str(tmp / "m.exr"), str(scene)]
    return {"tracer": tracer, "Mitsuba": mitsuba}


def compile_tracer() -> None:
    """The tracer's modules compiled to bytecode, as an installed package's are, before whole-process runs:
    where the environment sets PYTHONDONTWRITEBYTECODE, every run would else compile them anew (0.1-0.2 s of
    CPU a process)."""
    compileall.compile_dir(str(ROOT / "tracer"), quiet=1)


def _timed(command: list[str], env: dict) -> tuple[float, float, str]:
    """Wall seconds and CPU seconds (user + system, all its threads) of the command in a fresh process, and
    its error ('' if it exited 0). The CPU seconds are the steadier figure on a shared machine: other work
    stretches a process's wall time more than the work it does."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    run = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    error = "" if run.returncode == 0 else (run.stderr.strip().splitlines() or [f"exit {run.returncode}"])[-1][:200]
    return seconds, cpu, error


def measure_scene(path: Path, scale: float, runs: int, progress) -> dict:
    """One scene: a warm-up run of each renderer, then `runs` timed runs of each, interleaved."""
    width, height, spp, depth = _settings(path, scale)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")   # as the tracer command runs (tracer.cli.main)
    row = {"width": width, "height": height, "spp": spp, "max_depth": depth}
    with tempfile.TemporaryDirectory() as tmp:
        commands = _commands(path, width, height, scale, Path(tmp))
        for name in RENDERERS:
            seconds, _, error = _timed(commands[name], env)
            row[name] = {"warm_up": seconds, "seconds": [], "cpu_seconds": [], "error": error}
        for k in range(runs):
            for name in RENDERERS[k % 2:] + RENDERERS[:k % 2]:   # each renderer first in turn
                if row[name]["error"]:
                    continue
                progress(f"{path.name}: {name}, run {k + 1} of {runs}")
                seconds, cpu, error = _timed(commands[name], env)
                row[name]["seconds"].append(seconds)
                row[name]["cpu_seconds"].append(cpu)
                row[name]["error"] = error
    for name in RENDERERS:
        x = row[name]
        ok = x["seconds"] and not x["error"]
        x["median"] = statistics.median(x["seconds"]) if ok else None
        x["cpu_median"] = statistics.median(x["cpu_seconds"]) if ok else None
    if row["tracer"]["median"] and row["Mitsuba"]["median"]:
        row["ratio"] = row["tracer"]["median"] / row["Mitsuba"]["median"]
        row["cpu_ratio"] = row["tracer"]["cpu_median"] / row["Mitsuba"]["cpu_median"]
    return row


def scenes(progress, mitsuba_data: Path | None = None, globs: list[str] | None = None, scale: float = 1.0,
           max_seconds: float | None = None, runs: int = RUNS) -> dict:
    """The section's results: per scene its settings, each renderer's runs and median, and their ratio."""
    chosen = candidates(mitsuba_data, globs)
    compile_tracer()
    start = time.perf_counter()
    rows, skipped = {}, []
    for i, (name, path) in enumerate(chosen):
        if max_seconds is not None and time.perf_counter() - start > max_seconds:
            skipped = [n for n, _ in chosen[i:]]
            break
        progress(f"scenes: {name} ({i + 1} of {len(chosen)})")
        rows[name] = measure_scene(path, scale, runs, progress)
    return {"rows": rows, "skipped": skipped, "globs": globs or [], "scale": scale, "max_seconds": max_seconds,
            "runs": runs, "docs": mitsuba_data is not None}


def summary(section: dict, key: str = "ratio") -> tuple[float, str, float] | None:
    """(median ratio, worst scene, its ratio) over the scenes both renderers rendered; None if none did.
    `key`: "ratio" (wall seconds) or "cpu_ratio" (CPU seconds)."""
    ratios = {n: r[key] for n, r in section["rows"].items() if key in r}
    if not ratios:
        return None
    worst = max(ratios, key=ratios.get)
    return statistics.median(ratios.values()), worst, ratios[worst]


def markdown(section: dict, plot: str | None) -> list[str]:
    """The section of reports/performance.md: how the run was capped, the table, the median and the worst."""
    rows, scale = section["rows"], section["scale"]
    sources = "the project's scenes, the Cornell box with its light cut into 16 x 16 rectangles" + (" and every scene of `mitsuba-renderer/mitsuba-data` the tracer loads"
                                        if section["docs"] else " (mitsuba-data not given)")
    caps = []
    if section["globs"]:
        caps.append("only the scenes matching " + ", ".join(f"`{g}`" for g in section["globs"]))
    if scale != 1:
        caps.append(f"**every film scaled by {scale:g}** (width and height; spp and depth the scene's own): "
                    "compilation weighs more than at full size")
    if section["skipped"]:
        caps.append(f"stopped after {section['max_seconds']:g} s of wall time: {len(section['skipped'])} scenes "
                    "not measured (" + ", ".join(f"`{n}`" for n in section["skipped"]) + ")")
    lines = ["## Every scene: whole process, the tracer against Mitsuba", "",
             f"{sources[0].upper() + sources[1:]}, each at its own resolution, spp and max_depth: `tracer render SCENE` "
             "against `mitsuba -m llvm_ad_rgb SCENE`, each run a fresh process timed from start to exit (loading, "
             "BVH, kernel compilation, rendering, writing the EXR), the tracer's modules compiled to bytecode beforehand "
             "(as an installed package's are). Per scene a warm-up run of each (filling Dr.Jit's "
             f"kernel caches and the tracer's on-disk BVH cache), then {section['runs']} timed "
             f"run{'s' if section['runs'] > 1 else ''} of each, "
             "interleaved, the first renderer alternating; medians. Ratio: the tracer's median over Mitsuba's "
             "(below 1: the tracer is faster); CPU ratio: the same for the processes' CPU seconds (user and "
             "system, all threads), steadier than wall time when other work shares the machine.", ""]
    if caps:
        lines += ["This run: " + "; ".join(caps) + ".", ""]
    lines += ["| scene | size | spp | max_depth | tracer [s] | Mitsuba [s] | ratio | CPU ratio |",
              "|---|---|---:|---:|---:|---:|---:|---:|"]
    for name, r in rows.items():
        cells = []
        for renderer in RENDERERS:
            x = r[renderer]
            cells.append(f"failed: {x['error']}" if x["error"] else
                         f"{x['median']:.2f} ({min(x['seconds']):.2f}–{max(x['seconds']):.2f})")
        ratio, cpu = (f"{r[k]:.2f}" if k in r else "–" for k in ("ratio", "cpu_ratio"))
        lines.append(f"| `{name}` | {r['width']} x {r['height']} | {r['spp']} | {r['max_depth']} | {cells[0]} | "
                     f"{cells[1]} | {ratio} | {cpu} |")
    found, cpu = summary(section), summary(section, "cpu_ratio")
    if found:
        median, worst, worst_ratio = found
        n = sum("ratio" in r for r in rows.values())
        lines += ["", f"Over {n} scenes: median ratio **{median:.2f}**, worst **{worst_ratio:.2f}** (`{worst}`)."
                  + (f" In CPU seconds: median **{cpu[0]:.2f}**, worst **{cpu[2]:.2f}** (`{cpu[1]}`)." if cpu else "")]
    if plot:
        lines += ["", f"![the tracer's whole-process time over Mitsuba's, per scene]({plot})"]
    return lines + [""]
