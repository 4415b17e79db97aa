"""Telling an interrupted run from a failed one.

Ctrl-C (or SIGTERM, which the sweeps turn into KeyboardInterrupt) raises its exception at
the next Python bytecode. During a compiled kernel that is numba boxing the kernel's
returned arrays, which runs a small Python function: the interrupt surfaces there and numba's
dispatcher reports it as a ``SystemError`` ("returned a result with an exception set") whose
cause chain holds the ``KeyboardInterrupt``. Most of a run is spent in compiled kernels, so
this is the usual way an interrupt arrives.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Iterator
from typing import Any


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


class interrupts_deferred:
    """Cleanup that a Ctrl-C (or SIGTERM) must not cut short, such as removing a partial
    folder or closing the workers after a first Ctrl-C.

    A signal arriving meanwhile is held back: if the block was already stopping for an
    interrupt (or any other exception), it is dropped, since the command is ending anyway;
    otherwise ``KeyboardInterrupt`` is raised once the block is done. Outside the main
    thread, where Python delivers no signals, this does nothing.
    """

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __enter__(self) -> None:
        self.noted = False
        self.previous: dict[int, Any] = {}
        if threading.current_thread() is not threading.main_thread():
            return
        for number in self.SIGNALS:
            self.previous[number] = signal.signal(number, self._note)

    def _note(self, signum: int, frame: object) -> None:
        self.noted = True

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        for number, handler in self.previous.items():
            if handler is not None:  # None: set outside Python, cannot be put back
                signal.signal(number, handler)
        if self.noted and exc_type is None and sys.exc_info()[0] is None:
            raise KeyboardInterrupt


@contextlib.contextmanager
def started_deaf_to_interrupts() -> Iterator[None]:
    """Processes started in this block ignore Ctrl-C from their first instruction.

    Ctrl-C reaches the whole process group, so a worker still importing its modules would
    die of it with a traceback before it could ignore it. An ignored signal stays ignored
    through fork and exec (a blocked one does not: process spawners reset the mask), and
    Python leaves an ignored SIGINT alone at start-up. This process keeps SIGINT blocked
    meanwhile, so a Ctrl-C pressed in the block stays pending instead of being discarded
    and is delivered (as KeyboardInterrupt) when the block ends.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    handler = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, handler if handler is not None else signal.SIG_DFL)
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
