"""`validate mitsuba-tests DIR`: Mitsuba 3's own render tests, taken by the tracer with Mitsuba's protocol.

The tests are the scenes `DIR/tests/scenes/<folder>/<name>_<integrator>.xml` of a local copy of the public
`mitsuba-renderer/mitsuba-data`, each with `refs/<name>_ref_rgb.exr` (Mitsuba's mean image at 32,000 spp) and
`refs/<name>_ref_rgb_var.exr` (the per-pixel variance of one sample). The protocol is that of Mitsuba's
`src/render/tests/test_renders.py`, step by step:

- spp = 2,000,000 // (the reference's pixels); the scene loaded with `-D spp=<spp> -D integrator=<integrator>`
  (the suffix of its name), rendered once with seed 0;
- the image, the reference and its variance converted from linear sRGB to CIE XYZ (SRGB_TO_XYZ); the variance
  floored at 1e-4;
- per pixel and channel z = |mean - reference| sqrt(spp / variance), p = 2 (1 - Phi(z)), computed in float32
  with Dr.Jit's erf, as Mitsuba computes it (float32 rounds p to 0 beyond z of about 5.3, which decides the
  test on the largest images);
- Sidak's level alpha = 1 - (1 - 0.01)^(1 / pixels): were the pixels' tests independent and the image
  correct, all of them would accept with probability 99%;
- the test passes when (the number of (pixel, channel) tests with p > alpha) / 3 >= 99.75% of the pixels.

The z-test takes the reference as exact and the variance as the reference's; `detectable_bias` gives, for
each test, the smallest uniform relative error of a noise-free image that the rule rejects: the bias the
test could miss. Mitsuba itself (validation.verdict.mitsuba_render's variant) is put through the same protocol, so
that a test Mitsuba's own render fails on this machine is told apart from a fault of the tracer.

Renders are cached in `.cache/mitsuba_tests`, written atomically with a checksum checked on load, keyed by
the scene's content (every file it names), the spp, the seed and the renderer: Mitsuba's version, or the
tracer's source and Dr.Jit's version, so a change to the tracer re-renders the tests it renders and reuses
Mitsuba's. Verdicts are recomputed from the cached images on every run; refusals are read again (loading
is cheap, and a tracer change may lift them). Scene files are read, never copied: the repository states no
licence.
"""
from __future__ import annotations

import glob
import hashlib
import io
import json
import math
import time
import traceback
from collections import Counter
from contextlib import nullcontext
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from tracer.imageio import atomic_write, read_exr

from ..reports.provenance import environment, relative_to, write_json, write_text
from ..verdict.references import _digest
from ..verdict.scenefile import files_digest
from .runner import NONE, Runner, Unit, session

SAMPLE_BUDGET = 2_000_000     # samples per image, spread over the reference's pixels
SEED = 0
SIGNIFICANCE = 0.01           # the family-wise level Sidak's correction spreads over the pixels
ACCEPT = 0.9975               # the fraction of pixels that must accept
VARIANCE_FLOOR = 1e-4
# Linear sRGB (D65) to CIE XYZ, as Mitsuba's srgb_to_xyz and Bitmap.convert (checked in the tests)
SRGB_TO_XYZ = np.array([[0.412453, 0.357580, 0.180423],
                        [0.212671, 0.715160, 0.072169],
                        [0.019334, 0.119193, 0.950227]], np.float32)
CACHE = Path(".cache/mitsuba_tests")
SCENES = Path("tests/scenes")


# ---- the tests --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RenderTest:
    scene: Path
    integrator: str           # the suffix of the scene's name, passed as -D integrator=...
    reference: Path
    variance: Path

    @property
    def name(self) -> str:
        return f"{self.scene.parent.name}/{self.scene.name}"


def render_tests(root: Path) -> tuple[list[RenderTest], list[Path]]:
    """The tests under root/tests/scenes (one folder deep, as Mitsuba globs them), and the scene files that
    have no rgb reference (Mitsuba skips those)."""
    tests, missing = [], []
    for scene in sorted((root / SCENES).glob("*/*.xml")):
        base, integrator = scene.stem.rsplit("_", 1) if "_" in scene.stem else (scene.stem, scene.stem)
        ref = scene.parent / "refs" / f"{base}_ref_rgb.exr"
        var = ref.with_name(f"{base}_ref_rgb_var.exr")
        if ref.is_file() and var.is_file():
            tests.append(RenderTest(scene, integrator, ref, var))
        else:
            missing.append(scene)
    return tests, missing


def to_xyz(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) linear sRGB as CIE XYZ, float32."""
    return np.asarray(rgb, np.float32) @ SRGB_TO_XYZ.T


# ---- the protocol's statistics ----------------------------------------------------------------------------
def sample_count(pixels: int) -> int:
    return SAMPLE_BUDGET // pixels


def sidak_level(pixels: int) -> float:
    return 1.0 - (1.0 - SIGNIFICANCE) ** (1.0 / pixels)


def p_values(mean: np.ndarray, spp: int, reference: np.ndarray, variance: np.ndarray) -> np.ndarray:
    """Per pixel and channel, the z-test's two-sided p-value, in float32 as Mitsuba computes it."""
    import drjit as dr
    from drjit.scalar import ArrayXf

    mean, reference, variance = (np.asarray(a, np.float32) for a in (mean, reference, variance))
    z = np.abs(mean - reference) * np.sqrt(np.float32(spp) / np.maximum(variance, np.float32(VARIANCE_FLOOR)))
    cdf = np.array((1.0 - dr.erf(-ArrayXf(z.ravel()) / dr.sqrt(2.0))) * 0.5, np.float32).reshape(z.shape)
    return np.float32(2.0) * (np.float32(1.0) - cdf)


@dataclass
class Verdict:
    passed: bool
    rejected: float           # the fraction of the pixels rejected: 1 - accepted tests / 3 / pixels
    min_p: float
    alpha: float


def verdict(mean: np.ndarray, spp: int, reference: np.ndarray, variance: np.ndarray) -> Verdict:
    """Mitsuba's rule on XYZ images: at least ACCEPT of the pixels (accepted channels / 3) have p > alpha."""
    pixels = reference.shape[0] * reference.shape[1]
    p = p_values(mean, spp, reference, variance)
    alpha = sidak_level(pixels)
    accepted = np.count_nonzero(p > alpha) / 3
    return Verdict(bool(accepted >= ACCEPT * pixels), 1.0 - accepted / pixels, float(p.min()), alpha)


def detectable_bias(spp: int, reference: np.ndarray, variance: np.ndarray) -> float:
    """The smallest s for which the noise-free image (1 + s) x reference fails the rule: fails means more than
    (1 - ACCEPT) x 3 x pixels tests reject, a test rejecting when s |ref| sqrt(spp / var) exceeds z_alpha."""
    from scipy.stats import norm

    pixels = reference.shape[0] * reference.shape[1]
    z_alpha = norm.isf(sidak_level(pixels) / 2)
    with np.errstate(divide="ignore"):
        thresholds = np.sort((z_alpha * np.sqrt(np.maximum(variance, VARIANCE_FLOOR) / spp)
                              / np.abs(reference)).ravel())
    k = math.floor(round((1 - ACCEPT) * 3 * pixels, 9))     # this many rejections still pass
    return float(thresholds[k]) if k < thresholds.size else math.inf


# ---- renders, cached ----------------------------------------------------------------------------------------
@dataclass
class Render:
    xyz: np.ndarray          # (H, W, 3) float32, the image in CIE XYZ
    seconds: float


def _load(path: Path, key: str) -> Render | None:
    try:
        with np.load(path) as z:
            meta, xyz = json.loads(str(z["meta"])), z["xyz"]
    except (OSError, ValueError, KeyError, EOFError):
        return None
    if meta.get("key") != key or meta.get("sha256") != _digest({"xyz": xyz}):
        return None
    return Render(xyz, meta["seconds"])


def _encode(key: str, render: Render) -> bytes:
    meta = json.dumps({"key": key, "seconds": render.seconds, "sha256": _digest({"xyz": render.xyz})})
    buf = io.BytesIO()
    np.savez(buf, meta=np.array(meta), xyz=render.xyz)
    return buf.getvalue()


def write_files(cache: Path, files: dict[str, bytes]) -> None:
    """Renders a worker made (cache files by name), each written atomically unless the cache holds it."""
    for name, data in files.items():
        if not (cache / name).exists():
            (cache / name).parent.mkdir(parents=True, exist_ok=True)
            atomic_write(cache / name, lambda tmp: Path(tmp).write_bytes(data))


def cached(test: RenderTest, spp: int, renderer: str, identity: str, render, files: dict[str, bytes]) -> Render:
    """`render()` (the XYZ image and its seconds), or the cached one of the same scene content, spp, seed
    and renderer identity; `files`: the cache's files by name (as the suite's process sent them), where a new
    render is added."""
    text = json.dumps({"scene": files_digest(test.scene), "integrator": test.integrator, "spp": spp,
                       "seed": SEED, "renderer": identity}, sort_keys=True)
    key = hashlib.sha256(text.encode()).hexdigest()[:24]
    name = f"{renderer}-{test.scene.parent.name}-{test.scene.stem}-{key}.npz"
    found = _load(io.BytesIO(files.get(name, b"")), key)
    if found is None:
        found = render()
        files[name] = _encode(key, found)
    return found


def tracer_identity() -> str:
    """The tracer's source (every module's text), Dr.Jit's version and the backend: what its images depend on."""
    import drjit

    import tracer
    from tracer.jit import BACKEND, PRECISION

    h = hashlib.sha256()
    for f in sorted(Path(tracer.__file__).parent.rglob("*.py")):
        h.update(f.relative_to(Path(tracer.__file__).parent).as_posix().encode())
        h.update(f.read_bytes())
    return f"tracer {h.hexdigest()[:16]}, drjit {drjit.__version__}, {BACKEND}, {PRECISION}"


def tracer_render(test: RenderTest, spp: int) -> Render:
    import tracer

    scene = tracer.load_scene(test.scene, spp=spp, integrator=test.integrator)
    start = time.perf_counter()
    result = tracer.render(scene, "path", spp=spp, seed=SEED)
    return Render(to_xyz(result.image), time.perf_counter() - start)


def mitsuba_render(test: RenderTest, spp: int) -> Render:
    """Mitsuba's render as its test takes it: loaded with spp and the integrator, rendered with seed 0, and the
    mean read from the film as XYZ (the `moment` integrator's first AOV, else the image converted)."""
    from ..verdict.mitsuba_render import loading, mitsuba

    mi = mitsuba()
    start = time.perf_counter()
    with loading():
        scene = mi.load_file(str(test.scene), spp=spp, integrator=test.integrator)
    scene.integrator().render(scene, seed=SEED, spp=spp, develop=True)
    parts = scene.sensors()[0].film().bitmap(raw=False).split()
    if len(parts) > 1:
        xyz = np.array(parts[1][1], np.float32)
    else:
        root = parts[0][1]
        if root.channel_count() >= 3 and root.pixel_format() != mi.Bitmap.PixelFormat.XYZ:
            root = root.convert(mi.Bitmap.PixelFormat.XYZ, mi.Struct.Type.Float32, False)
        xyz = np.array(root, np.float32)
    return Render(xyz.reshape(xyz.shape[0], xyz.shape[1], -1)[..., :3], time.perf_counter() - start)


# ---- one test, both renderers ---------------------------------------------------------------------------
@dataclass
class Outcome:
    test: str                  # <folder>/<scene>.xml
    integrator: str
    pixels: int
    spp: int
    detectable_bias: float
    tracer: str                # pass | fail | refused | error
    tracer_rejected: float | None = None
    tracer_reason: str = ""    # the refusal or error, one line (paths relative to the data's root)
    tracer_refusals: int = 0
    tracer_seconds: float = 0.0
    mitsuba: str = ""          # pass | fail | error | "" (not run)
    mitsuba_rejected: float | None = None
    mitsuba_reason: str = ""
    mitsuba_seconds: float = 0.0

    def line(self) -> str:
        if self.tracer in ("pass", "fail"):
            ours = (f"{self.tracer_rejected:.2%} of pixels rejected (limit {1 - ACCEPT:.2%}), {self.spp} spp, "
                    f"{self.tracer_seconds:.1f} s")
        else:
            more = f" (+{self.tracer_refusals - 1} more)" if self.tracer_refusals > 1 else ""
            ours = self.tracer_reason + more
        theirs = (f"{self.mitsuba} ({self.mitsuba_rejected:.2%} rejected)" if self.mitsuba in ("pass", "fail")
                  else f"error: {self.mitsuba_reason}" if self.mitsuba == "error" else "not run")
        return f"{self.tracer:<8} {self.test}: {ours}; Mitsuba: {theirs}"


def _one_line(e: BaseException) -> str:
    lines = [line.strip() for line in str(e).splitlines() if line.strip()]
    return lines[0] if lines else type(e).__name__


def take(test: RenderTest, root: Path, run_mitsuba: bool = True, files: dict[str, bytes] | None = None) -> Outcome:
    """One test (a unit of the suite, on a worker): the tracer's verdict, and Mitsuba's where `run_mitsuba`;
    `files`: the cached renders of the test by name, to which new renders are added."""
    import tracer
    from tracer.errors import UserError

    files = {} if files is None else files

    ref, var = to_xyz(read_exr(test.reference)), to_xyz(read_exr(test.variance))
    pixels = ref.shape[0] * ref.shape[1]
    spp = sample_count(pixels)
    out = Outcome(test.name, test.integrator, pixels, spp, detectable_bias(spp, ref, var), "")
    try:
        tracer.load_scene(test.scene, spp=spp, integrator=test.integrator)
    except (tracer.SceneError, UserError) as e:
        out.tracer, out.tracer_reason = "refused", relative_to(_one_line(e), root)
        out.tracer_refusals = len(str(e).splitlines())
    if not out.tracer:
        try:
            r = cached(test, spp, "tracer", tracer_identity(), lambda: tracer_render(test, spp), files)
            v = verdict(r.xyz, spp, ref, var)
            out.tracer, out.tracer_rejected, out.tracer_seconds = ("pass" if v.passed else "fail"), v.rejected, r.seconds
        except UserError as e:
            out.tracer, out.tracer_reason = "error", relative_to(_one_line(e), root)
        except Exception as e:    # a bug of the tracer: its traceback, and the other tests still run
            traceback.print_exc()
            out.tracer, out.tracer_reason = "error", f"{type(e).__name__}: {relative_to(_one_line(e), root)}"
    if run_mitsuba:
        from ..verdict.mitsuba_render import version

        try:
            r = cached(test, spp, "mitsuba", version(), lambda: mitsuba_render(test, spp), files)
            v = verdict(r.xyz, spp, ref, var)
            out.mitsuba, out.mitsuba_rejected, out.mitsuba_seconds = ("pass" if v.passed else "fail"), v.rejected, r.seconds
        except Exception as e:    # Mitsuba's refusal or failure is the datum
            out.mitsuba, out.mitsuba_reason = "error", relative_to(_one_line(e), root)[:200]
    return out


def take_unit(test: RenderTest, root: Path, run_mitsuba: bool, files: dict[str, bytes]) -> tuple[Outcome, dict]:
    """take() as a unit of the suite: its outcome and the renders it made (cache files by name)."""
    before = set(files)
    outcome = take(test, root, run_mitsuba, files)
    return outcome, {k: v for k, v in files.items() if k not in before}


def run(root: Path, only: list[str] | None = None, run_mitsuba: bool = True, cache: Path = CACHE,
        runner: Runner | None = None) -> tuple[list[Outcome], list[Path]]:
    """Every test under root (those whose name contains one of `only`) as a unit of one suite on `runner`
    (default: in this process), one line each on the terminal as it arrives; its renders cached here."""
    tests, missing = render_tests(root)
    if only:
        tests = [t for t in tests if any(s in t.name for s in only)]

    def cached_files(test: RenderTest) -> dict[str, bytes]:
        return {f.name: f.read_bytes() for f in cache.glob(f"*-{glob.escape(test.scene.parent.name)}-"
                                                              f"{glob.escape(test.scene.stem)}-*.npz")}

    def on_result(unit: Unit, result) -> None:
        write_files(cache, result[1])
        print(result[0].line(), flush=True)

    units = [Unit(f"{t.name}-{files_digest(t.scene)[:16]}-{'both' if run_mitsuba else 'tracer'}", take_unit,
                  (t, root, run_mitsuba, cached_files(t))) for t in tests]
    with (nullcontext(runner) if runner is not None else session(NONE)) as r:
        results = r.run(units, "Mitsuba's render tests", on_result)
    return [results[u.key][0] for u in units], missing


# ---- the report -----------------------------------------------------------------------------------------------
def _cell(status: str, rejected: float | None) -> str:
    return f"{status} ({rejected:.2%})" if rejected is not None else (status or "not run")


def markdown(outcomes: list[Outcome], missing: list[str], command: str) -> str:
    from .coverage import blocker
    from ..verdict.mitsuba_render import version

    n = len(outcomes)
    count = Counter(o.tracer for o in outcomes)
    theirs = Counter(o.mitsuba for o in outcomes)
    ran_mitsuba = any(o.mitsuba for o in outcomes)
    lines = ["# Mitsuba's render tests, taken by the tracer", "",
             f"Generated by `{command}` on a local copy of `mitsuba-renderer/mitsuba-data` (its `tests/scenes`: "
             "each scene with Mitsuba's 32,000-spp reference image and per-pixel variance in `refs/`), with the "
             "protocol of Mitsuba's `src/render/tests/test_renders.py`: spp = 2,000,000 // the reference's pixels, "
             "the scene loaded with that spp and the integrator its name ends with, seed 0; image, reference and "
             "variance in CIE XYZ, the variance floored at 1e-4; per pixel and channel z = |mean - ref| "
             "sqrt(spp / var) and p = 2 (1 - Phi(z)) in float32; Sidak's level alpha = 1 - 0.99^(1 / pixels); "
             f"a test passes when at least {ACCEPT:.2%} of the pixels (accepted channels / 3) have p > alpha. "
             + (f"Mitsuba ({version()}) is put through the same protocol on this machine, so that a test its own "
                "render fails here is told apart from a fault of the tracer." if ran_mitsuba else
                "Mitsuba was not run (`--no-mitsuba`)."), "",
             "*Detectable bias*: the smallest uniform relative error of a noise-free image that the rule "
             "rejects, from the reference's variance and the spp; an image wrong by less can pass. The z-test "
             "takes the reference as exact.", "",
             "| | tests |", "|---|---:|",
             f"| render tests (scenes with an rgb reference) | {n} |",
             f"| the tracer passes | {count['pass']} |",
             f"| the tracer fails | {count['fail']} |",
             f"| the tracer refuses | {count['refused']} |"]
    if count["error"]:
        lines.append(f"| the tracer's render failed | {count['error']} |")
    if ran_mitsuba:
        lines += [f"| Mitsuba passes | {theirs['pass']} |", f"| Mitsuba fails | {theirs['fail']} |"]
        if theirs["error"]:
            lines.append(f"| Mitsuba's render failed | {theirs['error']} |")
    lines += ["", "## Every test", "",
              "| test | integrator | pixels | spp | detectable bias | tracer (rejected) | Mitsuba (rejected) | "
              "tracer's reason |", "|---|---|---:|---:|---:|---|---|---|"]
    for o in outcomes:
        reason = o.tracer_reason + (f" (+{o.tracer_refusals - 1} more)" if o.tracer_refusals > 1 else "")
        mitsuba = _cell(o.mitsuba, o.mitsuba_rejected) + (f": {o.mitsuba_reason}" if o.mitsuba_reason else "")
        lines.append(f"| {o.test} | {o.integrator} | {o.pixels} | {o.spp} | {o.detectable_bias:.2%} | "
                     f"{_cell(o.tracer, o.tracer_rejected)} | {mitsuba.replace('|', '/')[:120]} | "
                     f"{reason.replace('|', '/')[:200]} |")
    blockers = Counter(blocker(o.tracer_reason) for o in outcomes if o.tracer == "refused")
    if blockers:
        lines += ["", "## What the tracer refuses first", "",
                  "Each refused test's first refusal, reduced to what it refuses (a test may meet more).", "",
                  "| refusal | tests |", "|---|---:|"]
        lines += [f"| {k.replace('|', '/')} | {v} |" for k, v in sorted(blockers.items(), key=lambda kv: (-kv[1], kv[0]))]
    if missing:
        lines += ["", f"Scene files without an rgb reference (Mitsuba skips them too): {', '.join(missing)}."]
    lines += ["", "## Machine and versions", ""] + environment(command)
    return "\n".join(lines) + "\n"


def report(root: Path, out: Path | None, command: str, only: list[str] | None = None,
           run_mitsuba: bool = True, cache: Path = CACHE, runner: Runner | None = None) -> int:
    """Runs the tests, writes `out` (.md, and .json beside it) unless None; 0 when every test the tracer
    renders passes, 1 when one fails or its render failed."""
    outcomes, missing = run(root, only, run_mitsuba, cache, runner)
    names = [f"{p.parent.name}/{p.name}" for p in missing]
    if out is not None:
        write_json(out.with_suffix(".json"), [asdict(o) for o in outcomes])
        print(write_text(out, markdown(outcomes, names, command)))
    count = Counter(o.tracer for o in outcomes)
    print(f"{len(outcomes)} tests: the tracer passes {count['pass']}, fails {count['fail']}, refuses "
          f"{count['refused']}" + (f", errors on {count['error']}" if count["error"] else "")
          + ("; Mitsuba passes " + str(sum(o.mitsuba == 'pass' for o in outcomes)) if run_mitsuba else ""))
    return 1 if count["fail"] or count["error"] else 0
