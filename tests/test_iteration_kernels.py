"""The plumbing of the fused BSO iterations: settings tuples and random numbers drawn ahead."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from formation_bench.optimizers import Bounds, Budget, get_optimizer
from formation_bench.optimizers.cls_bso import LocalSettings, cls_iteration
from formation_bench.optimizers.modified_bso_kernels import (
    KernelSettings,
    ideas_from_clusters,
    modified_bso_iteration,
)
from formation_bench.optimizers.original_bso_kernels import ShiSettings, shi_ideas, shi_step
from formation_bench.optimizers.population import ROWS_AHEAD, iteration_randoms, no_randoms


def trailing_parameters(kernel, count: int) -> tuple[str, ...]:
    names = tuple(inspect.signature(kernel.py_func).parameters)
    return names[len(names) - count :]


@pytest.mark.parametrize(
    ("kernel", "fields"),
    [
        (modified_bso_iteration, KernelSettings._fields),
        (ideas_from_clusters, KernelSettings._fields),
        (shi_ideas, ShiSettings._fields),
        (shi_step, ShiSettings._fields),
        (cls_iteration, LocalSettings._fields + ShiSettings._fields),
    ],
)
def test_settings_tuples_match_the_kernel_parameters(kernel, fields: tuple[str, ...]) -> None:
    """The settings are passed as ``*settings``: their field order is the kernel's."""
    assert trailing_parameters(kernel, len(fields)) == fields


def test_a_block_covers_the_planned_iterations_and_is_redrawn_when_used_up() -> None:
    rng = np.random.default_rng(3)
    block = no_randoms(7, (2, 3))
    rows = []
    for iteration in range(1, 6):
        block, u, normals = iteration_randoms(block, rng, iteration, t_max=3)
        assert u.shape == (7,) and normals.shape == (2, 3)
        rows.append((block.first_iteration, block.uniforms.shape[0]))
    # iterations 1-3 from one block of 3 rows; past T_max, one row at a time
    assert rows == [(1, 3), (1, 3), (1, 3), (4, 1), (5, 1)]


def test_blocks_never_exceed_rows_ahead_and_rows_are_the_generators_numbers() -> None:
    rng = np.random.default_rng(5)
    block = no_randoms(4, (2,))
    seen_u, seen_n = [], []
    for iteration in range(1, ROWS_AHEAD + 3):
        block, u, normals = iteration_randoms(block, rng, iteration, t_max=1000)
        assert block.uniforms.shape[0] <= ROWS_AHEAD
        seen_u.append(u.copy())
        seen_n.append(normals.copy())
    reference = np.random.default_rng(5)
    np.testing.assert_array_equal(np.array(seen_u[:ROWS_AHEAD]), reference.random((ROWS_AHEAD, 4)))
    np.testing.assert_array_equal(
        np.array(seen_n[:ROWS_AHEAD]), reference.standard_normal((ROWS_AHEAD, 2))
    )
    np.testing.assert_array_equal(seen_u[ROWS_AHEAD], reference.random((ROWS_AHEAD, 4))[0])


def test_a_row_is_never_reused_when_a_step_is_repeated() -> None:
    """Calling with an iteration outside the block (e.g. a restarted loop) draws afresh."""
    rng = np.random.default_rng(1)
    block, first, _ = iteration_randoms(no_randoms(3, (1,)), rng, 5, t_max=10)
    block, again, _ = iteration_randoms(block, rng, 4, t_max=10)
    assert block.first_iteration == 4
    assert not np.array_equal(first, again)


@pytest.mark.parametrize("name", ["modified-bso", "original-bso", "cls-bso"])
def test_long_solves_cross_several_blocks(name: str) -> None:
    """More iterations than one block holds, and an evaluation budget past the plan."""
    optimizer = get_optimizer(name)
    box = Bounds(np.full(4, -3.0), np.full(4, 3.0))

    def sphere(x: np.ndarray) -> np.ndarray:
        return np.einsum("ij,ij->i", x - 1.0, x - 1.0)

    long = optimizer.minimize(
        sphere, box, np.random.default_rng(2), Budget(max_iterations=ROWS_AHEAD * 2 + 5)
    )
    assert long.nit == ROWS_AHEAD * 2 + 5
    assert long.fun < 1e-3
    again = optimizer.minimize(
        sphere, box, np.random.default_rng(2), Budget(max_iterations=ROWS_AHEAD * 2 + 5)
    )
    np.testing.assert_array_equal(long.history_fun, again.history_fun)
    by_evaluations = optimizer.minimize(
        sphere, box, np.random.default_rng(2), Budget(max_evaluations=3001)
    )
    assert by_evaluations.nfev == 3001
