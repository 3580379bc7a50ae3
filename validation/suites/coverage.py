"""`validate coverage DIR`: the tracer on Mitsuba's own scenes, as they stand (a local copy of the public
`mitsuba-renderer/mitsuba-data` repository: its docs/scenes, tests/scenes and scenes folders).

For every scene file: does Mitsuba load it; does the tracer load it, or what it refuses (every refusal,
one line each); where both load it, `validate check`'s verdict for the tracer's path estimator. A file that
declares no sensor, in itself or what it includes, is an include fragment (a part of other scenes): reported
as such, not as refused. Then the plugins and properties ranked by the scenes they alone block. Paths in
messages are relative to the data's folder: the report names the data by its repository. Results are
computed first (reports/mitsuba_scenes.json), formatted second (reports/mitsuba_scenes.md). Scene files are
read, never copied: the repository states no licence.
"""
from __future__ import annotations

import glob
import re
import time
from collections import Counter
from contextlib import nullcontext
from dataclasses import asdict, dataclass, field
from pathlib import Path

from ..reports.provenance import environment, relative_to, write_json, write_text
from ..verdict.scenefile import ScenePlanError, _parse, files_digest
from .runner import NONE, Runner, Unit, session

FOLDERS = ("docs/scenes", "tests/scenes", "scenes")
SPP = 32           # per pass: a check of Mitsuba's scenes at 16 x 32 spp, escalated up to MAX_SPP
MAX_SPP = 128


@dataclass
class SceneOutcome:
    scene: str                       # relative to the mitsuba-data folder
    mitsuba: str                     # "loads" or Mitsuba's message
    tracer: str                      # "loads", "refused" or "fragment" (no sensor: a part of other scenes)
    refusals: list[str] = field(default_factory=list)   # the tracer's refusal lines, file and line stripped
    verdict: str = ""                # agree | disagree | inconclusive | error: ... (both load)
    line: str = ""                   # the check's line
    seconds: float = 0.0


def scene_files(root: Path) -> list[Path]:
    return sorted(p for d in FOLDERS for p in (root / d).rglob("*.xml"))


def blocker(refusal: str) -> str:
    """A refusal line reduced to what it refuses: 'bsdf roughplastic', '<film> crop_width', ..."""
    m = re.search(r"unsupported (\w+) plugin '([^']+)'", refusal)
    if m:
        return f"{m.group(1)} {m.group(2)}"
    m = re.search(r"<(\w+)(?: type=\"([^\"]+)\")?(?: name=\"([^\"]+)\")?>: (.*)", refusal)
    if m:
        what = " ".join(x for x in m.group(1, 2, 3) if x)
        quoted_removed = re.sub(r"'[^']*'", "…", m.group(4))
        return f"{what}: {quoted_removed[:70]}"
    return refusal[:80]


def has_sensor(path: Path) -> bool:
    """Whether the scene file declares a sensor, in itself or in the files it includes (those found)."""
    try:
        root = _parse(path)
    except ScenePlanError:
        return "<sensor" in path.read_text(errors="replace")
    return root.find("sensor") is not None


def _mitsuba_loads(path: Path) -> str:
    from ..verdict.mitsuba_render import loading, mitsuba

    try:
        with loading():      # one plugin after another: the first error, Mitsuba's message, is the same every run
            mitsuba().load_file(str(path), parallel=False)
        return "loads"
    except Exception as e:   # Mitsuba raises RuntimeError, sometimes others; its message is the datum
        lines = [line.strip() for line in str(e).splitlines() if line.strip()]
        return (lines[-1] if lines else type(e).__name__)[:200]


def survey_scene(path: Path, root: Path, check_scenes: bool = True,
                 files: dict[str, bytes] | None = None) -> tuple[SceneOutcome, dict[str, bytes]]:
    """One scene (a unit of the suite, on a worker): does Mitsuba load it, does the tracer, and the check's
    verdict where both do; with the reference files it rendered (by name; `files`: those already cached)."""
    import tracer
    from tracer.errors import UserError

    from ..verdict.check import Settings, check
    from ..verdict.references import in_memory
    from ..verdict.renderers import TracerRenderer

    start = time.perf_counter()
    out = SceneOutcome(str(path.relative_to(root)), relative_to(_mitsuba_loads(path), root), "loads")
    try:
        tracer.load_scene(path)
    except (tracer.SceneError, UserError) as e:
        out.tracer = "refused" if has_sensor(path) else "fragment"
        out.refusals = [relative_to(re.sub(r"^.*?:\d+: ", "", line), root) for line in str(e).splitlines()]
    rendered = {}
    if out.tracer == "loads" and out.mitsuba == "loads" and check_scenes:
        with in_memory(files or {}) as rendered:
            try:
                result = check(path, TracerRenderer("path"), settings=Settings(spp=SPP, max_spp=MAX_SPP))
                out.verdict, out.line = result.verdict, relative_to(result.line(), root)
            except (tracer.SceneError, UserError) as e:
                out.verdict = f"error: {str(e).splitlines()[0][:150]}"
    out.seconds = time.perf_counter() - start
    return out, rendered


def survey(root: Path, check_scenes: bool = True, runner: Runner | None = None,
           paths: list[Path] | None = None) -> list[SceneOutcome]:
    """Every scene (or those of `paths`) as a unit of one suite on `runner` (default: in this process); the
    references the checks render are written to the cache here, as each scene's result arrives."""
    from ..verdict.references import cache_folder, write_files

    cache = cache_folder()
    paths = scene_files(root) if paths is None else paths

    def cached(path: Path) -> dict[str, bytes]:
        return {f.name: f.read_bytes() for f in cache.glob(f"{glob.escape(path.stem)}-d*.npz")} if check_scenes else {}

    units = [Unit(f"{p.relative_to(root)}-{files_digest(p)[:16]}-{'checked' if check_scenes else 'loaded'}",
                  survey_scene, (p, root, check_scenes, cached(p))) for p in paths]
    with (nullcontext(runner) if runner is not None else session(NONE)) as r:
        results = r.run(units, "Mitsuba's scenes", lambda unit, result: write_files(cache, result[1]))
    return [results[u.key][0] for u in units]


def markdown(outcomes: list[SceneOutcome], command: str, checked: bool = True) -> str:
    """The report; `checked`: whether the run checked the scenes both load against Mitsuba (else it only
    loaded them, `--no-check`, and says so)."""
    n = len(outcomes)
    fragments = [o for o in outcomes if o.tracer == "fragment"]
    mitsuba = [o for o in outcomes if o.mitsuba == "loads" and o.tracer != "fragment"]
    loads = [o for o in mitsuba if o.tracer == "loads"]
    agree = [o for o in loads if o.verdict == "agree"]
    sole = Counter()
    anywhere = Counter()
    for o in mitsuba:
        kinds = {blocker(r) for r in o.refusals}
        anywhere.update(kinds)
        if len(kinds) == 1:
            sole.update(kinds)
    lines = ["# The tracer on Mitsuba's own scenes", "",
             f"Generated by `{command}` on a local copy of `mitsuba-renderer/mitsuba-data` ({', '.join(FOLDERS)}). "
             + (f"Where both renderers load a scene, the tracer's path estimator is checked against Mitsuba with "
                f"`validate check`'s function at 32 pixels on the longer side, 16 passes of {SPP} spp (escalated up "
                f"to {MAX_SPP} when inconclusive)." if checked else
                "This run loaded the scenes only (`--no-check`): where both renderers load a scene, agreement with "
                "Mitsuba was **not checked** in this run."), "",
             "| | scenes |", "|---|---:|",
             f"| scene files | {n} |",
             f"| include fragments (no sensor: parts of other scenes; not counted below) | {len(fragments)} |",
             f"| Mitsuba loads (of the {n - len(fragments)} scenes) | {len(mitsuba)} |",
             f"| the tracer renders as they stand (of those Mitsuba loads) | {len(loads)} |"]
    lines += ([f"| ... and agrees with Mitsuba | {len(agree)} |",
               f"| ... disagrees | {sum(o.verdict == 'disagree' for o in loads)} |",
               f"| ... inconclusive | {sum(o.verdict == 'inconclusive' for o in loads)} |",
               f"| ... check failed to run | {sum(o.verdict.startswith('error') for o in loads)} |"] if checked else
              ["| ... checked against Mitsuba | not in this run (`--no-check`) |"])
    lines += ["", "## What blocks the rest", "",
             "Each refusal reduced to what it refuses; *alone*: the scenes it is the only blocker of (supporting it "
             "would unlock them), *in all*: the scenes that meet it.", "",
             "| blocker | alone | in all |", "|---|---:|---:|"]
    lines += [f"| {k} | {sole[k]} | {anywhere[k]} |" for k, _ in
              sorted(anywhere.items(), key=lambda kv: (-sole[kv[0]], -kv[1], kv[0]))[:40]]
    lines += ["", "## Every scene", "", "| scene | Mitsuba | tracer | verdict or first refusal |", "|---|---|---|---|"]
    for o in outcomes:
        detail = (f"{o.verdict}: {o.line.split(']: ', 1)[-1]}" if o.line else
                  "an include fragment: no sensor" if o.tracer == "fragment" else
                  o.verdict or (o.refusals[0] if o.refusals else "" if checked else "not checked"))
        lines.append(f"| {o.scene} | {'loads' if o.mitsuba == 'loads' else 'fails'} | {o.tracer} | "
                     f"{detail.replace('|', '/')[:160]} |")
    lines += ["", "## Machine and versions", ""] + environment(command)
    return "\n".join(lines) + "\n"


def report(root: Path, out: Path, command: str, check_scenes: bool = True, runner: Runner | None = None) -> Path:
    outcomes = survey(root, check_scenes, runner)
    write_json(out.with_suffix(".json"), [asdict(o) for o in outcomes])
    return write_text(out, markdown(outcomes, command, check_scenes))
