"""numba's ``njit``, whose on-disk cache the processes of a machine share without compiling a
kernel twice.

numba caches a compiled kernel on disk (``NUMBA_CACHE_DIR``, or beside its source) and every
process loads it from there; but two processes that both miss the cache both compile, and a
sweep's workers, a Dask cluster's on one file system or two commands started together all
begin with the same kernels. :func:`njit` is numba's, with the cache of a ``cache=True``
kernel replaced by :class:`LockedCache`: a process that misses takes an exclusive lock on the
kernel (a ``.lock`` file beside its index), looks again, and compiles only if the kernel is
still not there, holding the lock until the compilation is saved or has failed. A process that
waited loads what the other compiled. Kernels call each other along an acyclic graph, and a
process holds the locks of the kernels it is compiling along one path of it, so two processes
cannot wait for each other.

Every compiled kernel of the package is made with :func:`njit`; a plugin's kernels may use it
too (``from formation_bench.kernel_cache import njit``), and work as well with numba's own.
"""

from __future__ import annotations

import fcntl
from collections.abc import Callable
from typing import IO, Any

import numba
from numba.core import event
from numba.core.caching import FunctionCache

LOCK_SUFFIX = ".lock"
"""A kernel's lock file: its index file's name with this ending, in the same folder."""


class LockedCache(FunctionCache):
    """numba's cache of one function, whose compilations one process of the machine makes at a
    time (see the module docstring)."""

    def __init__(self, py_func: Callable[..., Any]) -> None:
        super().__init__(py_func)
        self._held: IO[bytes] | None = None

    def load_overload(self, sig: Any, target_context: Any) -> Any:
        loaded = super().load_overload(sig, target_context)
        if loaded is not None or not self._enabled or self._held is not None:
            return loaded
        lock = self._open_lock()  # waits while another process compiles the kernel
        if lock is None:  # a cache folder this process cannot lock in: numba's own behaviour
            return None
        loaded = super().load_overload(sig, target_context)
        if loaded is not None:
            _release(lock)
            return loaded
        self._held = lock  # until the compilation is saved (save_overload) or has failed
        _FAILED_COMPILES.register()
        return None

    def save_overload(self, sig: Any, data: Any) -> None:
        try:
            super().save_overload(sig, data)
        finally:
            self.release()

    def release(self) -> None:
        """Let other processes look for the kernel again (it is saved, or will not be)."""
        lock, self._held = self._held, None
        if lock is not None:
            _release(lock)

    def _open_lock(self) -> IO[bytes] | None:
        """The kernel's lock file, locked (after waiting while another process holds it);
        None where the cache folder cannot be written or locked (a file system without
        ``flock``)."""
        try:
            self._impl.locator.ensure_cache_path()
            lock = open(self._cache_file._index_path + LOCK_SUFFIX, "ab")
        except (OSError, AttributeError):
            return None
        try:
            fcntl.flock(lock, fcntl.LOCK_EX)
        except OSError:
            lock.close()
            return None
        return lock


def _release(lock: IO[bytes]) -> None:
    try:
        fcntl.flock(lock, fcntl.LOCK_UN)
    finally:
        lock.close()


class _FailedCompiles(event.Listener):
    """Releases the lock of a kernel whose compilation raised: numba then saves nothing, and
    the other processes must not wait for this one to exit."""

    def __init__(self) -> None:
        self.registered = False

    def register(self) -> None:
        """Listen to numba's compile events, once per process."""
        if not self.registered:
            event.register("numba:compile", self)
            self.registered = True

    def on_start(self, ev: event.Event) -> None:
        pass

    def on_end(self, ev: event.Event) -> None:
        dispatcher = ev.data.get("dispatcher")
        cache = getattr(dispatcher, "_cache", None)
        # a compilation that succeeded has added its overload before this event ends
        if isinstance(cache, LockedCache) and tuple(ev.data["args"]) not in dispatcher.overloads:
            cache.release()


_FAILED_COMPILES = _FailedCompiles()


def locked(dispatcher: Any) -> Any:
    """``dispatcher`` (a numba ``njit`` function) with a :class:`LockedCache` in place of
    numba's, if it caches; returned as it is otherwise."""
    if type(getattr(dispatcher, "_cache", None)) is FunctionCache:
        dispatcher._cache = LockedCache(dispatcher.py_func)
    return dispatcher


def njit(*args: Any, **options: Any) -> Any:
    """``numba.njit``, taking the same arguments, with a locked cache when ``cache=True``."""
    if args and callable(args[0]) and not isinstance(args[0], str):
        return locked(numba.njit(*args, **options))
    decorate = numba.njit(*args, **options)
    return lambda func: locked(decorate(func))


__all__ = ["LOCK_SUFFIX", "LockedCache", "locked", "njit"]
