"""The C cost kernel: the numba kernel's numbers to the bit, eq. (14)'s to 1e-12."""

from __future__ import annotations

import ctypes
import os
import pickle
import shutil
import subprocess
import sys
import sysconfig

import numpy as np
import pytest

from formation_bench.instances.library import shipped
from formation_bench.mpc import native_cost
from formation_bench.mpc.cost import (
    NO_PENALTIES,
    Penalties,
    batch_cost,
    block_map,
    pack_problem,
    packed_batch_cost,
)
from formation_bench.mpc.native_cost import (
    KERNEL_VARIABLE,
    CostKernel,
    chosen_kernel,
    cost_function,
    native_cost_address,
)

C_COST = ctypes.CFUNCTYPE(
    None, ctypes.c_void_p, ctypes.c_int64, ctypes.c_int64, ctypes.c_void_p, ctypes.c_void_p
)
BATCH_SIZES = (1, 2, 3, 4, 5, 7, 10, 12, 29, 30, 31, 32, 33, 64, 100)


def has_c_compiler() -> bool:
    compiler = (sysconfig.get_config_var("CC") or "cc").split()[0]
    return shutil.which(compiler) is not None


@pytest.fixture(scope="module")
def c_cost():
    address = native_cost_address()
    if address is None:
        if has_c_compiler():
            pytest.fail("a C compiler is installed, but the C cost kernel was not built")
        pytest.skip("no C compiler: the package runs on the numba kernel")
    return C_COST(address)


def c_costs(c_cost, decisions: np.ndarray, data: np.ndarray) -> np.ndarray:
    decisions = np.ascontiguousarray(decisions, dtype=np.float64)
    out = np.full(decisions.shape[0], np.nan)
    c_cost(decisions.ctypes.data, decisions.shape[0], decisions.shape[1], data.ctypes.data,
           out.ctypes.data)  # fmt: skip
    return out


def one_problem_per_family():
    """A library problem of every scenario family: paper references, obstacles and
    collisions, swarms with 2 to 9 neighbours, group centres."""
    library = shipped()
    seen = {}
    for instance in library.instances("test") + library.instances("validation"):
        problem = instance.problem
        key = (
            problem.scenario.name,
            problem.neighbour_positions.shape[0],
            problem.centre_offset_sum is not None,
        )
        seen.setdefault(key, instance)
    return list(seen.values())


FAMILIES = one_problem_per_family()


def test_the_library_covers_every_family():
    names = {instance.problem.scenario.name for instance in FAMILIES}
    assert {"paper", "paper-obstacles", "swarm-5", "swarm-10"} <= names
    assert any(instance.problem.penalties.w_obstacle > 0 for instance in FAMILIES)
    assert any(instance.problem.centre_offset_sum is not None for instance in FAMILIES)


@pytest.mark.parametrize("instance", FAMILIES, ids=lambda i: f"{i.problem.scenario.name}-{i.index}")
def test_c_kernel_is_the_numba_kernel_to_the_bit(c_cost, instance):
    problem = instance.problem
    rng = np.random.default_rng(instance.index)
    bounds = problem.bounds
    for n in BATCH_SIZES:
        decisions = bounds.lower + rng.random((n, problem.dim)) * bounds.width
        numba = packed_batch_cost(decisions, problem.packed)
        assert np.array_equal(c_costs(c_cost, decisions, problem.packed), numba)
        # a call from Python takes the kernel the solve loops take: C here
        assert np.array_equal(problem(decisions), numba)


@pytest.mark.parametrize("instance", FAMILIES, ids=lambda i: f"{i.problem.scenario.name}-{i.index}")
def test_kernels_agree_with_eq_14_as_printed(instance):
    problem = instance.problem
    rng = np.random.default_rng(instance.index + 1)
    bounds = problem.bounds
    decisions = bounds.lower + rng.random((8, problem.dim)) * bounds.width
    printed = [problem.reference_cost(decision) for decision in decisions]
    np.testing.assert_allclose(problem(decisions), printed, rtol=1e-12, atol=0)


@pytest.mark.parametrize(
    ("substeps", "theta", "n_obstacles"),
    [(1, 0.3, 0), (17, -2.0, 1), (40, 7.5, 2), (2, 1e6, 0), (3, -4e6, 3)],
)
def test_c_kernel_to_the_bit_off_the_paper(c_cost, substeps, theta, n_obstacles):
    """Sub-steps past the heading's reset, headings past the polynomial's range (math's
    cos and sin), penalties that bite, and every tile width of the dispatch."""
    rng = np.random.default_rng([substeps, n_obstacles])
    horizon, n_blocks, n_neighbours = 13, 4, 3
    state = np.array([1.0, -2.0, theta, 9.0])
    targets = rng.normal(0.0, 20.0, (n_neighbours, horizon, 2))
    neighbours = rng.normal(0.0, 2.0, (n_neighbours, horizon, 2))
    obstacles = np.column_stack((rng.normal(0.0, 5.0, (n_obstacles, 2)), np.full(n_obstacles, 4.0)))
    penalties = Penalties(50.0, 3.0, obstacles, 20.0 if n_obstacles else 0.0)
    data = pack_problem(
        state, block_map(horizon, n_blocks).astype(np.float64), 0.2, substeps, targets,
        rng.normal(0.0, 30.0, (horizon, 2)), 1.0, 0.25, neighbours, penalties,
    )  # fmt: skip
    for n in BATCH_SIZES:
        decisions = rng.uniform([-7.0, -0.6] * n_blocks, [7.0, 0.6] * n_blocks, (n, 2 * n_blocks))
        assert np.array_equal(c_costs(c_cost, decisions, data), packed_batch_cost(decisions, data))


def test_numba_kernel_by_arguments_and_packed_agree():
    rng = np.random.default_rng(3)
    state, block_of_step = np.array([0.0, 1.0, 0.2, 12.0]), block_map(20, 5)
    targets, centre = rng.normal(size=(2, 20, 2)), rng.normal(size=(20, 2))
    decisions = rng.uniform(-1.0, 1.0, (30, 10))
    direct = batch_cost(decisions, state, block_of_step, 0.2, 1, targets, centre, 1.0, 0.1,
                        *NO_PENALTIES)  # fmt: skip
    data = pack_problem(state, block_of_step.astype(np.float64), 0.2, 1, targets, centre, 1.0,
                        0.1, np.zeros((2, 20, 2)), Penalties())  # fmt: skip
    assert np.array_equal(direct, packed_batch_cost(decisions, data))


def test_kernel_choice_from_the_environment(monkeypatch):
    monkeypatch.setenv(KERNEL_VARIABLE, "numba")
    assert chosen_kernel() is CostKernel.NUMBA
    assert cost_function().kernel is CostKernel.NUMBA
    monkeypatch.delenv(KERNEL_VARIABLE)
    expected = CostKernel.C if native_cost_address() is not None else CostKernel.NUMBA
    assert cost_function().kernel is expected
    monkeypatch.setenv(KERNEL_VARIABLE, "fortran")
    with pytest.raises(ValueError, match=f"{KERNEL_VARIABLE} must be one of auto, c, numba"):
        chosen_kernel()


def test_a_call_from_python_takes_the_chosen_kernel(c_cost, monkeypatch):
    problem = FAMILIES[0].problem
    decisions = np.ascontiguousarray(problem.bounds.lower + 0.3 * problem.bounds.width)[None]
    calls = []
    entry = native_cost._c_costs()
    assert entry is not None  # built with the kernel: calls from Python take it

    def counted(*args):
        calls.append(args)
        return entry(*args)

    monkeypatch.setattr(native_cost, "_c_costs", lambda: counted)
    fresh = pickle.loads(pickle.dumps(problem))  # without a chosen kernel
    assert np.array_equal(fresh(decisions), packed_batch_cost(decisions, problem.packed))
    assert len(calls) == 1  # the C kernel, as the compiled loops
    monkeypatch.setenv(KERNEL_VARIABLE, "numba")
    numba_problem = pickle.loads(pickle.dumps(problem))  # chosen at a problem's first call
    assert np.array_equal(numba_problem(decisions), fresh(decisions))
    assert len(calls) == 2  # the first problem kept its kernel; the new one took numba's
    assert fresh(np.empty((0, problem.dim))).shape == (0,)
    pickle.loads(pickle.dumps(fresh))(decisions)  # the chosen kernel is not pickled


@pytest.mark.parametrize(
    ("decisions", "packed", "out", "message"),
    [
        (np.zeros((2, 3), dtype=np.float32), np.zeros(9), np.zeros(2), "decisions must be"),
        (np.zeros((2, 3)).T, np.zeros(9), np.zeros(3), "not C-contiguous"),
        (np.zeros((2, 3)), np.zeros((3, 3)), np.zeros(2), "packed must be"),
        (np.zeros((2, 3)), np.zeros(9), np.zeros(3), "one entry per row"),
        (np.zeros((2, 3)), np.zeros(0), np.zeros(2), "packed is empty"),
    ],
)
def test_the_c_entry_refuses_what_it_cannot_read(c_cost, decisions, packed, out, message):
    # numpy refuses a C-contiguous view of a strided array itself (BufferError)
    with pytest.raises((ValueError, BufferError), match=message):
        native_cost._c_costs()(decisions, packed, out)
    with pytest.raises(TypeError, match="takes 3 arguments"):
        native_cost._c_costs()(decisions, packed)


def test_a_process_the_c_kernel_serves_never_compiles_the_numba_one(c_cost):
    # a fresh process: this one has compiled it for the tests above
    script = (
        "from formation_bench.pipeline.runner import warm_up_kernels\n"
        "from formation_bench.mpc.cost import packed_batch_cost\n"
        "warm_up_kernels()\n"
        "print(len(packed_batch_cost.overloads))\n"
    )
    env = {key: value for key, value in os.environ.items() if key != KERNEL_VARIABLE}
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=300, env=env
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["0"]


def test_asking_for_c_without_it_says_how_to_get_it(monkeypatch):
    monkeypatch.setenv(KERNEL_VARIABLE, "c")
    monkeypatch.setattr("formation_bench.mpc.native_cost.native_cost_address", lambda: None)
    native_cost._cost_function.cache_clear()
    try:
        with pytest.raises(RuntimeError, match="not built"):
            cost_function()
    finally:
        native_cost._cost_function.cache_clear()
