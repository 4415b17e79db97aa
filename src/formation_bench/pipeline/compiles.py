"""What a command will compile before its work, said once, and the order in which a sweep
starts its runs so that its workers compile at the same time and never the same kernel.

numba compiles a kernel the first time a process needs it and none is in its on-disk cache;
every later process loads it. A command looks first for what is missing
(:func:`pending_compiles`): the harness's kernels, and each optimiser's outermost ones
(:meth:`~formation_bench.optimizers.Optimizer.compiled_kernels`; the optimisers that share
them form one :class:`CompileGroup`). It says what it will compile and about how long that
takes (:meth:`PendingCompiles.notice`, from the CPU times the optimisers declare). A sweep then
starts the first run of every group first, the longest compile first (:func:`compile_first`):
each worker compiles another group while the others do, and the kernels two groups share are
compiled by one process while the others wait for them
(:mod:`formation_bench.kernel_cache`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:
    from formation_bench.optimizers import Optimizer

HARNESS_COMPILE_CPU_S = 2.2
"""CPU seconds numba takes to compile the harness's kernels (the model, the cost's helpers and
the trigger's conditions) on an empty cache, as ``python -m perf.cold_warm`` measured them."""

T = TypeVar("T")


@dataclass(frozen=True)
class CompileGroup:
    """Optimisers whose solves run the same outermost kernels, not yet in numba's cache."""

    kernels: tuple[Any, ...]
    """Their :meth:`~formation_bench.optimizers.Optimizer.compiled_kernels`."""
    labels: tuple[str, ...]
    """The optimisers' labels, in the order given."""
    cpu_s: float | None
    """Their declared compile time (:attr:`~formation_bench.optimizers.Optimizer.compile_cpu_s`);
    None: not measured."""

    def describe(self) -> str:
        more = len(self.labels) - 1
        shared = f" (+{more} configuration{'s' * (more > 1)})" if more else ""
        return f"{self.labels[0]}{shared} {_about(self.cpu_s)}"


@dataclass(frozen=True)
class PendingCompiles:
    """What a command will compile before its work."""

    harness: bool
    """Whether the harness's kernels are missing."""
    groups: tuple[CompileGroup, ...]

    @property
    def empty(self) -> bool:
        return not self.harness and not self.groups

    def cpu_s(self) -> float:
        """The declared CPU seconds of it all (those of the groups not measured left out)."""
        harness = HARNESS_COMPILE_CPU_S if self.harness else 0.0
        return harness + sum(group.cpu_s or 0.0 for group in self.groups)

    def wall_s(self, workers: int) -> float:
        """About how long compiling takes on ``workers`` processes, each taking the next group
        as it is free, the longest first (the harness first, in every process)."""
        loads = [HARNESS_COMPILE_CPU_S if self.harness else 0.0] * max(workers, 1)
        for group in sorted(self.groups, key=lambda g: -(g.cpu_s or 0.0)):
            loads[loads.index(min(loads))] += group.cpu_s or 0.0
        return max(loads)

    def notice(self, workers: int = 1) -> str | None:
        """One line saying what will compile and about how long it takes; None: nothing."""
        if self.empty:
            return None
        parts = ([f"the harness {_about(HARNESS_COMPILE_CPU_S)}"] if self.harness else []) + [
            group.describe() for group in self.groups
        ]
        total = f"{_seconds(self.cpu_s())} of CPU in all"
        if workers > 1 and len(self.groups) > 1:
            total += f", ~{_seconds(self.wall_s(workers))} on {workers} workers"
        unmeasured = sum(group.cpu_s is None for group in self.groups)
        if unmeasured:
            total += f", plus {unmeasured} not measured"
        return (
            "compiling numba kernels once, before any timed solve (numba caches them for every "
            f"later run): {', '.join(parts)}; {total}..."
        )


def _seconds(value: float) -> str:
    return f"{value:.0f} s" if value >= 1.5 else "1 s"


def _about(cpu_s: float | None) -> str:
    return "(time not measured)" if cpu_s is None else f"~{_seconds(cpu_s)}"


def pending_compiles(
    optimizers: Mapping[str, Optimizer], *, harness: bool = True
) -> PendingCompiles:
    """The harness (if ``harness``) and the groups of ``optimizers`` (labels to optimisers)
    whose kernels are not in numba's cache."""
    from formation_bench.pipeline import runner

    groups: dict[tuple[Any, ...], list[str]] = {}
    declared: dict[tuple[Any, ...], float | None] = {}
    for label, optimizer in optimizers.items():
        kernels = optimizer.compiled_kernels()
        if not kernels:
            continue
        if kernels not in groups and runner.optimizer_kernels_cached(optimizer):
            continue
        groups.setdefault(kernels, []).append(label)
        declared.setdefault(kernels, optimizer.compile_cpu_s)
    return PendingCompiles(
        harness=harness and not runner.kernels_cached(),
        groups=tuple(
            CompileGroup(kernels, tuple(labels), declared[kernels])
            for kernels, labels in groups.items()
        ),
    )


def compile_first(
    specs: Sequence[T], optimizer_of: Callable[[T], Optimizer | None]
) -> list[T]:
    """``specs`` with the first of each group whose kernels are not in the cache moved to the
    front, the longest declared compile first (those not measured last); the others keep
    their order. A run's results do not depend on when it runs."""
    from formation_bench.pipeline import runner

    firsts: dict[tuple[Any, ...], tuple[int, float]] = {}
    cached: dict[tuple[Any, ...], bool] = {}
    for index, spec in enumerate(specs):
        optimizer = optimizer_of(spec)
        kernels = optimizer.compiled_kernels() if optimizer is not None else ()
        if not kernels or kernels in firsts:
            continue
        if kernels not in cached:
            cached[kernels] = runner.optimizer_kernels_cached(optimizer)  # type: ignore[arg-type]
        if not cached[kernels]:
            firsts[kernels] = (index, optimizer.compile_cpu_s or 0.0)  # type: ignore[union-attr]
    leading = [index for index, _ in sorted(firsts.values(), key=lambda first: -first[1])]
    moved = set(leading)
    return [specs[i] for i in leading] + [s for i, s in enumerate(specs) if i not in moved]
