"""Telling an interrupted run from a failed one.

Ctrl-C (or SIGTERM, which the sweeps turn into KeyboardInterrupt) raises its exception at
the next Python bytecode. During a compiled kernel that is numba boxing the kernel's
returned arrays, which runs a small Python function: the interrupt surfaces there and numba's
dispatcher reports it as a ``SystemError`` ("returned a result with an exception set") whose
cause chain holds the ``KeyboardInterrupt``. Most of a run is spent in compiled kernels, so
this is the usual way an interrupt arrives.
"""

from __future__ import annotations


def is_interrupt(error: BaseException) -> bool:
    """Whether ``error`` is a KeyboardInterrupt or was caused by one (through numba)."""
    seen: set[int] = set()
    current: BaseException | None = error
    while current is not None and id(current) not in seen:
        if isinstance(current, KeyboardInterrupt):
            return True
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return False
