"""The C cost kernel behind the compiled-objective handle, and the choice between kernels.

``_cost_kernel.c`` is :func:`formation_bench.mpc.cost.batch_cost` in C: the same packed
problem, the same calling convention and the same IEEE operations, so its costs are the
numba kernel's to the bit (a test checks this on every scenario family). It is compiled
at install for the installing machine (``setup.py``); where no C compiler works, the
package installs without it and the numba kernel serves, with the same results, more
slowly (docs/explanation/design.md, "The native cost kernel", has the figures).

The environment variable :data:`KERNEL_VARIABLE` chooses: ``auto`` (the default: C when
built, else numba), ``c`` (C, or an error saying it was not built) or ``numba``. The choice
holds for every evaluation, compiled solve loops and calls from Python alike
(:func:`python_cost`), so that a process served by the C kernel never compiles the numba
one (about 3 s of a first run's compile, with the shape-error paths its reshapes bring).
"""

from __future__ import annotations

import enum
import functools
import importlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from formation_bench.environment import environment_variable


class CostKernel(enum.Enum):
    """Which implementation computes the cost in compiled solve loops."""

    AUTO = "auto"
    """C when it was built at install, else numba."""
    C = "c"
    """The C kernel; an error if it was not built."""
    NUMBA = "numba"
    """The numba kernel (``formation_bench.mpc.cost.packed_batch_cost``)."""


@dataclass(frozen=True)
class CostFunction:
    """A compiled cost's C function: its address, what keeps it alive, and its name."""

    address: int
    owner: Any
    kernel: CostKernel
    """:attr:`CostKernel.C` or :attr:`CostKernel.NUMBA`: the kernel this is."""


def _unbuilt(kernel: CostKernel) -> str | None:
    if kernel is CostKernel.C and native_cost_address() is None:
        return (
            "the C cost kernel was not built when formation-bench was installed (reinstall "
            "with a working C compiler, or set it to auto or numba)"
        )
    return None


COST_KERNEL = environment_variable(
    "FORMATION_BENCH_COST_KERNEL", CostKernel, CostKernel.AUTO,
    "the cost kernel of compiled solve loops", usable=_unbuilt,
)  # fmt: skip
"""Environment variable choosing the cost kernel (see :class:`CostKernel`)."""
KERNEL_VARIABLE = COST_KERNEL.name


def chosen_kernel() -> CostKernel:
    """The kernel :data:`KERNEL_VARIABLE` asks for (``auto`` when it is unset)."""
    return COST_KERNEL.value()


@functools.cache
def native_cost_address() -> int | None:
    """Address of the C kernel's function, or None when it was not built at install."""
    try:
        module = importlib.import_module("formation_bench.mpc._cost_kernel")
    except ImportError:
        return None
    return int(module.cost_address)


def cost_function(kernel: CostKernel | None = None) -> CostFunction:
    """The C function of ``kernel`` (default: :func:`chosen_kernel`) with the compiled-cost
    signature; the numba one is compiled, or loaded from numba's cache, on first use."""
    return _cost_function(chosen_kernel() if kernel is None else kernel)


@functools.cache
def _cost_function(kernel: CostKernel) -> CostFunction:
    # once per kernel and process: every solve's problem asks for it
    address = native_cost_address() if kernel is not CostKernel.NUMBA else None
    if address is not None:
        return CostFunction(address, None, CostKernel.C)
    if kernel is CostKernel.C:  # a command refuses this before any work; a library caller
        raise RuntimeError(f"{KERNEL_VARIABLE}=c: {_unbuilt(kernel)}")
    from formation_bench.mpc.cost import compiled_cost

    numba_cost = compiled_cost()
    return CostFunction(numba_cost.address, numba_cost, CostKernel.NUMBA)


@functools.cache
def _c_costs() -> Callable[[np.ndarray, np.ndarray, np.ndarray], None] | None:
    """The C kernel's Python entry, ``costs(decisions, packed, out)``, or None when it was not
    built (or was built before it had one)."""
    try:
        module = importlib.import_module("formation_bench.mpc._cost_kernel")
    except ImportError:
        return None
    return getattr(module, "costs", None)


def python_cost() -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """What evaluates a packed problem from Python, by the kernel compiled solve loops use
    (:func:`cost_function`): the C kernel's Python entry when it serves, else numba's
    ``packed_batch_cost``. Both take ``(decisions, packed)`` (``(n, d)`` float64, C-contiguous,
    and :func:`~formation_bench.mpc.cost.pack_problem`'s array) and give the same numbers to
    the bit. Resolved once per problem: the choice reads the environment."""
    c_costs = _c_costs() if cost_function().kernel is CostKernel.C else None
    if c_costs is None:
        from formation_bench.mpc.cost import packed_batch_cost

        return packed_batch_cost

    def c_kernel(decisions: np.ndarray, packed: np.ndarray) -> np.ndarray:
        out = np.empty(decisions.shape[0])
        c_costs(decisions, packed, out)
        return out

    return c_kernel


def packed_costs(decisions: np.ndarray, packed: np.ndarray) -> np.ndarray:
    """:func:`python_cost` applied once: the costs of ``decisions`` on ``packed``."""
    return python_cost()(decisions, packed)
