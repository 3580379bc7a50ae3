"""The renderers a comparison runs, each giving independent passes of a planned scene.

- `TracerRenderer`: the tracer's `path` or branching (`report`) estimator, through its public API;
- `MitsubaRenderer`: Mitsuba 3's `path` integrator, the ground truth;
- `ExternalRenderer`: any command that renders a scene file to an EXR (a student's renderer, another tool),
  given as a template with the placeholders {scene}, {output}, {spp}, {seed} and {defines}.

`passes(plan, passes, spp, seed)` returns a (passes, height, width, 3) float32 array; pass k uses seed
`seed + k` (Mitsuba: `seed * 1_000_003 + k`, as validation.mitsuba_render), so two uses with different seed
bases (validation.protocol) never share a stream.
"""
from __future__ import annotations

import contextlib
import os
import shlex
import signal
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tracer.errors import UserError

from .scenefile import ScenePlan, ScenePlanError

PLACEHOLDERS = ("scene", "output", "spp", "seed", "defines")


class RendererError(UserError, RuntimeError):
    """The renderer under test failed or wrote something unusable (reported in one line)."""


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
    timeout: float | None = None       # seconds a pass may take (--timeout); None: no limit

    def __post_init__(self):
        if "{output}" not in self.template:
            raise ScenePlanError(f"--renderer '{self.template}': the command must contain {{output}} (the EXR "
                                 f"it writes); placeholders: {', '.join('{' + p + '}' for p in PLACEHOLDERS)}")
        try:
            self.template.format(**{p: "" for p in PLACEHOLDERS})
        except (KeyError, IndexError, ValueError) as e:
            raise ScenePlanError(f"--renderer '{self.template}': bad placeholder {e}; the placeholders are "
                                 f"{', '.join('{' + p + '}' for p in PLACEHOLDERS)}") from None

    @property
    def label(self) -> str:
        return f"external: {self.template}"

    def command(self, plan: ScenePlan, output: Path, spp: int, seed: int) -> list[str]:
        defines = " ".join(f"-D {shlex.quote(d)}" for d in plan.defines(spp))
        return shlex.split(self.template.format(scene=shlex.quote(str(plan.path)), output=shlex.quote(str(output)),
                                                spp=spp, seed=seed, defines=defines))

    def passes(self, plan: ScenePlan, passes: int, spp: int, seed: int) -> np.ndarray:
        """The passes, each checked: the command ran, ended in time with status 0, and wrote a readable
        OpenEXR image of the plan's size with finite pixels. Anything else is a RendererError naming the pass;
        what it wrote is removed with the temporary folder and never reaches a cache."""
        images = []
        with tempfile.TemporaryDirectory(prefix="validate-") as tmp:
            for k in range(passes):
                output = Path(tmp) / f"pass{k}.exr"
                self._run(self.command(plan, output, spp, seed + k), k)
                images.append(_read_pass(output, plan, k))
        return np.stack(images)

    def _run(self, argv: list[str], k: int) -> None:
        """Runs pass k's command in a session of its own (so that a timeout ends its children too)."""
        try:
            proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                    errors="replace", start_new_session=True)
        except OSError as e:
            raise RendererError(f"renderer command '{argv[0]}' could not run: {e.strerror}") from None
        try:
            out, err = proc.communicate(timeout=self.timeout)
        except subprocess.TimeoutExpired:
            _kill_session(proc)
            raise RendererError(f"renderer did not finish pass {k} within --timeout {self.timeout:g} s (stopped)") \
                from None
        except BaseException:
            _kill_session(proc)
            raise
        if proc.returncode < 0:
            raise RendererError(f"renderer was killed by signal {_signal_name(-proc.returncode)} on pass {k}")
        if proc.returncode != 0:
            last = (err.strip() or out.strip() or "no output").splitlines()[-1]
            raise RendererError(f"renderer exited with status {proc.returncode} on pass {k}: {last[:300]}")


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
