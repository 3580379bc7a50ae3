"""`validate media DIR`: every media scene of Mitsuba's own data (a local copy of the public
`mitsuba-renderer/mitsuba-data` repository) checked against Mitsuba at two depths (reports/media.md).

The scenes: every scene file of its docs/scenes, tests/scenes and scenes folders that declares a <medium>,
and the files of its render tests' participating_media folder. Each at DEPTHS: max_depth 3 (single and
double scattering, direct light through the media) and the scene's own (6 for the render tests, 64 for
the docs' subsurface scenes: multiple scattering). Each check is `validate check`'s (Welch's t-test per
4 x 4 block and channel, Bonferroni-corrected, family-wise false-positive rate validation.protocol.ALPHA;
escalated in stages when undecided) at SIZE pixels on the longer side, 16 passes of SPP spp up to MAX_SPP;
each verdict line states the bias it could have missed (its detectable image-mean bias at the check's
power). A scene the tracer refuses is listed with its refusal. Paths are relative to the data's folder.
Each outcome is kept in RESULTS as it arrives (an interrupted run resumes); results are computed first
(reports/media.json), formatted second (reports/media.md), with the causes of any disagreement found so far
(CAUSES)."""
from __future__ import annotations

import glob
import hashlib
import json
import re
import time
from contextlib import nullcontext
from dataclasses import asdict, dataclass
from pathlib import Path

from ..reports.provenance import environment, relative_to, write_json, write_text
from ..verdict.scenefile import files_digest
from .coverage import FOLDERS
from .runner import NONE, Runner, Unit, session

MEDIA_FOLDER = "tests/scenes/participating_media"
DEPTHS = (3, None)          # None: the scene's own max_depth
SIZE = 16
SPP = 32
MAX_SPP = 128
RESULTS = Path(".cache/media")   # each check's outcome, kept as it arrives: an interrupted run resumes

# What was found about a disagreement, by scene (relative to the data's folder); the report quotes it.
CAUSES: dict[str, str] = {}
# Sharper checks of the scenes whose agreement left the most room (the largest difference, the largest
# detectable bias), by scene: the command and its verdict lines, quoted by the report.
FOLLOW_UPS: dict[str, list[str]] = {
    f"{MEDIA_FOLDER}/test_homo_area_light_volpath.xml": [
        "validate check MITSUBA_DATA_DIR/tests/scenes/participating_media/test_homo_area_light_volpath.xml "
        "--max-depth 3 --size 16 --spp 256 --max-spp 256 --seed 4242",
        "agree        [tracer path, max_depth 3]: 0/51 tests rejected, worst block (2, 2) B p = 0.022, image mean "
        "-0.19%; detectable bias (80% power): image mean 2.4%/2.4%/2.4% (RGB), median block 5.8%; 16 x 256 spp vs "
        "Mitsuba 16 x 256 spp, 16 x 16, 50.4 s",
        "agree        [tracer path, max_depth 6] (the same command without --max-depth): 0/51 tests rejected, worst "
        "block (2, 0) R p = 0.029, image mean -0.22%; detectable bias (80% power): image mean 1.9%/1.9%/1.9% (RGB), "
        "median block 6%; 16 x 256 spp vs Mitsuba 16 x 256 spp, 16 x 16, 60.3 s"],
    f"{MEDIA_FOLDER}/test_homo_roughdielectric_spot_volpath.xml": [
        "validate check MITSUBA_DATA_DIR/tests/scenes/participating_media/test_homo_roughdielectric_spot_volpath.xml "
        "--max-depth 3 --size 16 --spp 256 --max-spp 256 --seed 4242",
        "agree        [tracer path, max_depth 3]: 0/51 tests rejected, worst block (0, 3) G p = 0.0067, image mean "
        "-0.04%; detectable bias (80% power): image mean 3.1%/2.9%/3.1% (RGB), median block 4.7%; 16 x 256 spp vs "
        "Mitsuba 16 x 256 spp, 16 x 16, 23.0 s",
        "agree        [tracer path, max_depth 16] (the same command without --max-depth): 0/51 tests rejected, worst "
        "block (0, 3) G p = 0.0069, image mean -0.05%; detectable bias (80% power): image mean 3%/2.9%/3% (RGB), "
        "median block 2.5%; 16 x 256 spp vs Mitsuba 16 x 256 spp, 16 x 16, 54.2 s"],
}


@dataclass
class MediaOutcome:
    scene: str                   # relative to the mitsuba-data folder
    max_depth: int | None        # the depth asked for (None: the scene's own)
    verdict: str                 # agree | disagree | inconclusive | refused | error: ...
    line: str = ""               # the check's line, or the tracer's first refusal
    depth: int | None = None     # the depth checked (the scene's own resolved)
    mean_difference: float = 0.0       # the tracer's image mean relative to Mitsuba's
    detectable: float = 0.0            # the image-mean bias the check detects at its power (largest channel)
    seconds: float = 0.0


def media_scenes(root: Path) -> list[Path]:
    """The scene files that declare a medium, and those of the render tests' media folder."""
    found = {p for d in FOLDERS for p in (root / d).rglob("*.xml")
             if "include" not in p.relative_to(root).parts and "<medium" in p.read_text(errors="replace")}
    found |= set((root / MEDIA_FOLDER).glob("*.xml"))
    return sorted(found)


def check_scene(path: Path, root: Path, max_depth: int | None, files: dict[str, bytes]) -> tuple[MediaOutcome, dict]:
    """One scene at one depth (a unit of the suite, on a worker), with the reference files it rendered."""
    import tracer
    from tracer.errors import UserError

    from ..verdict.check import Settings, check
    from ..verdict.references import in_memory
    from ..verdict.renderers import TracerRenderer

    start = time.perf_counter()
    out = MediaOutcome(str(path.relative_to(root)), max_depth, "")
    rendered: dict[str, bytes] = {}
    try:
        tracer.load_scene(path)
    except (tracer.SceneError, UserError) as e:
        out.verdict = "refused"
        out.line = relative_to(re.sub(r"^.*?:\d+: ", "", str(e).splitlines()[0]), root)
    if not out.verdict:
        with in_memory(files) as rendered:
            try:
                result = check(path, TracerRenderer("path"), max_depth=max_depth,
                               settings=Settings(size=SIZE, spp=SPP, max_spp=MAX_SPP))
                c = result.comparison
                out.verdict, out.line, out.depth = result.verdict, relative_to(result.line(), root), result.max_depth
                out.mean_difference = float(c.relative_mean_difference)
                out.detectable = float(max(c.detectable_image))
            except (tracer.SceneError, UserError) as e:
                out.verdict = f"error: {relative_to(str(e).splitlines()[0][:150], root)}"
    out.seconds = time.perf_counter() - start
    return out, rendered


def tracer_source() -> str:
    """A digest of the tracer's source files (read here: this process imports neither Dr.Jit nor Mitsuba)."""
    root, h = Path(__file__).resolve().parents[2] / "tracer", hashlib.sha256()
    for f in sorted(root.rglob("*.py")):
        h.update(f.relative_to(root).as_posix().encode() + f.read_bytes())
    return h.hexdigest()[:16]


def survey(root: Path, runner: Runner | None = None, paths: list[Path] | None = None) -> list[MediaOutcome]:
    """Every media scene (or those of `paths`) at every depth, as units of one suite on `runner` (default: in
    this process); the references rendered and each outcome are written here as the results arrive, and an
    outcome kept from an earlier run of the same scene files, settings and tracer source is reused."""
    from ..verdict.references import cache_folder, write_files

    cache, source = cache_folder(), tracer_source()
    paths = media_scenes(root) if paths is None else paths

    def cached(path: Path) -> dict[str, bytes]:
        return {f.name: f.read_bytes() for f in cache.glob(f"{glob.escape(path.stem)}-d*.npz")}

    def kept(unit: Unit) -> Path:
        return RESULTS / (hashlib.sha256(unit.key.encode()).hexdigest()[:24] + ".json")

    def arrived(unit: Unit, result) -> None:
        write_files(cache, result[1])
        write_json(kept(unit), asdict(result[0]))

    units = [Unit(f"media-{p.relative_to(root)}-{depth}-{files_digest(p)[:16]}-{SIZE}-{SPP}-{MAX_SPP}-{source}",
                  check_scene, (p, root, depth)) for p in paths for depth in DEPTHS]
    done = {u.key: MediaOutcome(**json.loads(kept(u).read_text())) for u in units if kept(u).is_file()}
    todo = [Unit(u.key, u.fn, u.args + (cached(u.args[0]),)) for u in units if u.key not in done]
    with (nullcontext(runner) if runner is not None else session(NONE)) as r:
        results = r.run(todo, "media scenes", arrived)
    return [done[u.key] if u.key in done else results[u.key][0] for u in units]


def _depth(o: MediaOutcome) -> str:
    own = "own" if o.max_depth is None else ""
    return f"{o.depth} ({own})" if own and o.depth is not None else own or str(o.max_depth)


def _verdict_line(o: MediaOutcome) -> str:
    """The check's line; for a scene not checked, its verdict, scene and reason in the same layout."""
    if o.verdict in ("refused",) or o.verdict.startswith("error"):
        depth = "the scene's max_depth" if o.max_depth is None else f"max_depth {o.max_depth}"
        return f"{o.verdict.split(':')[0]:<12} {o.scene} [{depth}]: {o.line or o.verdict}"
    return o.line


def markdown(outcomes: list[MediaOutcome], command: str) -> str:
    checked = [o for o in outcomes if o.verdict not in ("refused",) and not o.verdict.startswith("error")]
    counts = {v: sum(o.verdict == v for o in outcomes) for v in ("agree", "disagree", "inconclusive", "refused")}
    errors = sum(o.verdict.startswith("error") for o in outcomes)
    scenes = sorted({o.scene for o in outcomes})
    lines = ["# Participating media against Mitsuba", "",
             f"Generated by `{command}` on a local copy of `mitsuba-renderer/mitsuba-data`: every scene file that "
             f"declares a `<medium>` and every file of `{MEDIA_FOLDER}`, each at max_depth 3 and at the scene's own "
             f"max_depth, checked with `validate check`'s function (the tracer's `volpath` against Mitsuba's, "
             f"Welch's t-test per 4 x 4 block and channel, family-wise false-positive rate 1% per check) at {SIZE} "
             f"pixels on the longer side, 16 passes of {SPP} spp escalated up to {MAX_SPP} when undecided. "
             "*Detectable* is the image-mean bias (largest channel) the check would have detected at its power: "
             "an agreement rules out a bias of that size, not a smaller one. A scene's two depths are rendered "
             "from the same seeds, so their noise is correlated: two agreements are not two independent "
             "confirmations of the shared part of the image. The closed-form tests (a homogeneous "
             "slab's transmittance and single scattering, an infinite medium in a white furnace, the phase "
             "functions' chi-square) are tests/test_media.py and tests/test_phase_chi2.py.", "",
             "| | checks |", "|---|---:|",
             f"| scenes | {len(scenes)} |", f"| checks (scenes x 2 depths) | {len(outcomes)} |"]
    lines += [f"| {v} | {n} |" for v, n in counts.items()] + [f"| check failed to run | {errors} |"]
    if checked:
        worst = max(o.detectable for o in checked)
        lines += ["", f"The largest bias a check here could have missed: {worst:.1%} of the image mean."]
    lines += ["", "## Every check", "",
              "| scene | max_depth | verdict | image mean | detectable | seconds |", "|---|---|---|---:|---:|---:|"]
    for o in outcomes:
        diff = f"{o.mean_difference:+.2%}" if o in checked else ""
        det = f"{o.detectable:.1%}" if o in checked else ""
        lines.append(f"| {o.scene} | {_depth(o)} | {o.verdict.replace('|', '/')} | {diff} | {det} | {o.seconds:.0f} |")
    lines += ["", "## Verdict lines", "", "```"] + [_verdict_line(o) for o in outcomes] + ["```"]
    found = [o.scene for o in outcomes if o.verdict in ("disagree", "inconclusive") or o.verdict.startswith("error")]
    if found or CAUSES:
        lines += ["", "## Causes", ""]
        lines += [f"- {s}: {CAUSES.get(s, 'not yet found')}" for s in dict.fromkeys(found + list(CAUSES))]
    if FOLLOW_UPS:
        lines += ["", "## Follow-up checks", "",
                  "Run by hand after the suite, quoted here: the largest difference and the largest detectable bias "
                  "above, checked again with 8 times the samples and another seed (the tracer of a15e6f2):", ""]
        for scene, (cmd, *verdicts) in FOLLOW_UPS.items():
            lines += [f"- {scene}: `{cmd}`", "", "  ```"] + [f"  {v}" for v in verdicts] + ["  ```"]
    lines += ["", "## Machine and versions", ""] + environment(command)
    return "\n".join(lines) + "\n"


def report(root: Path, out: Path, command: str, runner: Runner | None = None) -> Path:
    outcomes = survey(root, runner)
    write_json(out.with_suffix(".json"), [asdict(o) for o in outcomes])
    return write_text(out, markdown(outcomes, command))
