"""The plumbing of the fused BSO iterations: settings tuples and random numbers drawn ahead."""

from __future__ import annotations

import ast
import inspect
import pickle
import textwrap

import numpy as np
import pytest

from formation_bench.fields import kernel_field_names, kernel_value
from formation_bench.optimizers import (
    OPTIMIZERS,
    Bounds,
    Budget,
    cem,
    cem_update,
    get_optimizer,
    mppi,
    predictive_sampling,
)
from formation_bench.optimizers.bso_ops import move_ideas
from formation_bench.optimizers.cls_bso import (
    LocalSearchConfig,
    LocalSettings,
    cls_ask,
    local_candidates,
)
from formation_bench.optimizers.modified_bso_kernels import (
    KernelSettings,
    ModifiedBSOConfig,
    modified_bso_ask,
)
from formation_bench.optimizers.original_bso_kernels import (
    PER_SOLVE,
    ShiConfig,
    ShiSettings,
    shi_ask,
    shi_step,
)
from formation_bench.optimizers.population import ROWS_AHEAD, iteration_randoms, no_randoms
from formation_bench.optimizers.pso import PER_SOLVE as PSO_PER_SOLVE
from formation_bench.optimizers.pso import PSOConfig, PSOSettings, move_swarm, pso_ask

# (config, settings class, per-solve values, kernels reading it, the kernels' name for it)
SETTINGS = [
    (ModifiedBSOConfig, KernelSettings, PER_SOLVE, (modified_bso_ask, move_ideas), "s"),
    (
        ShiConfig,
        ShiSettings,
        PER_SOLVE,
        (shi_ask, shi_step, cls_ask, local_candidates, move_ideas),
        "s",
    ),
    (LocalSearchConfig, LocalSettings, (), (cls_ask, local_candidates), "local"),
    (
        mppi.MPPIConfig,
        mppi.MPPISettings,
        mppi.PER_SOLVE,
        (mppi.mppi_ask, mppi.mppi_tell, mppi.mppi_update),
        "s",
    ),
    (
        predictive_sampling.PredictiveSamplingConfig,
        predictive_sampling.PredictiveSamplingSettings,
        predictive_sampling.PER_SOLVE,
        (predictive_sampling.predictive_sampling_ask, predictive_sampling.predictive_sampling_tell),
        "s",
    ),
    (
        cem.CEMConfig,
        cem.CEMSettings,
        cem.PER_SOLVE,
        (cem.cem_ask, cem.cem_tell, cem_update.batch_size),
        "s",
    ),
]
IDS = [entry[1].__name__ for entry in SETTINGS]


def attributes_read(kernels, variable: str) -> set[str]:
    """Attributes the kernels' source reads on ``variable`` (e.g. ``s.p_one_cluster``)."""
    read = set()
    for kernel in kernels:
        tree = ast.parse(textwrap.dedent(inspect.getsource(kernel.py_func)))
        read |= {
            node.attr
            for node in ast.walk(tree)
            if isinstance(node, ast.Attribute)
            and isinstance(node.value, ast.Name)
            and node.value.id == variable
        }
    return read


@pytest.mark.parametrize(
    ("config", "settings", "per_solve", "kernels", "variable"), SETTINGS, ids=IDS
)
def test_every_field_declared_for_a_kernel_is_read_by_it(
    config, settings, per_solve, kernels, variable
) -> None:
    """A field marked ``kernel=True`` that no kernel reads would be a setting with no effect."""
    declared = set(kernel_field_names(config)) | set(per_solve)
    assert declared == set(settings._fields)
    assert declared <= attributes_read(kernels, variable)


@pytest.mark.parametrize(
    ("config", "settings", "per_solve", "kernels", "variable"), SETTINGS, ids=IDS
)
def test_kernels_read_only_declared_settings(
    config, settings, per_solve, kernels, variable
) -> None:
    assert attributes_read(kernels, variable) <= set(settings._fields)


def settings_passed_on(kernels, variable: str) -> tuple[list[str], list[tuple[str, str]]]:
    """How the kernels hand settings to the operators they call.

    Returns the fields passed positionally (``f(s.slope)``) and the
    ``(keyword, field)`` pairs passed by keyword (``f(slope=s.slope)``).
    """
    positional, by_keyword = [], []

    def field_of(node: ast.expr) -> str | None:
        is_read = isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
        return node.attr if is_read and node.value.id == variable else None

    for kernel in kernels:
        tree = ast.parse(textwrap.dedent(inspect.getsource(kernel.py_func)))
        for call in (node for node in ast.walk(tree) if isinstance(node, ast.Call)):
            positional += [name for arg in call.args if (name := field_of(arg))]
            by_keyword += [(kw.arg, name) for kw in call.keywords if (name := field_of(kw.value))]
    return positional, by_keyword


@pytest.mark.parametrize(
    ("config", "settings", "per_solve", "kernels", "variable"), SETTINGS, ids=IDS
)
def test_settings_reach_the_operators_by_name(config, settings, per_solve, kernels, variable):
    """A setting handed on travels as ``name=s.name``: two values cannot trade places."""
    positional, by_keyword = settings_passed_on(kernels, variable)
    assert positional == [], f"passed by position: {positional}"
    assert by_keyword, "the kernels hand no settings on"
    assert [(kw, field) for kw, field in by_keyword if kw != field] == []


MAX_KERNEL_ARGUMENTS = 8


def compiled_functions() -> list[tuple[str, object]]:
    """Every compiled function (numba dispatcher) defined in the optimisers."""
    import importlib
    import pkgutil

    import numba.core.registry

    import formation_bench.optimizers

    found = []
    for package in (formation_bench.optimizers,):
        for info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
            module = importlib.import_module(info.name)
            for name, value in vars(module).items():
                if (
                    isinstance(value, numba.core.registry.CPUDispatcher)
                    and value.py_func.__module__ == module.__name__
                ):
                    found.append((f"{module.__name__}.{name}", value))
    return found


def test_no_kernel_takes_more_than_eight_positional_arguments() -> None:
    """Settings travel as one tuple, state as one named tuple: no long lists to keep in order."""
    functions = compiled_functions()
    assert len(functions) > 30
    too_long = {
        name: len(inspect.signature(kernel.py_func).parameters)
        for name, kernel in functions
        if len(inspect.signature(kernel.py_func).parameters) > MAX_KERNEL_ARGUMENTS
    }
    assert too_long == {}


def test_the_kernels_take_one_settings_tuple() -> None:
    """No setting is a parameter of its own: each kernel reads them from one tuple."""
    every_setting = set(KernelSettings._fields + ShiSettings._fields + LocalSettings._fields)
    for kernel in (modified_bso_ask, shi_ask, cls_ask, shi_step, move_ideas, local_candidates):
        names = set(inspect.signature(kernel.py_func).parameters)
        assert not names & (every_setting - {"lower", "upper", "t_max", "scale"}), kernel


def test_the_pso_kernels_read_exactly_their_declared_settings() -> None:
    declared = set(kernel_field_names(PSOConfig)) | set(PSO_PER_SOLVE)
    assert declared == set(PSOSettings._fields)
    assert attributes_read([pso_ask, move_swarm], "s") == declared


@pytest.mark.parametrize("name", ["pso", "pso-constriction", "chaotic-pso"])
def test_packed_pso_settings_hold_each_field_under_its_own_name(name: str) -> None:
    optimizer = get_optimizer(name)
    box = Bounds(np.full(3, -1.0), np.full(3, 2.0))
    settings = PSOSettings(*optimizer.params(box, 17))
    for field in settings._fields:
        value = getattr(settings, field)
        if field == "t_max":
            assert value == 17
        elif field in ("lower", "upper"):
            np.testing.assert_array_equal(value, getattr(box, field))
            assert value.flags.writeable
        elif field == "v_max":
            np.testing.assert_array_equal(value, np.full(3, 3.0 * optimizer.velocity_clamp))
        else:
            assert value == kernel_value(getattr(optimizer, field))
            assert type(value) is type(kernel_value(getattr(optimizer, field)))
    assert pickle.loads(pickle.dumps(PSOSettings)) is PSOSettings


BSO_NAMES = [n for n in OPTIMIZERS if type(OPTIMIZERS[n].optimizer).__name__.endswith("BSO")]


@pytest.mark.parametrize("name", BSO_NAMES)
def test_packed_settings_hold_each_field_under_its_own_name(name: str) -> None:
    optimizer = get_optimizer(name)
    box = Bounds(np.full(3, -1.0), np.full(3, 2.0))
    packs = []
    if isinstance(optimizer, ModifiedBSOConfig):
        packs.append((KernelSettings, optimizer.params(box, 17)))
    if isinstance(optimizer, ShiConfig):
        packs.append((ShiSettings, optimizer.shi_settings(box, 17)))
    if isinstance(optimizer, LocalSearchConfig):
        from formation_bench.fields import pack_settings

        packs.append((LocalSettings, pack_settings(LocalSettings, optimizer)))
    assert packs
    for settings_class, packed in packs:
        settings = settings_class(*packed)
        for field in settings._fields:
            value = getattr(settings, field)
            if field == "t_max":
                assert value == 17
            elif field in ("lower", "upper"):
                np.testing.assert_array_equal(value, getattr(box, field))
                assert value.flags.writeable
            elif field != "scale":
                assert value == kernel_value(getattr(optimizer, field))
                assert type(value) is type(kernel_value(getattr(optimizer, field)))
        # numba's cache pickles the generated class by module and qualified name
        assert pickle.loads(pickle.dumps(settings_class)) is settings_class
        restored = pickle.loads(pickle.dumps(settings))
        assert type(restored) is settings_class and restored._fields == settings._fields


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
