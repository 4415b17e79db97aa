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
"""The extra that installs every adapted library: ``pip install "formation-bench[adapters]"``."""

INSTALL_HINT = f'pip install "formation-bench[{EXTRA}]"'


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
