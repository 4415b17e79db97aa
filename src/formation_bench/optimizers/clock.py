"""The clock a solve's deadline is read from, in Python and inside compiled blocks alike.

A compiled block of iterations checks a deadline before each iteration, so a method whose
iterations are short loses no more of its deadline to the check than one whose iterations are
long. numba cannot call ``time.perf_counter`` in compiled code, so the block reads the clock
the way Python does: it calls the C library's ``clock_gettime`` with ``CLOCK_MONOTONIC``
(about 22 ns a read, through the vDSO on Linux). The function's address comes from ``ctypes``
and reaches the block as an argument, as a compiled cost's does
(:mod:`~formation_bench.optimizers.compiled`): a compiled function that embedded the address
could not be cached by numba.

Any function with ``clock_gettime``'s C signature is a clock (:class:`Clock`); a test can make
one from a Python function (:func:`python_clock`) and set it as :data:`SOLVE_CLOCK`, so that
what a deadline ends is decided by a clock it drives, not by the machine's load.
"""

from __future__ import annotations

import ctypes
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from formation_bench.kernel_cache import njit
from formation_bench.optimizers.compiled import UNLIMITED


class Timespec(ctypes.Structure):
    """C's ``struct timespec`` (``time_t`` and ``long`` are 64-bit on the supported systems)."""

    _fields_ = [("tv_sec", ctypes.c_int64), ("tv_nsec", ctypes.c_int64)]


CLOCK_FUNCTION = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_int, ctypes.POINTER(Timespec))
"""``int clock_gettime(clockid_t clock, struct timespec *now)``, the signature of a clock."""

NEVER = UNLIMITED
""":attr:`Deadline.at_ns` of a solve without a deadline (no clock is read)."""


@dataclass(frozen=True)
class Clock:
    """A clock read through a C function with :data:`CLOCK_FUNCTION`'s signature."""

    address: int
    """Address of the function; valid while ``owner`` lives."""
    clock_id: int
    """The clock the function is asked for (its first argument)."""
    owner: Any = None
    """What keeps the function alive (a ``ctypes`` function or callback)."""

    def now_ns(self) -> int:
        """The clock's time in nanoseconds, read by the same call a compiled block makes."""
        return int(read_clock(self.address, self.clock_id))


def monotonic_clock() -> Clock:
    """The C library's ``clock_gettime`` on ``CLOCK_MONOTONIC``: the clock of
    ``time.monotonic_ns``, which no change of the system's time moves."""
    function = ctypes.CDLL(None).clock_gettime
    address = ctypes.cast(function, ctypes.c_void_p).value
    assert address is not None
    return Clock(address, time.CLOCK_MONOTONIC, function)


def python_clock(now_ns: Callable[[], int]) -> Clock:
    """A clock whose time is ``now_ns()``, for a test that decides when time passes."""

    def read(clock_id: int, now: Any) -> int:
        ns = int(now_ns())
        now.contents.tv_sec, now.contents.tv_nsec = divmod(ns, 1_000_000_000)
        return 0

    callback = CLOCK_FUNCTION(read)
    address = ctypes.cast(callback, ctypes.c_void_p).value
    assert address is not None
    return Clock(address, 0, callback)


SOLVE_CLOCK = monotonic_clock()
"""The clock every solve's deadline is read from (:func:`solve_deadline`)."""


class Deadline(NamedTuple):
    """When a solve must stop: a time on a clock that compiled code reads."""

    clock: Clock
    """The clock."""
    at_ns: int
    """The clock's time at the deadline, ns; :data:`NEVER`: no deadline."""

    def passed(self) -> bool:
        """Whether the deadline has come (False without one, and no clock is read)."""
        return self.at_ns != NEVER and self.clock.now_ns() >= self.at_ns


def solve_deadline(deadline_s: float | None) -> Deadline:
    """The deadline ``deadline_s`` seconds from now on :data:`SOLVE_CLOCK` (a solve calls it
    as it begins); None: no deadline."""
    clock = SOLVE_CLOCK
    if deadline_s is None:
        return Deadline(clock, NEVER)
    return Deadline(clock, clock.now_ns() + round(deadline_s * 1e9))


@intrinsic
def _call_clock(typingctx, address, clock_id):  # type: ignore[no-untyped-def]
    """The time, ns, of the clock function at ``address`` asked for ``clock_id``."""
    if not (isinstance(address, types.Integer) and isinstance(clock_id, types.Integer)):
        return None
    sig = types.int64(address, clock_id)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        address_v, clock_id_v = args
        i32, i64 = ir.IntType(32), ir.IntType(64)
        timespec = ir.LiteralStructType([i64, i64])
        now = cgutils.alloca_once(builder, timespec)
        fn_type = ir.FunctionType(i32, [i32, timespec.as_pointer()])
        fn = builder.inttoptr(address_v, fn_type.as_pointer())
        builder.call(fn, [builder.trunc(clock_id_v, i32), now])
        seconds = builder.load(cgutils.gep_inbounds(builder, now, 0, 0))
        nanoseconds = builder.load(cgutils.gep_inbounds(builder, now, 0, 1))
        return builder.add(builder.mul(seconds, i64(1_000_000_000)), nanoseconds)

    return sig, codegen


@njit(cache=True, inline="always")
def read_clock(address: int, clock_id: int) -> int:
    """The time, ns, of the clock at ``address`` (a :class:`Clock`'s), from compiled code."""
    return _call_clock(address, clock_id)
