"""`tracer render SCENE.xml [-o OUT.exr ...]` and `tracer info SCENE.xml`.

Every render is checked before its first ray: the options, the output paths (a probe file in each
folder), the plan (tracer.plan: passes, memory). Errors a user can act on (tracer.errors.UserError, the
loader's SceneError, OSError, MemoryError) print one line and return 1; anything else is a bug in the tracer and
prints its traceback, a line saying so, and returns 70. Parsing the command line imports nothing of
Dr.Jit, so that `--help` and `--version` work whatever the machine's LLVM.
"""
from __future__ import annotations

import argparse
import dataclasses
import importlib
import os
import re
import sys
import time
import traceback
from pathlib import Path

from .errors import BackendError, OutOfMemory, OutputError, SettingsError, UserError, clip, shorten

DEPTH_NOTE = ("max_depth counts path segments as Mitsuba does (1: lights seen directly, 2: direct light, "
              "-1: unbounded); the report's depth D is max_depth D + 2")
BACKEND_NOTE = ("The backend is CUDA where Dr.Jit finds a GPU, LLVM on the CPU otherwise; --backend or the "
                "environment variable TRACER_BACKEND=llvm|cuda forces one, TRACER_PRECISION=double makes every "
                "kernel compute in float64.")
BUG_EXIT = 70  # EX_SOFTWARE
INT32_MAX, UINT32_MAX = 2 ** 31 - 1, 2 ** 32 - 1    # Mitsuba's bounds of max_depth and of image sizes


class _Version(argparse.Action):
    """--version: the versions are looked up (importlib.metadata) only when asked, not at every command's
    start."""

    def __init__(self, option_strings, dest, **kwargs):
        super().__init__(option_strings, dest, nargs=0, help="show the tracer's and Dr.Jit's versions and exit")

    def __call__(self, parser, namespace, values, option_string=None):
        print(_version())
        parser.exit()


def _version() -> str:
    from importlib import metadata

    def of(name):
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return "not installed"
    return f"tracer {of('tracer')} (Dr.Jit {of('drjit')})"


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="tracer", description="A Monte Carlo ray tracer on Dr.Jit for Mitsuba 3 scenes.",
                                epilog=BACKEND_NOTE)
    p.add_argument("--version", action=_Version)
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("render", help="render a scene to a linear EXR and an sRGB PNG beside it",
                       epilog=f"{DEPTH_NOTE}. {BACKEND_NOTE}")
    r.add_argument("scene", type=Path)
    r.add_argument("--output", "-o", type=Path, action="append", default=[],
                   help="an output image, by its extension: .exr (linear float32) or .png (8-bit sRGB); may be "
                   "repeated; default: the scene's name with .exr in the scene's folder, as Mitsuba. A .png is "
                   "written beside each .exr unless --no-png or a .png is asked for")
    r.add_argument("--no-png", action="store_true", help="no .png beside the .exr")
    r.add_argument("--estimator", choices=("path", "report"), default="path")
    r.add_argument("--spp", type=int, help="samples (camera rays) per pixel; default: the scene's sample_count "
                   "for path, 1 for report (the report's one ray per pixel)")
    r.add_argument("--seed", type=int, help="random seed in [0, 2^32); default: the scene's sampler seed")
    depth = r.add_mutually_exclusive_group()
    depth.add_argument("--max-depth", type=_int_in(high=INT32_MAX), help="Mitsuba's max_depth; default: the scene's integrator")
    depth.add_argument("--report-depth", type=_int_in(high=INT32_MAX - 2), help="the report's depth D >= 0 (= max_depth D + 2)")
    r.add_argument("--direct", "-N", type=_int_in(high=INT32_MAX),
                   help="report estimator: shadow rays per diffuse hit (eq. 10; default 16)")
    r.add_argument("--indirect", "-M", type=_int_in(high=INT32_MAX), help="report estimator: hemisphere rays per diffuse hit (eq. 11; "
                   "default 8)")
    r.add_argument("--hemisphere", choices=("cosine", "uniform"),
                   help="report estimator: how eq. 11's directions are drawn (default cosine)")
    r.add_argument("--filter", metavar="box|gaussian|tent", help="pixel reconstruction filter, replacing the scene's "
                   "rfilter (Mitsuba's defaults: gaussian stddev 0.5, tent radius 1)")
    r.add_argument("--size", metavar="WxH", help="image size, replacing the scene film's width and height")
    r.add_argument("--width", type=_int_in(high=UINT32_MAX), help="image width, replacing the scene film's")
    r.add_argument("--height", type=_int_in(high=UINT32_MAX), help="image height, replacing the scene film's")
    r.add_argument("--time-limit", type=float, metavar="SECONDS", help="render one sample per pixel per pass and "
                   "stop after the last whole pass that fits in SECONDS (at most --spp); the spp rendered is "
                   "printed and stored in the EXR header")
    r.add_argument("--backend", choices=("llvm", "cuda"), help="Dr.Jit backend (as TRACER_BACKEND)")
    r.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE",
                   help="override a <default> of the scene, like mitsuba -D")
    r.add_argument("--aovs", action="store_true", help="also write OUT.albedo.exr and OUT.normal.exr: albedo and "
                   "world-space normal (in [-1, 1]) of the first non-specular surface, through mirrors and glass")
    r.add_argument("--denoise", action="store_true", help="denoise with Intel Open Image Denoise, guided by the "
                   "AOVs: OUT.exr/.png are denoised, the noisy image is kept as OUT.noisy.exr, the AOVs are written")
    r.add_argument("--aov-spp", type=_int_in(high=UINT32_MAX), default=8, help="samples per pixel of the AOVs (default 8)")
    r.add_argument("--adaptive", action="store_true", help="path estimator: the same mean spp, half in a pilot "
                   "pass, the rest placed where the pilot's neighbourhood is noisy (unbiased; box filter)")
    r.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    i = sub.add_parser("info", help="what a scene holds, its parameters (-D) and what its kernel includes")
    i.add_argument("scene", type=Path)
    i.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    i.add_argument("--backend", choices=("llvm", "cuda"), help="Dr.Jit backend (as TRACER_BACKEND)")
    return p


def parse_defines(items: list[str]) -> dict[str, str]:
    """-D NAME=VALUE arguments as a dict (the last value of a name wins)."""
    out = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name:
            raise SettingsError(f"-D {item}: expected NAME=VALUE")
        out[name] = value
    return out


def _is_user_error(e: BaseException) -> bool:
    """The loader's errors are users' too; they are looked up only if the loader was imported at all."""
    scene = sys.modules.get("tracer.scene")
    denoise = sys.modules.get("tracer.denoise")
    kinds = (UserError, OSError, MemoryError) + ((scene.SceneError,) if scene else ()) \
        + ((denoise.DenoiseError,) if denoise else ())
    return isinstance(e, kinds)


def main(argv: list[str] | None = None) -> int:
    # The host-side set-up multiplies n x 3 arrays by 3 x 3 matrices (to_world, plane tests); OpenBLAS's threads
    # make those slower, not faster (1M mesh vertices: 0.18 s against under 0.01 s on 2 busy cores), and spin
    # beside Dr.Jit's. One thread gives the same bits (each product is one thread's kernel). Set before NumPy is
    # first imported (in a command line, only once a command runs); a value the user set is kept.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    args = _parser().parse_args(argv)
    try:
        _use_backend(args.backend)
        return _render(args) if args.command == "render" else _info(args)
    except KeyboardInterrupt:
        print("tracer: interrupted; no output written", file=sys.stderr)
        return 130
    except BrokenPipeError:   # the reader of the output left (`tracer info SCENE | head`): not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())   # Python's exit flush has nowhere to fail
        return 0
    except Exception as e:
        if _is_user_error(e):
            print(f"tracer: error: {_one_line(e)}", file=sys.stderr)
            return 1
        traceback.print_exc()
        print(f"tracer: internal error: the {type(e).__name__} above is a bug in the tracer, not a problem with "
              f"your input; please report it with the command line", file=sys.stderr)
        return BUG_EXIT


def run() -> None:
    """The `tracer` command: main(), then the process ends at once, without the interpreter's and Dr.Jit's
    teardown (0.12-0.16 s after a 64 x 48 render, against 0.02 s). Nothing is left to it: main() has written
    and closed its files, Dr.Jit writes a kernel to its cache when it compiles it, and the standard streams
    are flushed here."""
    code = main()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (BrokenPipeError, ValueError):   # the reader left, or the stream is closed: nothing to deliver
            pass
    os._exit(code)


def _one_line(e: BaseException) -> str:
    """A user error's message with long values clipped; an OSError's as its file and reason."""
    if isinstance(e, OSError) and not isinstance(e, UserError) and e.strerror:
        text = f"{e.filename}: {e.strerror}" if e.filename else e.strerror
    else:
        text = str(e) or type(e).__name__
    return "\n".join(shorten(line) for line in text.splitlines())


def _int_in(high: int):
    """An argparse type: an integer of at most `high` (lower bounds are checked with the other settings)."""
    def parse(text: str) -> int:
        value = int(text)
        if value > high:
            raise argparse.ArgumentTypeError(f"{clip(text)} exceeds {high}")
        return value
    parse.__name__ = "integer"
    return parse


def _use_backend(backend: str | None) -> None:
    """--backend as TRACER_BACKEND, then Dr.Jit and its backend (tracer.jit). Dr.Jit prints its own
    diagnostics when it finds no usable LLVM; they are caught here and joined to the one-line error."""
    jit = sys.modules.get("tracer.jit")
    if backend is not None and jit is not None and jit.BACKEND != backend:
        raise BackendError(f"--backend {backend}: this process already renders with {jit.BACKEND}")
    if backend is not None:
        os.environ["TRACER_BACKEND"] = backend
    if jit is not None:
        return
    import tempfile    # here, not at every command's start

    with tempfile.TemporaryFile() as log:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(log.fileno(), 2)
        try:
            importlib.import_module("tracer.jit")
        except BackendError as e:
            os.dup2(saved, 2)
            log.seek(0)
            said = " ".join(line.strip() for line in log.read().decode(errors="replace").splitlines() if line.strip())
            raise BackendError(f"{e}{f' (Dr.Jit: {said})' if said else ''}") from None
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        log.seek(0)
        sys.stderr.write(log.read().decode(errors="replace"))  # anything Dr.Jit said on success


def _size(args) -> tuple[int | None, int | None]:
    width, height = args.width, args.height
    if args.size is not None:
        m = re.fullmatch(r"(\d{1,10})[xX](\d{1,10})", args.size)
        if not m:
            raise SettingsError(f"--size {clip(args.size)}: expected WIDTHxHEIGHT, e.g. 640x480")
        if width is not None or height is not None:
            raise SettingsError("--size replaces --width and --height: give one or the other")
        width, height = int(m[1]), int(m[2])
    for name, value in (("width", width), ("height", height)):
        if value is not None and value < 1:
            raise SettingsError(f"--{name} must be >= 1, got {value}")
        if value is not None and value > UINT32_MAX:
            raise SettingsError(f"--{name} must be at most {UINT32_MAX} (as Mitsuba's film), got {value}")
    return width, height


def output_paths(scene: Path, outputs: list[Path], no_png: bool) -> list[Path]:
    """The images to write: those asked for (default: the scene's name with .exr beside it, as Mitsuba),
    and a .png beside each .exr unless --no-png or a .png was asked for. Checked, before any work: a known
    format, no path twice, a folder that can be written (a probe file, removed)."""
    from .imageio import probe_writable, writer

    paths = list(outputs) or [scene.with_suffix(".exr")]
    for path in paths:
        writer(path)
    if not no_png and not any(p.suffix.lower() == ".png" for p in paths):
        paths += [p.with_suffix(".png") for p in paths if p.suffix.lower() == ".exr"]
    seen = set()
    for path in paths:
        key = os.path.normcase(os.path.abspath(path))
        if key in seen:
            raise OutputError(f"{path}: asked for twice")
        seen.add(key)
        probe_writable(path)
    return paths


def _render(args) -> int:
    if args.aov_spp < 1:
        raise SettingsError(f"--aov-spp must be >= 1, got {args.aov_spp}")
    if args.report_depth is not None and args.report_depth < 0:
        raise SettingsError(f"--report-depth must be >= 0 (the report's depth D is max_depth D + 2), "
                            f"got {args.report_depth}")
    if args.adaptive and args.estimator != "path":
        raise SettingsError("--adaptive works with the path estimator only, not --estimator report")
    if args.adaptive and args.time_limit is not None:
        raise SettingsError("--time-limit works without --adaptive (whose passes are planned from the pilot)")
    width, height = _size(args)

    from .film import Film
    from .mitsuba_xml import load_scene
    from .estimators import REPORT_DEPTH_OFFSET, make_estimator
    from .rendering import check_rfilter, check_settings, make_plan, render

    scene = load_scene(args.scene, **parse_defines(args.defines))
    if width is not None or height is not None:
        cam = scene.camera
        if cam.cropped:
            raise SettingsError(f"{args.scene}: the film renders a {cam.width} x {cam.height} crop window of its "
                                f"{cam.film_size[0]} x {cam.film_size[1]} pixels; --size, --width and --height "
                                "resize whole films (set the film's crop_* and size with -D where the scene declares them)")
        scene.camera = dataclasses.replace(cam, width=width or cam.width, height=height or cam.height)
    max_depth = args.max_depth if args.report_depth is None else args.report_depth + REPORT_DEPTH_OFFSET
    spp = args.spp if args.spp is not None or args.estimator == "path" else 1
    rfilter = check_rfilter(args.filter if args.filter else scene.camera.rfilter)
    name, spp, seed, max_depth = check_settings(scene, args.estimator, spp, args.seed, max_depth)
    estimator = make_estimator(name, max_depth, args.direct, args.indirect, args.hemisphere)
    # the plan counts every image the outputs hold: the AOVs, the noisy image, OIDN's copies
    plan = make_plan(scene, spp, estimator, Film.border_of(rfilter), args.time_limit is not None,
                     images=2 + 2 * (args.aovs or args.denoise) + 3 * args.denoise)
    paths = output_paths(args.scene, args.output, args.no_png)
    if args.adaptive:
        from .adaptive import render_adaptive
        result = render_adaptive(scene, spp=spp, seed=seed, max_depth=max_depth, rfilter=rfilter,
                                 progress=not args.quiet)
    else:
        try:
            result = render(scene, name, spp=spp, seed=seed, max_depth=max_depth, direct=args.direct,
                            indirect=args.indirect, hemisphere=args.hemisphere, rfilter=rfilter,
                            progress=not args.quiet, time_limit=args.time_limit)
        except OutOfMemory as e:
            raise OutOfMemory(f"{e}; {_keep_partial(scene, e.partial, paths)}") from None
    from .imageio import check_image

    check_image(result.image, f"the render of {args.scene} (values near the float32 limit overflow; nothing written)")
    written, notes = _write_outputs(scene, args, paths, result, rfilter)
    depth = "unbounded" if result.max_depth < 0 else f"{result.max_depth}"
    extra = ""
    if args.estimator == "report":
        s = result.settings
        extra = f", N = {s['direct']}, M = {s['indirect']} ({s['hemisphere']}), report depth {s['report_depth']}"
    if args.adaptive:
        n = result.settings["samples"]
        extra = f" (adaptive: pilot {result.settings['pilot_spp']}, {n.min()} to {n.max()} per pixel)"
    if args.time_limit is not None:
        extra += f" (time limit {args.time_limit:g} s: {result.spp} of {spp} spp)"
    h, w = result.image.shape[:2]
    print(f"rendered {args.scene} with {args.estimator} at {w} x {h}, {result.spp} spp, seed {seed}, "
          f"max_depth {depth}{extra} on {result.backend}, {rfilter.describe()} filter")
    print(f"  plan: {plan.describe()}")
    print(f"  compile {result.compile_seconds:.2f} s, render {result.render_seconds:.2f} s, "
          f"total {result.seconds:.2f} s")
    print(f"  rays {result.rays:,} ({result.rays_per_second / 1e6:.1f} M rays/s)")
    for note in notes:
        print(note)
    print(f"  wrote {', '.join(str(path) for path in written)}")
    return 0


def _tags(result) -> dict:
    """The header entries of a render's images."""
    return {"spp": result.spp, "seed": result.seed, "estimator": result.estimator, "max_depth": result.max_depth}


def _keep_partial(scene, partial, paths: list[Path]) -> str:
    """The passes a render completed before it ran out of memory, written to the outputs with their spp in the
    header (no AOVs, no denoising: they would take more memory); says what was written."""
    from . import imageio

    if partial is None:
        return "nothing written"
    with imageio.Outputs() as out:
        for path in paths:
            out.add(path, imageio.writer(path), partial.image, metadata=_tags(partial))
        written = out.commit()
    return f"wrote them to {', '.join(str(p) for p in written)}"


def _write_outputs(scene, args, paths: list[Path], result, rfilter) -> tuple[list[Path], list[str]]:
    """Writes the images (with --aovs and --denoise, their extra files beside the first output), all or
    none; returns the files and lines on the extra work's time."""
    from . import imageio

    image, notes = result.image, []
    base = paths[0].with_suffix("")
    tags = _tags(result)
    with imageio.Outputs() as out:
        if args.aovs or args.denoise:
            from .aov import render_aovs

            aov = render_aovs(scene, args.aov_spp, result.seed, rfilter)
            notes.append(f"  AOVs (albedo, normal) {aov.spp} spp: {aov.render_seconds:.2f} s "
                         f"(compile {aov.compile_seconds:.2f} s)")
            out.add(f"{base}.albedo.exr", imageio.write_exr, aov.albedo)
            out.add(f"{base}.normal.exr", imageio.write_normal_exr, aov.normal)
        if args.denoise:
            from . import denoise

            if warning := denoise.splatting_warning(rfilter):
                print(f"tracer: warning: {warning}", file=sys.stderr)
            start = time.perf_counter()
            out.add(f"{base}.noisy.exr", imageio.write_exr, image, metadata=tags)
            image = denoise.denoise(image, aov.albedo, aov.normal)
            notes.append(f"  denoise (Open Image Denoise, colour + albedo + normal): "
                         f"{time.perf_counter() - start:.2f} s")
        for path in paths:
            out.add(path, imageio.writer(path), image, metadata=tags)
        return out.commit(), notes


def _info(args) -> int:
    from .mitsuba_xml import load_scene, parse_tree

    defines = parse_defines(args.defines)
    scene = load_scene(args.scene, **defines)
    from .geometry import SceneGeometry

    cam = scene.camera
    print(f"{scene.path}")
    defaults = [(n.attrib.get("name"), n.attrib.get("value", "")) for n in parse_tree(Path(args.scene)).children
                if n.tag == "default"]
    if defaults:
        print("  parameters (-D NAME=VALUE):")
        for name, value in defaults:
            given = f" (given {defines[name]})" if name in defines else ""
            print(f"    {name} = {value}{given}")
    else:
        print("  parameters: none (the scene declares no <default>)")
    view = f"perspective, fov {cam.fov} ({cam.fov_axis})" if cam.projection == "perspective" else "orthographic"
    window = (f" (the crop window at ({cam.crop_x}, {cam.crop_y}) of a {cam.film_size[0]} x {cam.film_size[1]} film)"
              if cam.cropped else "")
    border = f", its {cam.border}-pixel border sampled (sample_border)" if cam.sample_border else ""
    print(f"  camera: {view}, {cam.width} x {cam.height}{window}, "
          f"{cam.rfilter.describe()} filter{border}")
    print(f"  sampler: {scene.spp} spp, seed {scene.seed}; integrator: {scene.integrator}, "
          f"max_depth {scene.max_depth}, rr_depth {scene.rr_depth}")
    for note in scene.notes():
        print(f"  ({note})")
    print(f"  ({DEPTH_NOTE})")
    print(f"  shapes: {len(scene.rectangles)} rectangles, {len(scene.meshes)} meshes "
          f"({scene.triangle_count} triangles), {len(scene.spheres)} spheres")
    if scene.groups:
        held, drawn = scene.instanced_triangles
        print(f"  instanced: {sum(len(g.meshes) for g in scene.groups)} mesh(es) of {held} triangles in "
              f"{len(scene.groups)} shapegroup(s), held once, drawn as {drawn} triangles by "
              f"{sum(len(g.to_world) for g in scene.groups)} instance(s)")
    for e in scene.emitters:
        print(f"  light '{e.name}': radiance {tuple(round(x, 4) for x in e.radiance)}")
    print("  kernel:")
    for line in SceneGeometry(scene).describe():
        print(f"    {line}")
    return 0


if __name__ == "__main__":
    run()
