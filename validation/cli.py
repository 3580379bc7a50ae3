"""`validate report SCENE.xml [--quick] [--size N]`: run (or resume) the sweeps and write the report;
`validate reference SCENE.xml --max-depth D --size N`: render or load one cached Mitsuba reference;
`validate faults`: the table of injected faults the statistical test catches;
`validate improvements SCENE.xml`: filters, adaptive sampling and denoising, each measured."""
from __future__ import annotations

import argparse
import shlex
import sys
from dataclasses import replace
from pathlib import Path

DEPTH_NOTE = ("max_depth counts path segments as Mitsuba does (2: direct light, -1: unbounded); "
              "the report's depth D is max_depth D + 2")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="validate", description="The tracer against Mitsuba 3 ground truth.",
                                epilog=DEPTH_NOTE)
    sub = p.add_subparsers(dest="command", required=True)
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
    q = sub.add_parser("faults", help="write reports/faults.md: which injected faults the test catches at which spp")
    q.add_argument("--output", "-o", type=Path, default=Path("reports/faults.md"))
    m = sub.add_parser("improvements", help="write reports/<scene>/improvements.md: filters, adaptive sampling, "
                       "denoising, each judged by its error against render time")
    m.add_argument("scene", type=Path)
    m.add_argument("--quick", action="store_true", help="small images (written to out/reports/<scene>)")
    m.add_argument("--only", action="append", choices=("filters", "adaptive", "denoise"),
                   help="run only this study (repeatable)")
    m.add_argument("--output", "-o", type=Path, help="report folder (default reports/<scene>)")
    return p


def _improvements(args) -> None:
    from .improvements import generate

    out = args.output or (Path("out/reports") if args.quick else Path("reports")) / args.scene.stem
    command = "validate " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    print(generate(args.scene, out, args.quick, args.only, command))


def _config(args):
    from .report import Config

    config = Config.quick() if args.quick else Config()
    if args.size:
        config = replace(config, size=args.size)
    if args.sweep_size:
        config = replace(config, sweep_size=args.sweep_size)
    return config


def _report(args) -> None:
    from .report import generate

    out = args.output or (Path("out/reports") if args.quick else Path("reports")) / args.scene.stem
    command = "validate " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    print(generate(args.scene, out, _config(args), command))


def _reference(args) -> None:
    from .references import reference

    ref = reference(args.scene, args.max_depth, args.size, args.passes, args.spp)
    print(f"{args.scene.stem} max_depth {args.max_depth}, {args.size} px, {ref.spp} spp: mean radiance "
          f"{ref.mean.mean():.4f}, rendered in {ref.seconds:.1f} s (key {ref.key})")


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.command == "bench":
        from .benchmark import run

        print(run(args.output))
        return 0
    if args.command == "faults":
        from .power import table

        print(table(args.output))
        return 0
    if not args.scene.is_file():
        print(f"validate: error: scene file '{args.scene}' not found", file=sys.stderr)
        return 2
    for name, value in (("size", getattr(args, "size", None)), ("sweep-size", getattr(args, "sweep_size", None))):
        if value is not None and value < 8:
            print(f"validate: error: --{name} must be at least 8, got {value}", file=sys.stderr)
            return 2
    try:
        {"report": _report, "reference": _reference, "improvements": _improvements}[args.command](args)
    except KeyboardInterrupt:
        print("validate: interrupted; run the same command again to resume", file=sys.stderr)
        return 130
    except (ValueError, RuntimeError, OSError) as e:
        print(f"validate: error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
