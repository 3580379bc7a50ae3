"""The errors a user can act on: the command line prints their message in one line, without a traceback.

Anything else that escapes a render is a bug in the tracer, and `tracer` shows its traceback.
The loader's `SceneError` (tracer.scene) is the scene file's member of this family.
"""
from __future__ import annotations


class UserError(Exception):
    """A request the tracer refuses before (or instead of) doing the work; the message says why and what
    would be accepted."""


class SettingsError(UserError, ValueError):
    """A render argument out of its domain (spp, seed, max_depth, estimator options, ...)."""


class PlanError(UserError, ValueError):
    """A render that cannot succeed as asked (memory, sample counts), refused before its first ray."""


class OutputError(UserError, OSError):
    """An output path that cannot be written."""


class BackendError(UserError, RuntimeError):
    """Dr.Jit's backend is unavailable: no or too old an LLVM, CUDA without a GPU."""
