"""The errors a user can act on: the command line prints their message in one line, without a traceback.

Anything else that escapes a render is a bug in the tracer, and `tracer` shows its traceback.
The loader's `SceneError` (tracer.scene) is the scene file's member of this family.
"""
from __future__ import annotations

import re


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


CLIP = 60            # characters of a quoted value in a message, beyond which its middle is left out
LONG_WORD = 300      # characters of an unquoted word (a path) beyond which it is clipped too
_LONG = re.compile(r"'[^'\n]{%d,}'|\"[^\"\n]{%d,}\"|[^\s'\"]{%d,}" % (CLIP + 1, CLIP + 1, LONG_WORD + 1))


def clip(value: object, limit: int = CLIP) -> str:
    """`value` as text, its middle left out when longer than `limit` (a 20,000-character value is not
    repeated whole in a one-line error)."""
    text = str(value)
    if len(text) <= limit:
        return text
    keep = max(limit - 20, 10)
    return f"{text[:keep]}...({len(text) - keep - 15:,} characters)...{text[-15:]}"


def shorten(message: str, limit: int = 500) -> str:
    """A message longer than `limit` with each long quoted value and each very long word clipped."""
    if len(message) <= limit:
        return message

    def repl(m: re.Match) -> str:
        text = m[0]
        if text[0] in "'\"":
            return text[0] + clip(text[1:-1]) + text[0]
        return clip(text, LONG_WORD)
    return _LONG.sub(repl, message)


class OutOfMemory(UserError, MemoryError):
    """A render that ran out of memory: stopped, with the passes it had completed in `partial` (a RenderResult,
    None when no pass was complete)."""

    def __init__(self, message: str, partial=None):
        super().__init__(message)
        self.partial = partial
