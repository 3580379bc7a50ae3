"""The time Dr.Jit spends generating and compiling kernels during a render, read from its kernel history.

The history keeps a copy of every launched kernel's source until it is read: tens of kilobytes a kernel,
and a launch bounce by bounce through a BVH makes thousands (the batched walks' steps), so a history left
on over a whole render held hundreds of megabytes more after every launch, without bound. A running
`CompileClock` instead sums and clears the history at every launch and bounce (`lap`), and keeps only
the sum.
"""
from __future__ import annotations

import drjit as dr

_running: list["CompileClock"] = []    # the clocks now running, outermost first


class CompileClock:
    """`with CompileClock() as clock:` ... `clock.seconds`, Dr.Jit's codegen and backend time of the kernels
    launched within (nested clocks each count their own; the history is on while any runs)."""

    def __init__(self):
        self.seconds = 0.0
        self._flag = False

    def __enter__(self) -> "CompileClock":
        if _running:
            lap()
        else:
            self._flag = dr.flag(dr.JitFlag.KernelHistory)
            dr.set_flag(dr.JitFlag.KernelHistory, True)
            dr.kernel_history()    # clears what came before
        _running.append(self)
        return self

    def __exit__(self, *exc) -> None:
        lap()
        _running.remove(self)
        if not _running:
            dr.set_flag(dr.JitFlag.KernelHistory, self._flag)


def lap() -> None:
    """Adds the kernel history's codegen and backend time to every running clock and clears it; nothing
    while no clock runs. Called between launches and between a wavefront's bounces."""
    if _running:
        history = dr.kernel_history()
        seconds = sum(k.get("codegen_time", 0) + k.get("backend_time", 0) for k in history) / 1000
        for clock in _running:
            clock.seconds += seconds
