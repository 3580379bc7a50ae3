"""`tracer render SCENE.xml --output OUT.exr ...` and `tracer info SCENE.xml`."""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .film import FILTERS, ReconstructionFilter
from .mitsuba_xml import load_scene
from .scene import SceneError

DEPTH_NOTE = ("max_depth counts path segments as Mitsuba does (1: lights seen directly, 2: direct light, "
              "-1: unbounded); the report's depth D is max_depth D + 2")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="tracer", description="A Monte Carlo ray tracer on Dr.Jit for Mitsuba 3 scenes.")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("render", help="render a scene to a linear EXR and an sRGB PNG beside it",
                       epilog=DEPTH_NOTE)
    r.add_argument("scene", type=Path)
    r.add_argument("--output", "-o", type=Path, required=True, help="output .exr (a .png is written beside it)")
    r.add_argument("--estimator", choices=("path", "report"), default="path")
    r.add_argument("--spp", type=int, help="samples (camera rays) per pixel; default: the scene's sample_count "
                   "for path, 1 for report (the report's one ray per pixel)")
    r.add_argument("--seed", type=int, help="random seed; default: the scene's sampler seed")
    depth = r.add_mutually_exclusive_group()
    depth.add_argument("--max-depth", type=int, help="Mitsuba's max_depth; default: the scene's integrator")
    depth.add_argument("--report-depth", type=int, help="the report's depth D (= max_depth D + 2)")
    r.add_argument("--direct", "-N", type=int, default=16, help="report estimator: shadow rays per diffuse hit (eq. 10)")
    r.add_argument("--indirect", "-M", type=int, default=8, help="report estimator: hemisphere rays per diffuse hit (eq. 11)")
    r.add_argument("--hemisphere", choices=("cosine", "uniform"), default="cosine",
                   help="report estimator: how eq. 11's directions are drawn")
    r.add_argument("--filter", choices=FILTERS, help="pixel reconstruction filter, replacing the scene's rfilter "
                   "(Mitsuba's defaults: gaussian stddev 0.5, tent radius 1)")
    r.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE",
                   help="override a <default> of the scene, like mitsuba -D")
    r.add_argument("--aovs", action="store_true", help="also write OUT.albedo.exr and OUT.normal.exr: albedo and "
                   "world-space normal (in [-1, 1]) of the first non-specular surface, through mirrors and glass")
    r.add_argument("--denoise", action="store_true", help="denoise with Intel Open Image Denoise, guided by the "
                   "AOVs: OUT.exr/.png are denoised, the noisy image is kept as OUT.noisy.exr, the AOVs are written")
    r.add_argument("--aov-spp", type=int, default=8, help="samples per pixel of the AOVs (default 8)")
    r.add_argument("--adaptive", action="store_true", help="path estimator: the same mean spp, half in a pilot "
                   "pass, the rest placed where the pilot's neighbourhood is noisy (unbiased; box filter)")
    r.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    i = sub.add_parser("info", help="what a scene holds and what its kernel includes")
    i.add_argument("scene", type=Path)
    i.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    return p


def _defines(items: list[str]) -> dict[str, str]:
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise SceneError(f"-D {item}: expected NAME=VALUE")
        out[name] = value
    return out


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        scene = load_scene(args.scene, **_defines(args.defines))
        return _render(scene, args) if args.command == "render" else _info(scene)
    except (SceneError, ValueError, OSError) as e:
        print(f"tracer: error: {e}", file=sys.stderr)
        return 1
    except RuntimeError as e:  # Dr.Jit: no backend, out of memory, ...
        print(f"tracer: error: {str(e).splitlines()[0] if str(e) else type(e).__name__}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("tracer: interrupted; no output written", file=sys.stderr)
        return 130


def _render(scene, args) -> int:
    from .rendering import render

    if args.output.suffix.lower() != ".exr":
        raise SceneError(f"--output {args.output}: the output must be an .exr file")
    max_depth = args.max_depth if args.report_depth is None else args.report_depth + 2
    spp = args.spp if args.spp is not None or args.estimator == "path" else 1
    rfilter = ReconstructionFilter(args.filter) if args.filter else scene.camera.rfilter
    if args.aov_spp < 1:
        raise ValueError(f"--aov-spp must be >= 1, got {args.aov_spp}")
    if args.adaptive and args.estimator != "path":
        raise ValueError("--adaptive works with the path estimator only, not --estimator report")
    if args.adaptive:
        from .adaptive import render_adaptive
        result = render_adaptive(scene, spp=spp, seed=args.seed, max_depth=max_depth, rfilter=rfilter,
                                 progress=not args.quiet)
    else:
        result = render(scene, args.estimator, spp=spp, seed=args.seed, max_depth=max_depth, direct=args.direct,
                        indirect=args.indirect, hemisphere=args.hemisphere, rfilter=rfilter, progress=not args.quiet)
    outputs, notes = _outputs(scene, args, result.image, rfilter)
    _write_all(outputs)
    depth = "unbounded" if result.max_depth < 0 else f"{result.max_depth}"
    extra = ""
    if args.estimator == "report":
        s = result.settings
        extra = f", N = {s['direct']}, M = {s['indirect']} ({s['hemisphere']}), report depth {s['report_depth']}"
    if args.adaptive:
        n = result.settings["samples"]
        extra = f" (adaptive: pilot {result.settings['pilot_spp']}, {n.min()} to {n.max()} per pixel)"
    h, w = result.image.shape[:2]
    print(f"rendered {args.scene} with {args.estimator} at {w} x {h}, {result.spp} spp, max_depth {depth}{extra} "
          f"on {result.backend}, {rfilter.describe()} filter")
    print(f"  compile {result.compile_seconds:.2f} s, render {result.render_seconds:.2f} s, "
          f"total {result.seconds:.2f} s")
    print(f"  rays {result.rays:,} ({result.rays_per_second / 1e6:.1f} M rays/s)")
    for note in notes:
        print(note)
    print(f"  wrote {', '.join(str(path) for path, _, _ in outputs)}")
    return 0


def _outputs(scene, args, image, rfilter) -> tuple[list, list[str]]:
    """The files to write, (path, writer, image), with --aovs and --denoise; lines on their time."""
    from .imageio import write_exr, write_normal_exr, write_png

    out = args.output
    extra, notes = [], []
    if args.aovs or args.denoise:
        from .aov import render_aovs

        aov = render_aovs(scene, args.aov_spp, args.seed, rfilter)
        notes.append(f"  AOVs (albedo, normal) {aov.spp} spp: {aov.render_seconds:.2f} s "
                     f"(compile {aov.compile_seconds:.2f} s)")
        extra += [(out.with_suffix(".albedo.exr"), write_exr, aov.albedo),
                  (out.with_suffix(".normal.exr"), write_normal_exr, aov.normal)]
    if args.denoise:
        from .denoise import denoise, splatting_warning

        if warning := splatting_warning(rfilter):
            print(f"tracer: warning: {warning}", file=sys.stderr)
        start = time.perf_counter()
        noisy, image = image, denoise(image, aov.albedo, aov.normal)
        notes.append(f"  denoise (Open Image Denoise, colour + albedo + normal): {time.perf_counter() - start:.2f} s")
        extra.append((out.with_suffix(".noisy.exr"), write_exr, noisy))
    return [(out, write_exr, image), (out.with_suffix(".png"), write_png, image)] + extra, notes


def _write_all(outputs: list) -> None:
    """Writes every file or, if one fails, removes those this call already wrote: no partial output."""
    written = []
    try:
        for path, write, image in outputs:
            write(path, image)
            written.append(path)
    except BaseException:
        for path in written:
            path.unlink(missing_ok=True)
        raise


def _info(scene) -> int:
    from .geometry import SceneGeometry

    cam = scene.camera
    print(f"{scene.path}")
    print(f"  camera: perspective, fov {cam.fov} ({cam.fov_axis}), {cam.width} x {cam.height}, "
          f"{cam.rfilter.describe()} filter")
    print(f"  sampler: {scene.spp} spp, seed {scene.seed}; integrator: max_depth {scene.max_depth}, "
          f"rr_depth {scene.rr_depth}")
    print(f"  ({DEPTH_NOTE})")
    print(f"  shapes: {len(scene.rectangles)} rectangles, {len(scene.meshes)} meshes "
          f"({scene.triangle_count} triangles), {len(scene.spheres)} spheres")
    for e in scene.emitters:
        print(f"  light '{e.name}': radiance {tuple(round(x, 4) for x in e.radiance)}")
    print("  kernel:")
    for line in SceneGeometry(scene).describe():
        print(f"    {line}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
