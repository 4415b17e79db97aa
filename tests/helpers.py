"""What many tests share: a box, test functions, a recording objective, and which settings
make an optimiser's own budget."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from formation_bench.fields import describe_fields
from formation_bench.optimizers import Bounds, Optimizer, optimizer_names
from formation_bench.optimizers.tuned import is_tuned

D = 10
"""Dimension of the shared test problems."""
BOX = Bounds(np.full(D, -5.0), np.full(D, 5.0))
"""The shared search box, [-5, 5]^D."""
CENTRE = np.linspace(-3.0, 2.0, D)
"""An off-centre optimum inside BOX: no optimiser finds it by symmetry."""


def sphere(x: np.ndarray) -> np.ndarray:
    """Sum of squares of each row: minimum 0 at the origin."""
    return np.einsum("ij,ij->i", x, x)


def shifted_sphere(centre: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """The sphere with its minimum 0 at ``centre``."""

    def f(x: np.ndarray) -> np.ndarray:
        z = x - centre
        return np.einsum("ij,ij->i", z, z)

    return f


class Recorder:
    """A batch objective that keeps a copy of every batch it is asked to evaluate."""

    def __init__(self, f: Callable[[np.ndarray], np.ndarray] = sphere) -> None:
        self.f = f
        self.batches: list[np.ndarray] = []

    def __call__(self, x: np.ndarray) -> np.ndarray:
        self.batches.append(np.array(x, copy=True))
        return self.f(x)

    @property
    def calls(self) -> list[int]:
        """The size of each batch, in order."""
        return [batch.shape[0] for batch in self.batches]

    @property
    def points(self) -> np.ndarray:
        """Every row evaluated, in order, as one array."""
        if not self.batches:
            return np.zeros((0, D))
        return np.vstack(self.batches)


def budget_settings(optimizer: Optimizer) -> list[str]:
    """The settings an optimiser's own budget is made of: each integer field whose value its
    ``default_budget`` reports as its iterations or evaluations."""
    found = []
    for info in describe_fields(optimizer):
        if type(info.value) is not int:
            continue
        try:
            changed = dataclasses.replace(optimizer, **{info.name: info.value + 1})
        except (ValueError, TypeError):  # a limit of another field
            continue
        budget = changed.default_budget
        if info.value + 1 in (budget.max_iterations, budget.max_evaluations):
            found.append(info.name)
    return found


def configured_names() -> list[str]:
    """Every registered optimiser but the shipped tuned variants: the tests over the registry
    check each class and hand-written configuration; a tuned variant is other values of a class
    its base name covers, and tests/test_tuned_variants.py checks each one on the MPC problem."""
    return [name for name in optimizer_names() if not is_tuned(name)]
