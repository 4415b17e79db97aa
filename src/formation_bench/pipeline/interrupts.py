"""Telling an interrupted run from a failed one, and raising an interrupt only where Python
can take it.

Ctrl-C (or SIGTERM, which the sweeps turn into KeyboardInterrupt) raises its exception at
the next Python bytecode. During a compiled kernel that would be numba boxing the kernel's
returned arrays: numba fetches each array's Python type by calling a small Python function
(``numba.core.serialize._numba_unpickle``) and does not check whether that call failed. An
exception raised there leaves the boxing in no defined state: it reached Python as a
``SystemError`` ("returned a result with an exception set") holding the interrupt, or, at a
compiled function's first return (numba's lookup of the type not yet memoised, so the next
array's lookup catches a ``KeyError``, which replaces the interrupt), it was lost and the
call returned a tuple holding ``NULL``: a segmentation fault when Python read it. Unboxing a
numpy ``Generator`` for a compiled draw, numba calls ``ctypes.cast`` three times, and numpy
builds the bit generator's ctypes interface in Python (``ctypes.CFUNCTYPE``, a namedtuple),
and each result is read unchecked: an exception raised inside one is a segmentation fault at
once.
llvmlite's object-cache callbacks, which numba's compiler runs, print and drop an exception
raised in them, so a Ctrl-C there was lost, and its bindings mark an LLVM object handed to
LLVM as owned a statement after the C call that hands it over (an exception between them
frees it twice). And CPython (3.11) marks a KeyboardInterrupt that
leaves code run by ``exec`` or ``eval`` of a string as unhandled even when a caller catches
it, and ends the process by SIGINT at exit (-2 instead of 130): libraries exec strings while
they import (scipy's array API module does, when numba loads its cache).
:func:`raise_interrupt` therefore raises only outside such places (:func:`unsafe_to_raise`);
inside one it asks for the signal again a moment later, when Python is back in ordinary code.
Python itself prints and discards an exception raised in a weakref callback, a ``__del__``
or a garbage-collector callback (importlib runs one whenever a module lock is freed), which
no frame test can tell apart: a KeyboardInterrupt discarded there is delivered again instead
(:func:`raise_keyboard_interrupt`).
"""

from __future__ import annotations

import _thread
import contextlib
import ctypes
import os
import signal
import sys
import threading
from collections.abc import Iterator
from types import CodeType, FrameType
from typing import Any, NoReturn

AGAIN_AFTER_S = 0.001
"""How long after a signal that found Python where raising is unsafe it is delivered again:
a compiled call's callback returns within microseconds, an executed string within
milliseconds."""


def is_interrupt(error: BaseException) -> bool:
    """Whether ``error`` is a KeyboardInterrupt or was caused by one: C code that calls Python
    wraps an exception in its own (numba a ``SystemError``, CPython a ``RuntimeError`` from a
    ``__set_name__`` during an import), so the commands test every error with this."""
    seen: set[int] = set()
    current: BaseException | None = error
    while current is not None and id(current) not in seen:
        if isinstance(current, KeyboardInterrupt):
            return True
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return False


def _unchecked_callbacks() -> set[CodeType]:
    """The Python functions that compiled code calls without checking for an exception (a
    library not imported has run no compiled code): numba's type lookup while it boxes an
    array, and what its unboxing of a numpy ``Generator`` runs in Python and then reads
    unchecked (a segmentation fault): ``ctypes.cast``, which it calls three times, and, the
    first time a bit generator's ctypes interface is asked for (every new Generator's),
    numpy's ``ctypes.CFUNCTYPE`` calls and the interface namedtuple's ``__new__``."""
    serialize = sys.modules.get("numba.core.serialize")
    if serialize is None:
        return set()
    unchecked = {serialize._numba_unpickle.__code__, ctypes.cast.__code__}
    unchecked.add(ctypes.CFUNCTYPE.__code__)
    common = sys.modules.get("numpy.random._common")
    interface = getattr(common, "interface", None)
    if interface is not None:
        unchecked.add(interface.__new__.__code__)
    return unchecked


def _llvm_bindings() -> str | None:
    """The folder of llvmlite's bindings to LLVM, if loaded: they hand an LLVM object over
    with a C call and then mark it owned (``add_module``, then ``module._owned = True``), so an
    exception between the two makes Python and LLVM both free it, and they call back into
    Python from LLVM (the object cache), where an exception is printed and dropped."""
    bindings = sys.modules.get("llvmlite.binding")
    file = getattr(bindings, "__file__", None)
    return None if file is None else os.path.dirname(file) + os.sep


def _runs_a_string(frame: FrameType) -> bool:
    """Whether ``frame`` is the module-level code of an ``exec`` or ``eval`` of a string (the
    bottom frame is not: a ``python -c`` program is that, and its interrupt is unhandled)."""
    code = frame.f_code
    return (
        code.co_name == "<module>" and code.co_filename == "<string>" and frame.f_back is not None
    )


def unsafe_to_raise(frame: FrameType | None) -> bool:
    """Whether an exception raised at ``frame`` (where a signal found the main thread) would
    pass through a callback of compiled code that does not take it, llvmlite's bindings, or
    an executed string (:mod:`this module <formation_bench.pipeline.interrupts>`'s docstring)."""
    unchecked = _unchecked_callbacks()
    bindings = _llvm_bindings()
    while frame is not None:
        code = frame.f_code
        if code in unchecked or _runs_a_string(frame):
            return True
        if bindings is not None and code.co_filename.startswith(bindings):
            return True
        frame = frame.f_back
    return False


def interrupt_again_soon(signum: int) -> None:
    """Deliver ``signum`` to the main thread's Python handler again after
    :data:`AGAIN_AFTER_S` (unless the handler is by then ignoring it or Python's default)."""
    timer = threading.Timer(AGAIN_AFTER_S, _thread.interrupt_main, (signum,))
    timer.daemon = True
    timer.start()


class _DeliverDiscardedAgain:
    """``sys.unraisablehook`` around the one before it: a KeyboardInterrupt that Python
    discards is delivered again (and not printed); anything else goes to the previous hook."""

    def __init__(self, previous: Any) -> None:
        self.previous = previous

    def __call__(self, unraisable: Any) -> None:
        error = unraisable.exc_value
        if isinstance(error, BaseException) and is_interrupt(error):
            signum = _raised_for[0]
            _discarded.append(signum)
            interrupt_again_soon(signum)
            return
        self.previous(unraisable)


_raised_for: list[int] = [signal.SIGINT]
"""The signal the last KeyboardInterrupt raised by this module's handlers stood for."""
_discarded: list[int] = []
"""Signals whose KeyboardInterrupt Python discarded and which were asked for again."""


def raise_keyboard_interrupt(signum: int) -> NoReturn:
    """Raise KeyboardInterrupt for ``signum`` from a signal handler, such that if Python
    discards it (raised inside a weakref callback, a ``__del__`` or a garbage-collector
    callback, where Python prints and drops any exception), the signal is delivered again a
    moment later rather than lost."""
    if not isinstance(sys.unraisablehook, _DeliverDiscardedAgain):
        sys.unraisablehook = _DeliverDiscardedAgain(sys.unraisablehook)
    _raised_for[0] = signum
    raise KeyboardInterrupt


def delivered_again() -> bool:
    """Whether the signal a handler now handles is one whose KeyboardInterrupt Python
    discarded (a handler that drops repeated presses must raise it all the same)."""
    if _discarded:
        _discarded.pop()
        return True
    return False


def raise_interrupt(signum: int, frame: FrameType | None) -> None:
    """A signal handler: raise KeyboardInterrupt where the signal found the main thread, or,
    where that is unsafe, a moment later (:func:`unsafe_to_raise`)."""
    if unsafe_to_raise(frame):
        interrupt_again_soon(signum)
        return
    delivered_again()
    raise_keyboard_interrupt(signum)


@contextlib.contextmanager
def interrupts_where_safe() -> Iterator[None]:
    """Python's own Ctrl-C handler replaced by :func:`raise_interrupt` for the block, so a
    run started from a notebook or a script is interrupted as safely as the command's; a
    handler someone else installed is left alone, and so is a thread other than the main one.
    """
    if (
        threading.current_thread() is not threading.main_thread()
        or signal.getsignal(signal.SIGINT) is not signal.default_int_handler
    ):
        yield
        return
    signal.signal(signal.SIGINT, raise_interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)


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
