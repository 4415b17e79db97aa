"""The adapters of nevergrad, pycma and mealpy: budgets, batches, seeding, reached quality.

The interface properties every optimiser shares (bounds, warm start, NaN costs, same seed
same answer) are checked for the adapters by ``tests/test_conformance.py``, which runs
over every registered name; these tests add what is particular to an adapter. Each is
skipped, naming the extra to install, when its library is not installed.
"""

from __future__ import annotations

import re
import subprocess
import sys
from importlib.metadata import version
from types import SimpleNamespace

import numpy as np
import pytest
from helpers import BOX, CENTRE, D, Recorder, shifted_sphere

from formation_bench.instances.library import shipped
from formation_bench.optimizers import OPTIMIZERS, Bounds, Budget, get_optimizer
from formation_bench.optimizers.adapters import ADAPTERS
from formation_bench.optimizers.adapters.common import (
    INSTALL_HINT,
    LibraryIncompatibility,
    SolveGlobalRandomState,
    finite_costs,
    import_library,
    library_available,
)
from formation_bench.optimizers.adapters.mealpy_adapter import ALGORITHMS, MealpyOptimizer
from formation_bench.optimizers.adapters.nevergrad_adapter import (
    ALGORITHMS as NEVERGRAD_ALGORITHMS,
)
from formation_bench.optimizers.adapters.nevergrad_adapter import (
    NevergradOptimizer,
    NevergradState,
)
from formation_bench.plugins import Registry

NAMES = sorted(ADAPTERS)
BATCH_PER_ITERATION = {"ng-ngopt", "ng-de", "pycma", "mealpy-gwo"}
"""Adapters whose every iteration is one call of the objective (mealpy's BSO: one per cluster)."""


def adapter(name: str):
    library = ADAPTERS[name][0]
    if not library_available(library):
        pytest.skip(f"{name} needs {library!r}: {INSTALL_HINT}")
    return get_optimizer(name)


def global_state() -> tuple[bytes, int]:
    """numpy's global random state (key and position), read only to see that it is unchanged."""
    state = np.random.get_state(legacy=False)  # noqa: NPY002 - read, never drawn from
    return state["state"]["key"].tobytes(), state["state"]["pos"]


def rosenbrock(x: np.ndarray) -> np.ndarray:
    return np.sum(100.0 * (x[:, 1:] - x[:, :-1] ** 2) ** 2 + (1.0 - x[:, :-1]) ** 2, axis=1)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("evaluations", [1, 13, 100, 1001])
def test_spends_exactly_the_evaluation_budget(name: str, evaluations: int) -> None:
    optimizer = adapter(name)
    rec = Recorder(shifted_sphere(CENTRE))
    res = optimizer.minimize(rec, BOX, np.random.default_rng(0), Budget(evaluations))
    assert res.nfev == sum(rec.calls) == evaluations
    assert res.history_nfev[-1] == evaluations
    assert res.message == "evaluation budget reached"
    assert BOX.contains(np.vstack(rec.points))


@pytest.mark.parametrize("name", NAMES)
def test_an_iteration_budget_runs_that_many_batched_iterations(name: str) -> None:
    optimizer = adapter(name)
    rec = Recorder(shifted_sphere(CENTRE))
    res = optimizer.minimize(rec, BOX, np.random.default_rng(1), Budget(max_iterations=40))
    assert res.nit == 40 and res.message == "iteration budget reached"
    assert res.nfev == sum(rec.calls) == res.history_nfev[-1]
    assert len(res.history_nfev) == 41
    if name in BATCH_PER_ITERATION:
        assert len(rec.calls) == 41  # the start (or first population), then one call per iteration
        assert len(set(rec.calls[1:])) == 1 and rec.calls[1] > 1
    else:
        assert len(rec.calls) < res.nfev / 4  # batched per cluster, not one point per call


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.slow
def test_a_deadline_stops_the_solve_between_iterations(name: str) -> None:
    optimizer = adapter(name)
    res = optimizer.minimize(
        shifted_sphere(CENTRE),
        BOX,
        np.random.default_rng(2),
        Budget(max_evaluations=10**7, deadline_s=0.05),
    )
    assert res.message == "deadline reached"
    assert 1 <= res.nfev < 10**7


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.slow
def test_leaves_numpy_global_random_state_alone(name: str) -> None:
    optimizer = adapter(name)
    before = global_state()
    a = optimizer.minimize(shifted_sphere(CENTRE), BOX, np.random.default_rng(3))
    assert global_state() == before
    b = optimizer.minimize(shifted_sphere(CENTRE), BOX, np.random.default_rng(3))
    np.testing.assert_array_equal(a.x, b.x)


# Largest median (3 seeds, default budget of 1230 evaluations) each adapter must reach in
# 10 dimensions, 3-10 times the medians measured (docs/explanation/optimizers.md, "Adapters"):
# the sphere centred off the middle of [-5, 5]^10, Rosenbrock on [-2, 2]^10 (a random point
# costs ~2000).
SPHERE = {"ng-ngopt": 0.02, "ng-de": 2.0, "pycma": 1e-4, "mealpy-bso": 3.0, "mealpy-gwo": 0.5}
ROSENBROCK = {"ng-ngopt": 30.0, "ng-de": 40.0, "pycma": 30.0, "mealpy-bso": 120.0, "mealpy-gwo": 30}


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.slow
def test_reaches_a_small_cost_on_a_10d_sphere_and_rosenbrock(name: str) -> None:
    optimizer = adapter(name)
    sphere = shifted_sphere(CENTRE)
    box = Bounds(np.full(D, -2.0), np.full(D, 2.0))
    sphere_costs, rosenbrock_costs = [], []
    for seed in range(3):
        res = optimizer.minimize(sphere, BOX, np.random.default_rng(seed))
        assert res.nfev == 1230
        sphere_costs.append(res.fun)
        res = optimizer.minimize(rosenbrock, box, np.random.default_rng(seed))
        assert res.nfev == 1230
        rosenbrock_costs.append(res.fun)
    assert np.median(sphere_costs) <= SPHERE[name]
    assert np.median(rosenbrock_costs) <= ROSENBROCK[name]


# Largest median relative gap to J* on 5 instances spread over the shipped library (default
# budget, warm start): 3-10 times the measured medians.
LIBRARY_GAP = {"ng-ngopt": 0.2, "ng-de": 0.5, "pycma": 0.2, "mealpy-bso": 2.0, "mealpy-gwo": 0.2}


@pytest.fixture(scope="module")
def instances():
    library = list(shipped())
    return library[:: len(library) // 5][:5]


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.slow
def test_small_gap_on_instances_of_the_shipped_library(name: str, instances) -> None:
    optimizer = adapter(name)
    gaps = []
    for instance in instances:
        problem = instance.problem
        res = optimizer.minimize(
            problem, problem.bounds, np.random.default_rng(instance.index), None,
            instance.warm_start,
        )  # fmt: skip
        assert res.nfev == 1230
        assert problem.bounds.contains(res.x)
        gaps.append(float(instance.gap(res.fun)))
    assert min(gaps) >= -1e-6  # J* is the best known
    assert np.median(gaps) <= LIBRARY_GAP[name]


# --- the parts shared by the adapters, and a missing library ------------------------------


def test_finite_costs_rank_non_finite_costs_last_with_a_finite_penalty() -> None:
    costs, worst = finite_costs(np.array([3.0, np.inf, -2.0]), -np.inf)
    assert worst == 3.0 and np.isfinite(costs).all()
    assert costs[1] > 3.0 and costs[[0, 2]].tolist() == [3.0, -2.0]
    costs, worst = finite_costs(np.array([np.inf, np.inf]), worst)
    assert worst == 3.0 and (costs > 3.0).all()
    costs, worst = finite_costs(np.array([np.inf]), -np.inf)
    assert worst == -np.inf and np.isfinite(costs).all()


def test_a_missing_library_names_the_extra_to_install() -> None:
    assert 'pip install -c requirements/lock.txt ".[adapters]"' in INSTALL_HINT
    with pytest.raises(ImportError, match=re.escape(INSTALL_HINT)):
        import_library("formation_bench_no_such_library", "the test adapter")
    registry: Registry[object] = Registry("optimizer", "formation_bench.no_such_group")
    registry.add_missing("ng-x", f"it needs the 'nevergrad' package: {INSTALL_HINT}")
    assert "ng-x" not in registry
    message = registry.unknown("ng-x").args[0]
    assert "'ng-x' is not available" in message and INSTALL_HINT in message


def test_without_the_libraries_the_names_are_unregistered_and_explained() -> None:
    code = (
        "import sys\n"
        "for m in ('nevergrad', 'cma', 'mealpy'): sys.modules[m] = None\n"
        "from formation_bench.optimizers import OPTIMIZERS, get_optimizer\n"
        f"names = {NAMES!r}\n"
        "assert not set(names) & set(OPTIMIZERS), sorted(OPTIMIZERS)\n"
        "assert sorted(OPTIMIZERS.missing()) == names\n"
        "try:\n"
        "    get_optimizer('ng-ngopt')\n"
        "except KeyError as err:\n"
        "    print(err.args[0])\n"
        "from formation_bench.cli.main import main\n"
        "main(['list'])\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    first, listing = done.stdout.split("\n", 1)
    assert "'ng-ngopt' is not available" in first and INSTALL_HINT in first
    available, missing = listing.split("optimizers not available here:")
    assert "modified-bso" in available and "ng-ngopt" not in available
    assert all(name in missing for name in NAMES) and INSTALL_HINT in missing


def test_registered_adapters_are_the_available_ones() -> None:
    for name, (library, optimizer, description) in ADAPTERS.items():
        if library_available(library):
            assert OPTIMIZERS[name].optimizer == optimizer
            assert OPTIMIZERS[name].description == description
        else:
            assert name in OPTIMIZERS.missing()


@pytest.mark.parametrize("algorithm", sorted(ALGORITHMS))
def test_every_offered_mealpy_algorithm_runs_seeded_and_batched(algorithm: str) -> None:
    if not library_available("mealpy"):
        pytest.skip(f"needs 'mealpy': {INSTALL_HINT}")
    optimizer = MealpyOptimizer(algorithm=algorithm)
    runs = []
    for _ in range(2):
        rec = Recorder(shifted_sphere(CENTRE))
        runs.append(optimizer.minimize(rec, BOX, np.random.default_rng(5), Budget(200)))
        assert sum(rec.calls) == 200 and len(rec.calls) < 200 / 4
    assert runs[0].fun == runs[1].fun
    np.testing.assert_array_equal(runs[0].x, runs[1].x)


@pytest.mark.parametrize("algorithm", NEVERGRAD_ALGORITHMS)
@pytest.mark.slow
def test_every_offered_nevergrad_algorithm_is_seeded_by_the_generator_alone(algorithm: str):
    if not library_available("nevergrad"):
        pytest.skip(f"needs 'nevergrad': {INSTALL_HINT}")
    optimizer = NevergradOptimizer(algorithm=algorithm)
    runs = []
    for _ in range(2):
        before = global_state()
        rec = Recorder(shifted_sphere(CENTRE))
        runs.append(optimizer.minimize(rec, BOX, np.random.default_rng(5), Budget(200)))
        assert global_state() == before
        assert sum(rec.calls) == 200 and len(rec.calls) == 7  # 30 per call, the last 20
    assert runs[0].fun == runs[1].fun
    np.testing.assert_array_equal(runs[0].x, runs[1].x)


def test_ngopt_meta_model_depends_on_the_generator_alone() -> None:
    """NGOpt picks its meta-model for this problem, whose inner optimisers seed themselves
    from numpy's global state: the solve is the same whatever that state is, and leaves it."""
    if not library_available("nevergrad"):
        pytest.skip(f"needs 'nevergrad': {INSTALL_HINT}")
    optimizer = NevergradOptimizer()
    caller = global_state()
    first = optimizer.minimize(shifted_sphere(CENTRE), BOX, np.random.default_rng(5), Budget(200))
    assert first.info["nevergrad_algorithm"] == "_MetaModel"
    assert global_state() == caller
    saved = np.random.get_state()  # noqa: NPY002 - put back below, never drawn from
    try:
        # another global state before the same solve
        other = np.random.RandomState(np.random.MT19937(np.random.SeedSequence(11)))
        np.random.set_state(other.get_state())  # noqa: NPY002
        again = optimizer.minimize(
            shifted_sphere(CENTRE), BOX, np.random.default_rng(5), Budget(200)
        )
        assert np.random.get_state()[1].tobytes() == other.get_state()[1].tobytes()  # noqa: NPY002
    finally:
        np.random.set_state(saved)  # noqa: NPY002
    assert again.fun == first.fun
    np.testing.assert_array_equal(again.x, first.x)


def test_solve_global_state_is_carried_between_calls_and_the_callers_is_kept() -> None:
    solve = SolveGlobalRandomState(3)
    caller = global_state()
    with solve.active():
        a = np.random.random_sample(2)  # noqa: NPY002 - the swapped-in solve state
    assert global_state() == caller
    with solve.active():
        b = np.random.random_sample(2)  # noqa: NPY002
    fresh = SolveGlobalRandomState(3)
    with fresh.active():
        both = np.random.random_sample(4)  # noqa: NPY002
    np.testing.assert_array_equal(np.r_[a, b], both)  # carried on, not restarted
    assert global_state() == caller


def test_nevergrads_numpy_24_failure_is_named_with_the_versions() -> None:
    """nevergrad 1.0.12's meta-model TypeError under numpy >= 2.4 becomes one message that
    names both versions and the lock (injected: the lock's numpy does not raise it)."""
    if not library_available("nevergrad"):
        pytest.skip(f"needs 'nevergrad': {INSTALL_HINT}")

    def ask():
        raise TypeError("only 0-dimensional arrays can be converted to Python scalars")

    failing = SimpleNamespace(ask=ask, optim=None)
    state = NevergradState(failing, -np.inf, SolveGlobalRandomState(0))
    counter = SimpleNamespace(remaining=30)
    with pytest.raises(LibraryIncompatibility) as raised:
        NevergradOptimizer().step(state, counter, BOX, np.random.default_rng(0), 1)
    message = str(raised.value)
    assert f"numpy {np.__version__}" in message and f"nevergrad {version('nevergrad')}" in message
    assert "requirements/lock.txt" in message
    other = SimpleNamespace(ask=lambda: (_ for _ in ()).throw(TypeError("unrelated")))
    state = NevergradState(other, -np.inf, SolveGlobalRandomState(0))
    with pytest.raises(TypeError, match="unrelated"):
        NevergradOptimizer().step(state, counter, BOX, np.random.default_rng(0), 1)


def test_only_nevergrads_known_numpy_warning_is_left_out() -> None:
    """pyproject.toml's filterwarnings leaves out the one DeprecationWarning nevergrad's
    meta-model raises by the thousand; the same message from elsewhere, and any other warning
    of that module, still show."""
    import warnings

    message = (
        "Conversion of an array with ndim > 0 to a scalar is deprecated, and will error in "
        "future. Ensure you extract a single element from your array before performing this "
        "operation. (Deprecated NumPy 1.25.)"
    )
    metamodel = "nevergrad.optimization.metamodel"
    with warnings.catch_warnings(record=True) as caught:
        for text, module in (
            (message, metamodel),
            (message, "formation_bench.optimizers.adapters.nevergrad_adapter"),
            ("another deprecation", metamodel),
        ):
            warnings.warn_explicit(text, DeprecationWarning, "metamodel.py", 177, module=module)
    assert [(str(w.message), w.category) for w in caught] == [
        (message, DeprecationWarning),
        ("another deprecation", DeprecationWarning),
    ]
