"""Built-in peers for `validate check --renderer cycles|luxcore`: production renderers configured to estimate
Mitsuba's `path` integral (README "Peers"; reports/peers.md).

The scene goes to the peer as `{scene_json}` (validation.verdict.scenejson: the tracer's loader reads it, so its
refusals come first), and the peer's worker (cycles_worker.py, luxcore_worker.py) converts it through the peer's Python
API and renders every pass of a check in one process of the peers' own Python: bpy needs NumPy 1.x, the
project NumPy 2, so the peers live in a virtual environment of their own (`scripts/setup.sh --peers`
creates `<venv>-peers`; `VALIDATE_PEERS_PYTHON` names another interpreter). What a peer cannot express is
refused in one line before any pass (support.refusal) and reported as skipped: unsupported.
"""
from __future__ import annotations

import json
import os
import shlex
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from ..renderers import ExternalRenderer, RendererUnsupported
from ..scenefile import ScenePlan, ScenePlanError
from .support import MISTAKES, refusal

PEERS = ("cycles", "luxcore")
PYTHON_VARIABLE = "VALIDATE_PEERS_PYTHON"
WORKERS = Path(__file__).parent


def python() -> Path:
    """The peers' interpreter: $VALIDATE_PEERS_PYTHON, else the project environment's sibling `<venv>-peers`."""
    if os.environ.get(PYTHON_VARIABLE):
        return Path(os.environ[PYTHON_VARIABLE])
    return Path(sys.prefix + "-peers") / "bin" / "python"


@dataclass(frozen=True)
class PeerRenderer(ExternalRenderer):
    """A built-in peer: an ExternalRenderer whose command is the peer's worker, in the batch form."""
    peer: str = "cycles"
    mistake: str | None = None      # an injected conversion mistake (support.MISTAKES), for the check's power

    @classmethod
    def named(cls, peer: str, timeout: float | None = None, mistake: str | None = None) -> PeerRenderer:
        if peer not in PEERS:
            raise ScenePlanError(f"no built-in renderer '{peer}' (built in: {', '.join(PEERS)})")
        if mistake is not None and mistake not in MISTAKES:
            raise ScenePlanError(f"no mistake '{mistake}' (mistakes: {', '.join(MISTAKES)})")
        exe = python()
        if not exe.is_file():
            raise ScenePlanError(f"--renderer {peer}: the peers' Python '{exe}' does not exist: install the peers "
                                 f"with `bash scripts/setup.sh --peers` (or set {PYTHON_VARIABLE})")
        template = (f"{shlex.quote(str(exe))} {shlex.quote(str(WORKERS / (peer + '_worker.py')))} {{scene_json}} "
                    f"--spp {{spp}} --seeds {{seeds}} --outputs {{outputs}}" + (f" --mistake {mistake}" if mistake else ""))
        label = peer + (f" (mistake: {mistake})" if mistake else "")
        return cls(template, timeout, label, 1, peer, mistake)

    def prepare(self, plan: ScenePlan, spp: int, seed: int) -> None:
        """The loader's refusals, then the peer's: what it cannot express, in one line (RendererUnsupported)."""
        super().prepare(plan, spp, seed)
        from ..scenejson import write

        with tempfile.TemporaryDirectory(prefix="validate-peer-") as tmp:
            why = refusal(json.loads(write(plan, Path(tmp)).read_text()), self.peer)
        if why:
            raise RendererUnsupported(f"{self.peer}: {why}")
