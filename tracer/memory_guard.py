"""A render that runs out of memory stops between launches, with the passes it has completed, instead of being
ended by the system's out-of-memory killer (exit 137, no message, nothing written) or failing with Dr.Jit's
allocation error mid-launch.

Linux grants allocations beyond the memory there is and kills the largest process when the pages are touched,
so waiting for an allocation to fail is not enough: between launches, a render whose machine has less than
RESERVE_BYTES available stops (tracer.rendering turns either into tracer.errors.OutOfMemory).
"""
from __future__ import annotations

from .plan import available_memory, gib, proc_bytes

RESERVE_BYTES = 256 << 20    # available memory below which a render stops (the killer acts near none)


class Exhausted(MemoryError):
    """Raised between launches when the machine's available memory fell below RESERVE_BYTES."""


def check() -> None:
    """Raises Exhausted when less than RESERVE_BYTES are available (called between launches)."""
    available = available_memory()
    if available < RESERVE_BYTES:
        raise Exhausted(f"{gib(available)} available, less than the {gib(RESERVE_BYTES)} a render keeps free")


def is_allocation_failure(error: BaseException) -> bool:
    """A MemoryError (NumPy's, Exhausted) or Dr.Jit's failed allocation (a RuntimeError saying so)."""
    return isinstance(error, MemoryError) or (isinstance(error, RuntimeError) and "out of memory" in str(error).lower())


def resident_bytes() -> int | None:
    """This process's resident memory (Linux's VmRSS), None where unknown."""
    return proc_bytes("/proc/self/status", "VmRSS")
