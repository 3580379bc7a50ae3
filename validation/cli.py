"""`validate check SCENE.xml [...]`: is a renderer right on these scenes? agree / disagree / inconclusive, with
exit codes for CI (0 all agree, 1 any disagrees, 3 any inconclusive and none disagrees, 2 usage or input error);
`validate calibrate`: the check's measured false-alarm rate and power (reports/calibration.md);
`validate stability`: the numerical stability suite (reports/stability.md);
`validate coverage DIR`: the tracer on Mitsuba's own scenes (reports/mitsuba_scenes.md);
`validate media DIR`: every media scene of Mitsuba's data against Mitsuba at two depths (reports/media.md);
`validate mitsuba-tests DIR`: Mitsuba's render tests with Mitsuba's protocol (reports/mitsuba_tests.md);
`validate report SCENE.xml [--quick] [--size N]`: run (or resume) the sweeps and write the report;
`validate reference SCENE.xml --max-depth D --size N`: render or load one cached Mitsuba reference;
`validate faults`: the table of injected faults the statistical test catches;
`validate improvements SCENE.xml`: filters, adaptive sampling and denoising, each measured;
`validate light-choice`: uniform against power-proportional choice of lights (reports/light_choice.md);
`validate snapshot DIR [--against OLD]`: a refactor's images, bit-identical or not."""
from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from dataclasses import replace
from pathlib import Path

# modules of the `validation` extra (pyproject.toml), by the package that installs them
EXTRA_MODULES = {"mitsuba": "mitsuba", "skimage": "scikit-image", "scipy": "scipy", "matplotlib": "matplotlib",
                 "plotly": "plotly"}
DEPTH_NOTE = ("max_depth counts path segments as Mitsuba does (2: direct light, -1: unbounded); "
              "the report's depth D is max_depth D + 2")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="validate", description="The tracer against Mitsuba 3 ground truth.",
                                epilog=DEPTH_NOTE)
    sub = p.add_subparsers(dest="command", required=True)
    _check_parser(sub)
    c = sub.add_parser("calibrate", help="write reports/calibration.md: the check's false-alarm rate on null "
                       "comparisons and its power on injected faults (cached renders; resumes)")
    c.add_argument("--output", "-o", type=Path, default=Path("reports/calibration.md"))
    c.add_argument("--repetitions", type=int, default=12, help="null comparisons per cell (default 12)")
    c.add_argument("--only", choices=("equivalence", "criterion"), help="re-measure one section, keeping the "
                   "others: equivalence (the check with a margin: false alarms, false 'equivalent', power) or "
                   "criterion (Mitsuba's render-test criterion beside the check; needs --mitsuba-data)")
    c.add_argument("--mitsuba-data", type=Path, metavar="DIR", help="a copy of mitsuba-renderer/mitsuba-data: "
                   "adds the section comparing Mitsuba's render-test criterion with the check, and its render-test scene "
                   "test_arealight_path.xml to the equivalence section")
    c.add_argument("--equivalence-repetitions", type=int, default=20, help="repetitions per scene and renderer "
                   "of the equivalence section (default 20)")
    c.add_argument("--render-test-repetitions", type=int, metavar="N", help="with --mitsuba-data: repetitions of "
                   "the equivalence section's render-test scene (default: --equivalence-repetitions)")
    c.add_argument("--criterion-repetitions", type=int, default=8, help="repetitions of the criterion section "
                   "(default 8)")
    _suite_options(c)
    v = sub.add_parser("coverage", help="write reports/mitsuba_scenes.md: which of Mitsuba's own scenes (a local "
                       "copy of mitsuba-renderer/mitsuba-data) the tracer renders and agrees on, what blocks the rest")
    v.add_argument("mitsuba_data", type=Path, metavar="MITSUBA_DATA_DIR")
    v.add_argument("--output", "-o", type=Path, default=Path("reports/mitsuba_scenes.md"))
    v.add_argument("--no-check", action="store_true", help="only load the scenes (no renders)")
    _suite_options(v)
    md = sub.add_parser("media", help="write reports/media.md: every media scene of a local copy of "
                        "mitsuba-renderer/mitsuba-data checked against Mitsuba at max_depth 3 and at its own depth")
    md.add_argument("mitsuba_data", type=Path, metavar="MITSUBA_DATA_DIR")
    md.add_argument("--output", "-o", type=Path, default=Path("reports/media.md"))
    _suite_options(md)
    t = sub.add_parser("mitsuba-tests", help="write reports/mitsuba_tests.md: Mitsuba's own render tests "
                       "(tests/scenes of a local copy of mitsuba-renderer/mitsuba-data) taken by the tracer, and by "
                       "Mitsuba, with Mitsuba's protocol; exit 1 if a test the tracer renders fails",
                       description="Mitsuba's render tests with Mitsuba's protocol (src/render/tests/test_renders.py): "
                       "spp = 2,000,000 // pixels, seed 0, a per-pixel z-test in XYZ against the reference and its "
                       "variance at Sidak's level, passed when 99.75% of the pixels accept. Renders are cached in "
                       ".cache/mitsuba_tests by content.")
    t.add_argument("mitsuba_data", type=Path, metavar="MITSUBA_DATA_DIR")
    t.add_argument("--output", "-o", type=Path, help="the report (default reports/mitsuba_tests.md; with --only, "
                   "none unless given)")
    t.add_argument("--only", action="append", metavar="TEXT", help="only the tests whose <folder>/<scene>.xml "
                   "contains TEXT (repeatable)")
    t.add_argument("--no-mitsuba", action="store_true", help="do not put Mitsuba's own render through the protocol")
    _suite_options(t)
    st = sub.add_parser("stability", help="write reports/stability.md: the numerical stability suite")
    st.add_argument("--output", "-o", type=Path, default=Path("reports/stability.md"))
    r = sub.add_parser("report", help="write reports/<scene>/README.md (resumes an interrupted sweep)")
    r.add_argument("scene", type=Path)
    r.add_argument("--quick", action="store_true", help="small images and short sweeps (a minute or two); "
                   "written to out/reports/<scene> unless --output is given")
    r.add_argument("--size", type=int, help="image size of the tables and images (default 600, quick 64)")
    r.add_argument("--sweep-size", type=int, help="image size of the convergence and depth sweeps (default 128)")
    r.add_argument("--output", "-o", type=Path, help="report folder (default reports/<scene>)")
    f = sub.add_parser("reference", help="render (or load from .cache/references) one Mitsuba reference")
    f.add_argument("scene", type=Path)
    f.add_argument("--max-depth", type=int, default=4)
    f.add_argument("--size", type=int, default=128)
    f.add_argument("--passes", type=int, default=16)
    f.add_argument("--spp", type=int, default=64, help="samples per pixel of each pass")
    b = sub.add_parser("bench", help="time the tracer and Mitsuba side by side: reports/performance.md")
    b.add_argument("--output", "-o", type=Path, default=Path("reports"))
    b.add_argument("--only", nargs="+", metavar="SECTION", help="run only these sections (side_by_side, tables, "
                   "ceiling, cold, specialisation, scaling, meshes, memory, scenes, instances), keeping the others from the "
                   "previous performance.json; the report says which run each section comes from. A folder among "
                   "them is taken as --mitsuba-data (`--only scenes DIR`)")
    b.add_argument("--mitsuba-data", type=Path, metavar="DIR", help="a copy of mitsuba-renderer/mitsuba-data: the "
                   "memory section measures its docs scenes too, the scenes section times every scene of it the "
                   "tracer loads")
    b.add_argument("--scenes", nargs="+", metavar="GLOB", help="scenes section: only the scenes whose name (as "
                   "the report writes it, e.g. 'docs/scenes/shape_*', 'mitsuba_scenes/*') matches one of these")
    b.add_argument("--scale", type=float, default=1.0, help="scenes section: every film's width and height "
                   "multiplied by this (default 1: the scene's own; the report labels a scaled run)")
    b.add_argument("--max-seconds", type=float, metavar="S", help="scenes section: start no scene after S seconds "
                   "of wall time (the report lists those left out)")
    b.add_argument("--runs", type=int, default=3, help="scenes section: timed runs of each renderer per scene "
                   "(default 3, after a warm-up run of each)")
    b.add_argument("--against", type=Path, metavar="TREE", help="section 'against' (run only when named, or when "
                   "this is given without --only): a checkout of another commit (git worktree add --detach TREE "
                   "COMMIT); the room's and the Cornell box's path renders by this checkout's tracer and TREE's, "
                   "A/B interleaved")
    b.add_argument("--rounds", type=int, default=5, help="section 'against': processes per checkout and scene, "
                   "the one that goes first alternating (default 5)")
    q = sub.add_parser("faults", help="write reports/faults.md: which injected faults the test catches at which spp")
    q.add_argument("--output", "-o", type=Path, default=Path("reports/faults.md"))
    n = sub.add_parser("snapshot", help="render every project scene small with one Dr.Jit thread into DIR (.npy); "
                       "with --against, exit 1 unless each image equals the earlier snapshot's to the bit")
    n.add_argument("folder", type=Path, metavar="DIR")
    n.add_argument("--against", type=Path, metavar="OLD", help="an earlier snapshot's folder")
    z = sub.add_parser("fuzz", help="write reports/fuzz.md: N seeded mutants of the project's scenes, meshes, images "
                       "and arguments through `tracer render`, each classified (exit 1 on a traceback, crash, hang, "
                       "lost output or malformed error)")
    z.add_argument("--n", type=int, default=1000, help="mutants (default 1000)")
    z.add_argument("--seed", type=int, default=0)
    z.add_argument("--workers", type=int, default=2, help="worker processes (default 2)")
    z.add_argument("--command", dest="run", choices=("render", "info"), default="render",
                   help="what each mutant runs: `tracer render` at 8 x 8, 1 spp (default), or `tracer info`")
    z.add_argument("--timeout", type=float, default=120.0, help="seconds a mutant may take before it is a hang")
    z.add_argument("--no-mitsuba", action="store_true", help="skip the cross-check of rendered mutants against "
                   "Mitsuba's loader")
    z.add_argument("--save", action="store_true", help="keep each finding (a failure, or a rendered mutant Mitsuba refuses) under tests/data/fuzz")
    z.add_argument("--output", "-o", type=Path, default=Path("reports/fuzz.md"))
    m = sub.add_parser("improvements", help="write reports/<scene>/improvements.md: filters, adaptive sampling, "
                       "denoising, each judged by its error against render time")
    m.add_argument("scene", type=Path)
    m.add_argument("--quick", action="store_true", help="small images (written to out/reports/<scene>)")
    m.add_argument("--only", action="append", choices=("filters", "adaptive", "denoise"),
                   help="run only this study (repeatable)")
    m.add_argument("--output", "-o", type=Path, help="report folder (default reports/<scene>)")
    c = sub.add_parser("light-choice", help="write reports/light_choice.md: the error of uniform and of "
                       "power-proportional light choice on the project's scenes with lights of unequal power, "
                       "at equal spp and equal time")
    c.add_argument("--quick", action="store_true", help="32 x 32, 4 seeds, reference at 1024 spp")
    c.add_argument("--scenes", nargs="+", type=Path, help="default: every project scene with lights of unequal power")
    c.add_argument("--output", "-o", type=Path, default=Path("reports/light_choice.md"))
    return p


EXIT_UNSUPPORTED = 77    # validation.verdict.renderers.EXIT_UNSUPPORTED (not imported here: the parser loads fast)
def _suite_options(p) -> None:
    """--scheduler and --workers: where a suite's units run (validation.suites.runner)."""
    p.add_argument("--scheduler", default="local", metavar="local|none|tcp://HOST:PORT", help="where the suite's "
                   "units run: a local Dask cluster (default), this process alone (none, for debugging), or the "
                   "Dask scheduler at this address (its workers need the project importable, no shared disk)")
    p.add_argument("--workers", type=int, metavar="N", help="--scheduler local: worker processes of one Dr.Jit "
                   "thread each (default: one per core, fewer if memory is short)")


def _session(args):
    from .suites.runner import check_scheduler, session

    check_scheduler(args.scheduler, args.workers)       # before anything runs
    return session(args.scheduler, args.workers)


EXIT_NOTE = ("exit status: 0 every check agrees (or is skipped: the renderer does not support the scene), 1 any "
             "disagrees, 4 a check timed out (--timeout) and none disagrees: the run is incomplete, 3 any is inconclusive "
             "(and none disagrees or timed out), 2 usage or input error")


def _check_parser(sub) -> None:
    from .verdict import protocol

    k = sub.add_parser("check", help="agree / disagree / inconclusive for a renderer against Mitsuba, with exit "
                       "codes for CI", epilog=EXIT_NOTE + ". " + DEPTH_NOTE)
    k.add_argument("scenes", type=Path, nargs="+", metavar="SCENE.xml")
    who = k.add_mutually_exclusive_group()
    who.add_argument("--estimator", action="append", choices=("path", "report"),
                     help="the tracer's estimator under test (repeatable; default path)")
    who.add_argument("--renderer", metavar="'CMD ...'", help="a built-in peer, cycles or luxcore (README: Peers), "
                     "or an external renderer: a command template with "
                     "the scene as {scene} (the file), {scene_resolved} (one self-contained Mitsuba XML with the "
                     "plan written in) or {scene_json} (neutral JSON with PLY meshes); {output} and {seed} (one "
                     "pass per call) or {outputs} and {seeds} (many, comma-separated); {spp}; {defines} (-D "
                     "name=value for the film size, max_depth, spp and every -D given here). Exit status "
                     f"{EXIT_UNSUPPORTED}: the scene is unsupported (reported as skipped). README: the renderer "
                     "contract")
    k.add_argument("--timeout", type=float, metavar="SECONDS", help="--renderer: the most one call may take; a call "
                   "that takes longer is stopped (with its children), that check is reported as timed out and the run goes on "
                   "with the next; exit 4 if none disagrees (default: no limit)")
    k.add_argument("--mistake", choices=("extra-bounce", "twosided-light", "default-filter", "dim-emission",
                                         "wide-fov"), help="--renderer cycles|luxcore: inject a conversion mistake "
                   "(to show the check catches it; reports/peers.md)")
    k.add_argument("--jobs", "-j", type=int, default=1, help="--renderer: calls run at once (a batch command with "
                   "{outputs}: the passes split into this many calls; default 1)")
    k.add_argument("--label", metavar="NAME", help="--renderer: its name in the verdict lines (default: the command)")
    k.add_argument("--cache", type=Path, metavar="DIR", help="where Mitsuba's references are cached (default "
                   "$VALIDATE_CACHE, else .cache/references in the working folder)")
    k.add_argument("--direct", "-N", type=int, default=16, help="report estimator: shadow rays per diffuse hit")
    k.add_argument("--indirect", "-M", type=int, default=8, help="report estimator: hemisphere rays per diffuse hit")
    depth = k.add_mutually_exclusive_group()
    depth.add_argument("--max-depth", type=int, action="append", help="Mitsuba's max_depth (repeatable; "
                       "default: the scene's)")
    depth.add_argument("--report-depth", type=int, action="append", help="the report's depth D = max_depth D + 2")
    k.add_argument("--spp", type=int, help=f"samples per pixel of one pass (default {protocol.SPP}; report "
                   f"estimator {protocol.REPORT_SPP} camera rays)")
    k.add_argument("--passes", type=int, default=protocol.PASSES, help=f"independent passes (default {protocol.PASSES})")
    k.add_argument("--max-spp", type=int, default=protocol.MAX_SPP, help="the most spp per pass an undecided check "
                   "may raise itself to, in at most 3 stages: with --margin, each stage sized from the one before; "
                   f"without, the geometric mean of --spp and this, then this (default {protocol.MAX_SPP})")
    k.add_argument("--seed", type=int, default=protocol.SEED_TEST)
    k.add_argument("--size", type=_size, default=protocol.SIZE, help="longer side of the image, the scene's aspect "
                   f"kept (default {protocol.SIZE}; 'native': the scene's own film; -D width=... height=... sets both)")
    k.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE",
                   help="override a <default> of the scene; width, height, max_depth and spp (per pass) work on any scene")
    k.add_argument("--alpha", type=float, default=protocol.ALPHA, help="family-wise false-positive rate of one "
                   f"check (default {protocol.ALPHA:g})")
    k.add_argument("--margin", type=_margin, nargs="+", metavar="PERCENT", help="test equivalence within this "
                   "margin of the image mean (e.g. 1%%) and, optionally, a second margin per block (default "
                   f"{protocol.BLOCK_MARGIN * 100:.0f}%% of a block's mean or of the image mean where the block is darker): "
                   "equivalent / disagree / inconclusive, raising the spp per pass until decided or --max-spp. "
                   f"Default: {protocol.CI_MARGIN * 100:.0f}%% where the environment variable CI is set (CI services set "
                   "it), else none; 'none': a test of difference only (agree / disagree)")
    k.add_argument("--json", type=Path, metavar="FILE", help="write the results as JSON")
    k.add_argument("--junit", type=Path, metavar="FILE", help="write JUnit XML (one test case per check)")
    k.add_argument("--output", "-o", type=Path, metavar="DIR", help="on disagree or inconclusive: ours, the "
                   "reference, their difference and the rejected blocks as images")


def _size(text: str) -> int | None:
    """--size: a number of pixels, or 'native' (None: the scene's own film size)."""
    if text == "native":
        return None
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of pixels or 'native', got '{text}'") from None


def _margin(text: str) -> float | None:
    """--margin: a percentage ('1%', '1') as a fraction; 'none' as None."""
    if text == "none":
        return None
    try:
        value = float(text.removesuffix("%")) / 100
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a percentage such as 1%, got '{text}'") from None
    if not 0 < value < 1:
        raise argparse.ArgumentTypeError(f"a margin must lie strictly between 0% and 100%, got '{text}'")
    return value


def _check(args) -> int:
    from tracer.cli import parse_defines
    from tracer.estimators import BranchingEstimator

    from .verdict.check import Settings, TimedOut, exit_code, prepare, run, write_json, write_junit
    from .verdict.peers import PEERS, PeerRenderer
    from .verdict.references import CACHE_VARIABLE
    from .verdict.renderers import ExternalRenderer, RendererTimeout, RendererUnsupported, TracerRenderer
    from .verdict.scenefile import ScenePlanError

    defines = parse_defines(args.defines)
    spp = args.spp
    if "spp" in defines:     # -D spp sets the samples per pass on any scene, like --spp
        if spp is not None:
            raise ScenePlanError("give the samples per pass once: --spp or -D spp, not both")
        spp = _integer_define(defines.pop("spp"))
    margin = _check_margin(args.margin)
    settings = Settings(passes=args.passes, spp=spp, seed=args.seed, alpha=args.alpha, size=args.size,
                        max_spp=args.max_spp, margin=margin)
    if args.cache is not None:
        os.environ[CACHE_VARIABLE] = str(args.cache)
    if args.renderer:
        if args.timeout is not None and not args.timeout > 0:
            raise ScenePlanError(f"--timeout must be a positive number of seconds, got {args.timeout}")
        if args.renderer in PEERS:
            if args.jobs != 1:
                raise ScenePlanError(f"--jobs goes with an external --renderer, not the built-in '{args.renderer}'")
            renderers = [PeerRenderer.named(args.renderer, args.timeout, args.mistake)]
        else:
            if args.mistake:
                raise ScenePlanError("--mistake goes with a built-in --renderer (cycles, luxcore)")
            renderers = [ExternalRenderer(args.renderer, args.timeout, args.label, args.jobs)]
    else:
        if args.label or args.jobs != 1:
            raise ScenePlanError("--label and --jobs go with --renderer")
        renderers = [TracerRenderer(e, args.direct, args.indirect) for e in dict.fromkeys(args.estimator or ["path"])]
    depths = ([BranchingEstimator.from_report_depth(d).max_depth for d in args.report_depth] if args.report_depth
              else (args.max_depth or [None]))
    for scene in args.scenes:
        if not scene.is_file():
            raise ScenePlanError(f"scene file '{scene}' not found")
    planned, skipped = [], []
    for scene in args.scenes:               # every refusal before any pass
        for renderer in renderers:
            for depth in depths:
                try:
                    planned.append((prepare(scene, renderer, depth, defines, settings), renderer))
                except RendererUnsupported as e:
                    skipped.append(_skip(scene, renderer, depth, e))
    results, timed_out = [], []
    for line in skipped:
        print(line.line(), flush=True)
    for scene_plan, renderer in planned:
        start = time.perf_counter()
        try:
            result = run(scene_plan, renderer, settings, args.output)
        except RendererUnsupported as e:
            skipped.append(_skip(scene_plan.path, renderer, scene_plan.max_depth, e))
            print(skipped[-1].line(), flush=True)
            continue
        except RendererTimeout as e:     # this check is lost, not the run: go on with the next
            timed_out.append(TimedOut(str(scene_plan.path), renderer.label, scene_plan.max_depth, str(e),
                                      time.perf_counter() - start))
            print(timed_out[-1].line(), flush=True)
            continue
        print(result.line(), flush=True)
        results.append(result)
    if args.json:
        write_json(results, args.json, skipped, timed_out)
    if args.junit:
        write_junit(results, args.junit, skipped, timed_out)
    code = exit_code(results, timed_out)
    print(f"validate check: {len(results) + len(skipped) + len(timed_out)} checks, " + ", ".join(
        f"{sum(r.verdict == v for r in results)} {v}" for v in ("agree", "equivalent", "disagree", "inconclusive")
        if v in ("disagree", "inconclusive") or any(r.verdict == v for r in results)) +
        (f", {len(timed_out)} timed out" if timed_out else "") +
        (f", {len(skipped)} skipped: unsupported" if skipped else "") + f" (exit {code})")
    return code


def _skip(scene, renderer, depth, e):
    from .verdict.check import Skipped

    return Skipped(str(scene), renderer.label, depth, str(e))


def _check_margin(values: list[float | None] | None):
    """The check's margin: --margin's, or in CI (the CI environment variable set) protocol.CI_MARGIN."""
    import os

    from .verdict import protocol
    from .verdict.scenefile import ScenePlanError
    from .verdict.stats import Margin

    if values is None:
        if not os.environ.get("CI"):
            return None
        print(f"validate check: CI is set: equivalence within --margin {protocol.CI_MARGIN:.0%} (--margin none: a "
              "test of difference only)", flush=True)
        values = [protocol.CI_MARGIN]
    if None in values:
        if len(values) > 1:
            raise ScenePlanError("--margin none takes no second value")
        return None
    if len(values) > 2:
        raise ScenePlanError("--margin takes one or two percentages: the image mean's and the blocks'")
    return Margin(values[0], values[1] if len(values) > 1 else protocol.BLOCK_MARGIN)


def _integer_define(text: str) -> int:
    from .verdict.scenefile import ScenePlanError

    try:
        return int(text)
    except ValueError:
        raise ScenePlanError(f"-D spp={text}: expected an integer") from None


def _interrupted(e: BaseException | None) -> bool:
    """Whether `e` or an exception it was raised from is a KeyboardInterrupt (Dr.Jit wraps those raised
    inside its loops in a RuntimeError)."""
    while e is not None:
        if isinstance(e, KeyboardInterrupt):
            return True
        e = e.__cause__ or e.__context__
    return False


def _command_line() -> str:
    """This run's command, as a report quotes it."""
    return "validate " + " ".join(shlex.quote(a) for a in sys.argv[1:])


def _improvements(args) -> None:
    from .studies.improvements import generate

    out = args.output or (Path("out/reports") if args.quick else Path("reports")) / args.scene.stem
    print(generate(args.scene, out, args.quick, args.only, _command_line()))


def _light_choice(args) -> None:
    from .studies.light_choice import run

    print(run(args.scenes, args.output, args.quick, _command_line()))


def _config(args):
    from .reports.scene_report import Config

    config = Config.quick() if args.quick else Config()
    if args.size:
        config = replace(config, size=args.size)
    if args.sweep_size:
        config = replace(config, sweep_size=args.sweep_size)
    return config


def _report(args) -> None:
    from .reports.scene_report import generate

    out = args.output or (Path("out/reports") if args.quick else Path("reports")) / args.scene.stem
    print(generate(args.scene, out, _config(args), _command_line()))


def _reference(args) -> None:
    from .verdict.references import reference

    ref = reference(args.scene, args.max_depth, args.size, args.passes, args.spp)
    print(f"{args.scene.stem} max_depth {args.max_depth}, {args.size} px, {ref.spp} spp: mean radiance "
          f"{ref.mean.mean():.4f}, rendered in {ref.seconds:.1f} s (key {ref.key})")


def _snapshot(args) -> int:
    from .verdict.scenefile import ScenePlanError
    from .suites.snapshot import compare, write

    if args.against is not None and not any(args.against.glob("*.npy")):
        raise ScenePlanError(f"'{args.against}' holds no snapshot (.npy images)")
    names = write(args.folder)
    print(f"{len(names)} images in {args.folder}")
    if args.against is None:
        return 0
    differences = compare(args.folder, args.against)
    for line in differences:
        print(line)
    print(f"{len(names) - len(differences)} of {len(names)} bit-identical to {args.against}" if differences
          else f"all {len(names)} bit-identical to {args.against}")
    return 1 if differences else 0


COMMANDS = {"report": "_report", "reference": "_reference", "improvements": "_improvements"}


def _run(args) -> int:
    if args.command == "check":
        return _check(args)
    if args.command == "calibrate":
        from .suites import calibration_equivalence, mitsuba_criterion
        from .suites.calibration import report
        from .verdict.scenefile import ScenePlanError

        if args.only == "criterion" and args.mitsuba_data is None:
            raise ScenePlanError("--only criterion needs --mitsuba-data DIR (a copy of mitsuba-renderer/mitsuba-data)")
        if args.only is None:
            with _session(args) as runner:
                report(args.output, args.repetitions, runner)
        if args.only in (None, "equivalence"):
            calibration_equivalence.update(args.output, args.equivalence_repetitions, args.mitsuba_data,
                                           args.render_test_repetitions)
        if args.mitsuba_data is not None and args.only in (None, "criterion"):
            mitsuba_criterion.update(args.output, args.mitsuba_data, args.criterion_repetitions)
        print(args.output)
        return 0
    if args.command == "coverage":
        from .suites.coverage import FOLDERS, report
        from .reports.provenance import command_line
        from .verdict.scenefile import ScenePlanError

        if not any((args.mitsuba_data / f).is_dir() for f in FOLDERS):
            raise ScenePlanError(f"'{args.mitsuba_data}' holds none of {', '.join(FOLDERS)}: expected a copy of "
                                 "mitsuba-renderer/mitsuba-data")
        with _session(args) as runner:
            print(report(args.mitsuba_data, args.output, command_line(args.argv, args.mitsuba_data), not args.no_check,
                         runner))
        return 0
    if args.command == "media":
        from .suites.media import MEDIA_FOLDER, report
        from .reports.provenance import command_line
        from .verdict.scenefile import ScenePlanError

        if not (args.mitsuba_data / MEDIA_FOLDER).is_dir():
            raise ScenePlanError(f"'{args.mitsuba_data}' has no {MEDIA_FOLDER} folder: expected a copy of "
                                 "mitsuba-renderer/mitsuba-data")
        with _session(args) as runner:
            print(report(args.mitsuba_data, args.output, command_line(args.argv, args.mitsuba_data), runner))
        return 0
    if args.command == "mitsuba-tests":
        from .suites.mitsuba_tests import SCENES, report
        from .reports.provenance import command_line
        from .verdict.scenefile import ScenePlanError

        if not (args.mitsuba_data / SCENES).is_dir():
            raise ScenePlanError(f"'{args.mitsuba_data}' has no {SCENES} folder: expected a copy of "
                                 "mitsuba-renderer/mitsuba-data")
        output = args.output or (None if args.only else Path("reports/mitsuba_tests.md"))
        with _session(args) as runner:
            return report(args.mitsuba_data, output, command_line(args.argv, args.mitsuba_data), args.only,
                          not args.no_mitsuba, runner=runner)
    if args.command == "stability":
        from .suites.stability import main as stability

        return stability(["--report", str(args.output)])
    if args.command == "bench":
        from .benchmark.bench import run

        only, data = args.only, args.mitsuba_data
        if only and any(Path(x).is_dir() for x in only):
            data = data or next(Path(x) for x in only if Path(x).is_dir())
            only = [x for x in only if not Path(x).is_dir()]
        if args.scale <= 0 or args.runs < 1 or args.rounds < 1:
            print("validate bench: --scale must be positive, --runs and --rounds at least 1", file=sys.stderr)
            return 2
        if args.against and not only:
            only = ["against"]
        options = {"globs": args.scenes, "scale": args.scale, "max_seconds": args.max_seconds, "runs": args.runs}
        against = (args.against, args.rounds) if args.against else None
        print(run(args.output, only, data, options, against))
        return 0
    if args.command == "snapshot":
        return _snapshot(args)
    if args.command == "fuzz":
        from .suites.fuzz import command_line

        return command_line(args, _command_line())
    if args.command == "light-choice":
        from .verdict.scenefile import ScenePlanError

        for path in args.scenes or []:
            if not path.is_file():
                raise ScenePlanError(f"scene file '{path}' not found")
        _light_choice(args)
        return 0
    if args.command == "faults":
        from .suites.power import table

        print(table(args.output))
        return 0
    from .verdict.scenefile import ScenePlanError

    if not args.scene.is_file():
        raise ScenePlanError(f"scene file '{args.scene}' not found")
    for name, value, low in (("size", getattr(args, "size", None), 8), ("sweep-size", getattr(args, "sweep_size", None), 8),
                             ("spp", getattr(args, "spp", None), 1), ("passes", getattr(args, "passes", None), 2)):
        if value is not None and value < low:
            raise ScenePlanError(f"--{name} must be at least {low}, got {value}")
    globals()[COMMANDS[args.command]](args)
    return 0


def main(argv: list[str] | None = None) -> int:
    """Runs a command: user errors in one line (exit 2), an interruption as such (exit 130), a bug with its
    traceback."""
    from tracer.errors import UserError
    from tracer.scene import SceneError

    args = _parser().parse_args(argv)
    args.argv = sys.argv[1:] if argv is None else list(argv)
    try:
        return _run(args)
    except BaseException as e:
        if _interrupted(e):
            resume = "; run the same command again to resume" if args.command in COMMANDS else ""
            print(f"validate: interrupted{resume}", file=sys.stderr)
            return 130
        if isinstance(e, (UserError, SceneError)):
            print(f"validate: error: {e}", file=sys.stderr)
            return 2
        if isinstance(e, ModuleNotFoundError) and (e.name or "").split(".")[0] in EXTRA_MODULES:
            print(f"validate: error: the harness needs {EXTRA_MODULES[e.name.split('.')[0]]}, part of the validation "
                  "extra: pip install 'tracer[validation]' (or: make setup)", file=sys.stderr)
            return 2
        if isinstance(e, OSError) and e.filename:
            print(f"validate: error: {e.filename}: {e.strerror}", file=sys.stderr)
            return 1
        if isinstance(e, Exception):
            print("validate: internal error (a bug in the harness; the traceback follows)", file=sys.stderr)
        raise


if __name__ == "__main__":
    sys.exit(main())
