"""What the adapters share: importing an optional library, seeding it, costs it can digest."""

from __future__ import annotations

import contextlib
import importlib
import importlib.util
import math
from collections.abc import Iterator
from types import ModuleType

import numpy as np

EXTRA = "adapters"
"""The extra that installs every adapted library."""

INSTALL_HINT = f'pip install -c requirements/lock.txt ".[{EXTRA}]" in a clone of formation-bench'
"""How to install the extra: from a clone (the package is not on an index), at the locked
versions (nevergrad's NGOpt needs the lock's numpy)."""


def library_available(module: str) -> bool:
    """True when ``module`` can be found, without importing it (the libraries are slow to load)."""
    return importlib.util.find_spec(module) is not None


def import_library(module: str, adapter: str) -> ModuleType:
    """Import ``module`` for the adapter ``adapter``, or fail naming the extra to install."""
    try:
        # nevergrad draws from numpy's global random state while it is imported
        with global_random_state_kept():
            return importlib.import_module(module)
    except ImportError as err:
        raise ImportError(
            f"{adapter} needs the {module!r} package, which is not installed: {INSTALL_HINT}"
        ) from err


@contextlib.contextmanager
def global_random_state_kept() -> Iterator[None]:
    """Puts numpy's global random state back as it was, around library code that draws from it.

    A solve draws from the passed Generator only, so it leaves the caller's global
    state as it found it, whatever the adapted library does.
    """
    state = np.random.get_state()  # noqa: NPY002 - kept to be put back, never drawn from
    try:
        yield
    finally:
        np.random.set_state(state)  # noqa: NPY002


class SolveGlobalRandomState:
    """numpy's global random state as a solve's library code sees it.

    Some library code draws from numpy's global state however it is seeded (nevergrad's
    meta-model builds optimisers that seed themselves from it). Inside :meth:`active` the
    global state is the solve's own, seeded from ``seed`` and carried from call to call;
    outside it, the caller's is put back. So those draws depend on the solve's seed alone,
    and the caller's global state is left as it was.
    """

    def __init__(self, seed: int) -> None:
        # MT19937 through a SeedSequence: not the stream of RandomState(seed), which the
        # library may be given as well
        generator = np.random.MT19937(np.random.SeedSequence(seed))
        self._state = np.random.RandomState(generator).get_state()

    @contextlib.contextmanager
    def active(self) -> Iterator[None]:
        caller = np.random.get_state()  # noqa: NPY002 - kept to be put back, never drawn from
        np.random.set_state(self._state)  # noqa: NPY002
        try:
            yield
        finally:
            self._state = np.random.get_state()  # noqa: NPY002
            np.random.set_state(caller)  # noqa: NPY002


def library_seed(rng: np.random.Generator) -> int:
    """A seed for a library's own generator, drawn from ``rng`` (same rng, same seed).

    Below 2**31 - 1 so that every library takes it (legacy ``RandomState`` takes
    up to 2**32 - 1, some C code 32-bit signed integers).
    """
    return int(rng.integers(2**31 - 1))


def finite_costs(costs: np.ndarray, worst: float) -> tuple[np.ndarray, float]:
    """``costs`` with ``+inf`` replaced by a finite penalty, and the worst finite cost so far.

    The evaluation counter maps NaN and -inf to +inf; libraries that fit models
    to the costs (nevergrad's meta-models) or warn on infinite ones want finite
    numbers, and the penalty (above every finite cost seen so far in the solve)
    keeps the ranking the counter's +inf gives. ``worst`` is ``-inf`` before any
    finite cost was seen.
    """
    finite = np.isfinite(costs)
    if finite.any():
        worst = max(worst, float(costs[finite].max()))
    if finite.all():
        return costs, worst
    penalty = 1.0 if math.isinf(worst) else worst + abs(worst) + 1.0
    return np.where(finite, costs, penalty), worst


class LibraryIncompatibility(RuntimeError):
    """A known failure of an adapted library with the installed version of another one.

    Raised instead of the library's own error, naming both versions and what to do.
    """
