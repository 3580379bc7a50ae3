"""The renderers a comparison runs, each giving independent passes of a planned scene.

- `TracerRenderer`: the tracer's `path` or branching (`report`) estimator, through its public API;
- `MitsubaRenderer`: Mitsuba 3 with the scene's integrator (`path` where it names none), the ground truth;
- `ExternalRenderer`: any command that renders a scene to an EXR (a student's renderer, another tool), given
  as a template with placeholders (PLACEHOLDERS; README "validate check: the renderer contract"):
  the scene as {scene} (the original file), {scene_resolved} (one self-contained Mitsuba XML with the plan
  written in) or {scene_json} (validation.verdict.scenejson: neutral JSON and PLY meshes); {spp}; one pass per call
  with {seed} and {output}, or many with {seeds} and {outputs} (comma-separated, in the same order);
  {defines}: the plan as -D name=value (width, height, max_depth, spp and the scene parameters given with -D).
  A command may exit with EXIT_UNSUPPORTED to say the scene uses something it does not render.

`passes(plan, passes, spp, seed)` returns a (passes, height, width, 3) float32 array; pass k uses seed
`seed + k` (Mitsuba: `seed * 1_000_003 + k`, as validation.verdict.mitsuba_render), so two uses with different seed
bases (validation.verdict.protocol) never share a stream. A renderer's passes must be independent: `independence`
(called by validate check on every renderer's passes) refuses identical passes and pairs of passes correlated
beyond chance.
"""
from __future__ import annotations

import contextlib
import math
import os
import shlex
import signal
import subprocess
import tempfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tracer.errors import UserError

from .scenefile import ScenePlan, ScenePlanError

PLACEHOLDERS = ("scene", "scene_resolved", "scene_json", "output", "outputs", "spp", "seed", "seeds", "defines")
EXIT_UNSUPPORTED = 77      # a renderer's "this scene uses something I do not render" (automake's skip status)
INDEPENDENCE_ALPHA = 1e-4  # the level of the test that refuses correlated passes (all pairs together)


class RendererError(UserError, RuntimeError):
    """The renderer under test failed or wrote something unusable (reported in one line)."""


class RendererTimeout(RendererError):
    """A call of the renderer outlived --timeout and was stopped: that check is recorded as timed out and the
    run goes on with the next one."""


class RendererUnsupported(UserError, RuntimeError):
    """The renderer does not render this scene (its exit status EXIT_UNSUPPORTED, or an adapter's refusal):
    the check reports it as skipped."""


@dataclass(frozen=True)
class TracerRenderer:
    estimator: str = "path"
    direct: int = 16          # branching estimator: N shadow rays per diffuse hit
    indirect: int = 8         # branching estimator: M hemisphere rays per diffuse hit
    hemisphere: str = "cosine"

    def __post_init__(self):
        """The estimator's settings checked now, before any rendering (tracer.estimators' rules)."""
        from tracer.estimators import make_estimator

        if self.estimator == "report":
            make_estimator("report", 0, self.direct, self.indirect, self.hemisphere)
        else:
            make_estimator(self.estimator, -1)

    @property
    def label(self) -> str:
        if self.estimator == "report":
            return f"tracer report (N={self.direct}, M={self.indirect})"
        return "tracer path"

    def label_for(self, plan: ScenePlan) -> str:
        """The label in a check of `plan`: the path estimator renders the scene's integrator (volpath,
        ptracer, ...), and is named by it."""
        return self.label if self.estimator == "report" else f"tracer {plan.integrator}"

    def options(self) -> dict:
        return (dict(direct=self.direct, indirect=self.indirect, hemisphere=self.hemisphere)
                if self.estimator == "report" else {})

    def results(self, plan: ScenePlan, passes: int, spp: int, seed: int) -> list:
        """The passes as tracer.rendering.RenderResults (image, timing, rays)."""
        from tracer.rendering import render

        scene = plan.tracer_scene()
        return [render(scene, self.estimator, spp=spp, seed=seed + k, max_depth=plan.max_depth, **self.options())
                for k in range(passes)]

    def passes(self, plan: ScenePlan, passes: int, spp: int, seed: int) -> np.ndarray:
        return np.stack([r.image for r in self.results(plan, passes, spp, seed)])


@dataclass(frozen=True)
class MitsubaRenderer:
    label: str = "Mitsuba path"

    def passes(self, plan: ScenePlan, passes: int, spp: int, seed: int) -> np.ndarray:
        from .mitsuba_render import mitsuba

        mi = mitsuba()
        scene = plan.mitsuba_scene(spp)
        return np.stack([np.array(mi.render(scene, seed=(seed * 1_000_003 + k) % 2**32, spp=spp),
                                  dtype=np.float32)[..., :3] for k in range(passes)])


@dataclass(frozen=True)
class ExternalRenderer:
    template: str
    timeout: float | None = None       # seconds a call may take (--timeout); None: no limit
    name: str | None = None            # --label: the renderer's name in verdict lines (default: the command)
    jobs: int = 1                      # calls run at once (--jobs)

    def __post_init__(self):
        names = ", ".join("{" + p + "}" for p in PLACEHOLDERS)
        try:
            used = {f for _, f, _, _ in __import__("string").Formatter().parse(self.template) if f is not None}
            self.template.format(**{p: "" for p in PLACEHOLDERS})
        except (KeyError, IndexError, ValueError) as e:
            raise ScenePlanError(f"--renderer '{self.template}': bad placeholder {e}; the placeholders are {names}") \
                from None
        if ("output" in used) == ("outputs" in used):
            raise ScenePlanError(f"--renderer '{self.template}': the command must contain {{output}} (one pass per "
                                 f"call, with {{seed}}) or {{outputs}} (many, with {{seeds}}), not both; "
                                 f"placeholders: {names}")
        if "outputs" in used and "seed" in used or "output" in used and "seeds" in used:
            raise ScenePlanError(f"--renderer '{self.template}': {{seeds}} goes with {{outputs}}, {{seed}} with "
                                 "{output}")
        if isinstance(self.jobs, bool) or not isinstance(self.jobs, int) or self.jobs < 1:
            raise ScenePlanError(f"--jobs must be a positive integer, got {self.jobs!r}")

    @property
    def label(self) -> str:
        return self.name or f"external: {self.template}"

    @property
    def batch(self) -> bool:
        return "{outputs}" in self.template

    @property
    def reads_json(self) -> bool:
        return "{scene_json}" in self.template

    def command(self, plan: ScenePlan, outputs: list[Path], spp: int, seeds: list[int],
                folder: Path | None = None) -> list[str]:
        """The argv of one call rendering `seeds` into `outputs`; the resolved and JSON scenes are in `folder`
        (written by `write_scene`)."""
        folder = folder or Path("scene")
        defines = " ".join(f"-D {shlex.quote(d)}" for d in plan.defines(spp))
        q = lambda p: shlex.quote(str(p))     # noqa: E731
        return shlex.split(self.template.format(
            scene=q(plan.path), scene_resolved=q(folder / "resolved.xml"), scene_json=q(folder / "scene.json"),
            output=q(outputs[0]), outputs=q(",".join(map(str, outputs))), spp=spp, seed=seeds[0],
            seeds=",".join(map(str, seeds)), defines=defines))

    def prepare(self, plan: ScenePlan, spp: int, seed: int) -> None:
        """Every refusal before the first pass: the command's placeholders, the resolved scene, and for
        {scene_json} the tracer's loader (what it does not honour is refused in one line)."""
        self.command(plan, [Path("pass.exr")], spp, [seed])
        if "{scene_resolved}" in self.template:
            plan.resolved_xml(spp)
        if self.reads_json:
            plan.tracer_scene()

    def write_scene(self, plan: ScenePlan, spp: int, folder: Path) -> None:
        """The scene as the command reads it: resolved.xml and/or scene.json with its meshes, in `folder`."""
        folder.mkdir(parents=True, exist_ok=True)
        if "{scene_resolved}" in self.template:
            (folder / "resolved.xml").write_text(plan.resolved_xml(spp))
        if self.reads_json:
            from .scenejson import write

            write(plan, folder)

    def passes(self, plan: ScenePlan, passes: int, spp: int, seed: int) -> np.ndarray:
        """The passes, each checked: the command ran, ended in time with status 0, and wrote a readable
        OpenEXR image of the plan's size with finite pixels; then the passes' independence. Anything else is a
        RendererError naming the pass; what it wrote is removed with the temporary folder and never reaches a
        cache (check.run then tests their independence). Calls run `jobs` at a time (a batch command: the passes split into `jobs` calls)."""
        with tempfile.TemporaryDirectory(prefix="validate-") as tmp:
            folder = Path(tmp)
            if "," in str(folder) and self.batch:
                raise RendererError(f"the temporary folder '{folder}' holds a comma: {{outputs}} cannot list it")
            self.write_scene(plan, spp, folder / "scene")
            outputs = [folder / f"pass{k}.exr" for k in range(passes)]
            calls = ([list(c) for c in _chunks(range(passes), self.jobs)] if self.batch else [[k] for k in range(passes)])
            argvs = [(self.command(plan, [outputs[k] for k in c], spp, [seed + k for k in c], folder / "scene"), c)
                     for c in calls]
            with ThreadPoolExecutor(max_workers=self.jobs) as pool:
                for future in [pool.submit(self._run, argv, c[0]) for argv, c in argvs]:
                    future.result()
            return np.stack([_read_pass(outputs[k], plan, k) for k in range(passes)])

    def _run(self, argv: list[str], k: int) -> None:
        """Runs the call of pass k (the first of its batch) in a session of its own (so that a timeout ends its
        children too)."""
        try:
            proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                    errors="replace", start_new_session=True)
        except OSError as e:
            raise RendererError(f"renderer command '{argv[0]}' could not run: {e.strerror}") from None
        try:
            out, err = proc.communicate(timeout=self.timeout)
        except subprocess.TimeoutExpired:
            _kill_session(proc)
            raise RendererTimeout(f"renderer did not finish pass {k} within --timeout {self.timeout:g} s (stopped)") \
                from None
        except BaseException:
            _kill_session(proc)
            raise
        if proc.returncode < 0:
            raise RendererError(f"renderer was killed by signal {_signal_name(-proc.returncode)} on pass {k}")
        last = (err.strip() or out.strip() or "no output").splitlines()[-1][:300]
        if proc.returncode == EXIT_UNSUPPORTED:
            raise RendererUnsupported(last)
        if proc.returncode != 0:
            raise RendererError(f"renderer exited with status {proc.returncode} on pass {k}: {last}")


def _chunks(items: range, n: int) -> list[range]:
    """`items` in at most n contiguous runs of near-equal length."""
    n = min(n, len(items))
    bounds = [round(i * len(items) / n) for i in range(n + 1)]
    return [items[a:b] for a, b in zip(bounds, bounds[1:])]


def independence(images: np.ndarray, noisy: bool = True, alpha: float = INDEPENDENCE_ALPHA) -> None:
    """Refuses passes that are not independent draws: two identical passes where the image is `noisy` (Mitsuba's
    passes differ: a seed ignored), or a pair more correlated than chance allows. For passes i, j and two others a, b, the differences p_i - p_a and
    p_j - p_b of independent, identically distributed passes are independent and symmetric about 0, so their
    product is positive with probability exactly 1/2 in every pixel, whatever the pixels' distribution; a
    correlation between i and j (or a and b) makes it more often positive. A one-sided sign test over the
    pixels (channels summed) for each pair, Bonferroni over the K(K-1)/2 pairs at level `alpha`. A correlation shared
    equally by all pairs (a pattern common to every pass) cancels in the differences and is not seen; README
    says so."""
    k = len(images)
    flat = images.reshape(k, -1).astype(np.float64)
    pixels = images.sum(-1).reshape(k, -1).astype(np.float64)   # a pixel's channels share its paths: one value
    for i in range(k):
        for j in range(i + 1, k):
            if noisy and np.array_equal(flat[i], flat[j]):
                raise RendererError(f"passes {i} and {j} are identical: the renderer must draw different samples "
                                    "for different seeds ({seed}, {seeds})")
    if k < 4:
        return
    pairs = k * (k - 1) // 2
    limit = -_normal_quantile(alpha / pairs)
    for i in range(k):
        for j in range(i + 1, k):
            a, b = [m for m in range(k) if m not in (i, j)][:2]
            product = (pixels[i] - pixels[a]) * (pixels[j] - pixels[b])
            n = int(np.count_nonzero(product))
            if n < 16:
                continue
            positive = int((product > 0).sum())
            z = (positive - 0.5 * n - 0.5) / (0.5 * math.sqrt(n))      # continuity-corrected
            if z > limit:
                raise RendererError(
                    f"passes {i} and {j} (or {a} and {b}) are correlated: the product of their differences is "
                    f"positive in {positive / n:.1%} of {n} pixels (1/2 for independent passes; sign test "
                    f"z = {z:.1f} > {limit:.1f}); the renderer must draw independent samples for different seeds")


def _normal_quantile(p: float) -> float:
    from scipy.special import ndtri

    return float(ndtri(p))


def _kill_session(proc: subprocess.Popen) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()


def _signal_name(number: int) -> str:
    try:
        return signal.Signals(number).name
    except ValueError:
        return str(number)


def _read_pass(output: Path, plan: ScenePlan, k: int) -> np.ndarray:
    """Pass k's image as the renderer wrote it, refused in one line unless usable."""
    from tracer.imageio import read_exr

    if not output.is_file():
        raise RendererError(f"renderer exited 0 but wrote no {{output}} file on pass {k}")
    with output.open("rb") as f:
        magic = f.read(8)
    if magic.startswith(b"\x89PNG"):
        raise RendererError(f"renderer wrote a PNG on pass {k}; {{output}} must be an OpenEXR image (linear radiance)")
    if not magic.startswith(b"\x76\x2f\x31\x01"):
        raise RendererError(f"renderer wrote a file on pass {k} that is not an OpenEXR image (no EXR magic number)")
    try:
        image = read_exr(output)
    except Exception as e:     # whatever OpenEXR raises on a truncated or corrupted file
        raise RendererError(f"renderer wrote an unreadable OpenEXR image on pass {k} ({type(e).__name__}: "
                            f"{str(e)[:200]}); truncated?") from None
    if image.ndim != 3 or image.shape[:2] != (plan.height, plan.width):
        raise RendererError(f"renderer wrote {image.shape[1]} x {image.shape[0]} pixels on pass {k}, the plan is "
                            f"{plan.width} x {plan.height} (it must honour -D width=... -D height=..., or check "
                            "with --size native)")
    bad = ~np.isfinite(image[..., :3])
    if bad.any():
        raise RendererError(f"renderer wrote {int(bad.any(axis=-1).sum())} pixels with NaN or infinite values on pass "
                            f"{k}: a correct render has none")
    return image[..., :3].astype(np.float32)
