"""`python -m validation.viewer index [REPORTS]` writes REPORTS/index.html (default: reports);
`python -m validation.viewer images OUT A.exr B.exr ...` writes OUT/index.html showing the EXRs, the
first two compared (their signed difference and relative error)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tracer.imageio import read_exr

from . import write_index, write_viewer


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m validation.viewer", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    index = sub.add_parser("index", help="write REPORTS/index.html listing every report")
    index.add_argument("reports", nargs="?", default="reports", type=Path)
    images = sub.add_parser("images", help="write OUT/index.html viewing EXR images, the first two compared")
    images.add_argument("out", type=Path)
    images.add_argument("exr", nargs="+", type=Path)
    args = parser.parse_args(argv)
    if args.command == "index":
        if not args.reports.is_dir():
            print(f"error: {args.reports} is not a folder", file=sys.stderr)
            return 1
        print(write_index(args.reports))
        return 0
    missing = [str(p) for p in args.exr if not p.is_file()]
    if missing:
        print(f"error: no such EXR file: {', '.join(missing)}", file=sys.stderr)
        return 1
    if len({p.stem for p in args.exr}) < len(args.exr):
        print("error: the EXR files' names (without .exr) must differ: they name the images", file=sys.stderr)
        return 1
    arrays = {}
    for path in args.exr:
        try:
            arrays[path.stem] = read_exr(path)
        except Exception as e:  # OpenEXR's errors name no common base class
            print(f"error: {path}: not an RGB OpenEXR file ({e})", file=sys.stderr)
            return 1
    sizes = {a.shape for a in arrays.values()}
    if len(sizes) > 1:
        print("error: the images differ in size: " + ", ".join(f"{k} {a.shape[1]}x{a.shape[0]}"
                                                              for k, a in arrays.items()), file=sys.stderr)
        return 1
    names = list(arrays)
    print(write_viewer(args.out, " vs ".join(names[:2]) if len(names) > 1 else names[0], arrays,
                       compare=(names[0], names[1]) if len(names) > 1 else None,
                       provenance={"files": ", ".join(f"`{p}`" for p in args.exr)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
