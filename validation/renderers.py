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

import shlex
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
        from tracer.imageio import read_exr

        images = []
        with tempfile.TemporaryDirectory(prefix="validate-") as tmp:
            for k in range(passes):
                output = Path(tmp) / f"pass{k}.exr"
                argv = self.command(plan, output, spp, seed + k)
                try:
                    done = subprocess.run(argv, capture_output=True, text=True)
                except OSError as e:
                    raise RendererError(f"renderer command '{argv[0]}' could not run: {e.strerror}") from None
                if done.returncode != 0:
                    last = (done.stderr.strip() or done.stdout.strip() or "no output").splitlines()[-1]
                    raise RendererError(f"renderer exited with status {done.returncode} on pass {k}: {last}")
                if not output.is_file():
                    raise RendererError(f"renderer exited 0 but wrote no {{output}} file ({' '.join(argv)})")
                image = read_exr(output)
                if image.shape[:2] != (plan.height, plan.width):
                    raise RendererError(f"renderer wrote {image.shape[1]} x {image.shape[0]} pixels, the plan is "
                                        f"{plan.width} x {plan.height} (it must honour -D width=... -D height=..., or check with --size native)")
                images.append(image[..., :3].astype(np.float32))
        return np.stack(images)
