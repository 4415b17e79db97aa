"""Declared config fields: every setting has a doc and a range; out-of-range values fail."""

from __future__ import annotations

import dataclasses
import enum
import math

import numpy as np
import pytest

from formation_bench import fields
from formation_bench.fields import declared, describe_fields, setting, validate_fields
from formation_bench.mpc.scenario import Scenario
from formation_bench.optimizers import OPTIMIZERS, ModifiedBSO, base, get_optimizer
from formation_bench.optimizers.chaos import ChaoticMap

NAMES = sorted(OPTIMIZERS)


def config_fields(obj: object) -> list[dataclasses.Field]:
    return [f for f in dataclasses.fields(obj) if f.init and not f.name.startswith("_")]


@pytest.mark.parametrize("name", NAMES)
def test_every_field_of_every_registered_optimizer_is_declared_with_doc_and_range(name: str):
    optimizer = get_optimizer(name)
    infos = {info.name: info for info in describe_fields(optimizer)}
    for field in config_fields(optimizer):
        assert field.name in infos, f"{name}: {field.name} is not declared with setting()"
        info = infos[field.name]
        assert info.doc and "\n" not in info.doc, f"{name}: {field.name} has no one-line doc"
        assert info.allowed, f"{name}: {field.name} has no allowed range"
        assert info.value == getattr(optimizer, field.name)


def test_every_scenario_field_is_declared_with_doc_and_range():
    infos = describe_fields(Scenario)
    assert [i.name for i in infos] == [f.name for f in dataclasses.fields(Scenario)]
    assert all(i.doc and i.allowed for i in infos)


def out_of_range(obj: object, spec: fields.Setting) -> list[object]:
    """Values the declaration must refuse (read against ``obj`` for limits naming a field)."""
    limit = fields._limit
    none = [] if spec.optional else [None]
    if spec.kind == "bool":
        return ["yes", 1, *none]
    if spec.kind == "enum":
        return ["no-such-member", True, *none]
    if spec.kind == "choice":
        return ["no-such-choice", *none]
    if spec.kind == "int":
        bad: list[object] = [limit(obj, spec.low) - 1, 2.5, True, "3", *none]
        if spec.high is not None:
            bad.append(limit(obj, spec.high) + 1)
        return bad
    if spec.kind == "real":
        low, high = limit(obj, spec.low), limit(obj, spec.high)
        bad = [math.nan, math.inf, "0.5", False, *none]
        if low is not None:
            bad.append(low if spec.low_open else low - 1.0)
        if high is not None:
            bad.append(high if spec.high_open else high + 1.0)
        return bad
    return [object()] if spec.check is not None else []


@pytest.mark.parametrize("name", NAMES)
def test_validate_fields_rejects_each_out_of_range_value_naming_the_field(name: str):
    optimizer = get_optimizer(name)
    owner = type(optimizer).__name__
    checked = 0
    for field in config_fields(optimizer):
        spec = declared(field)
        assert spec is not None
        for value in out_of_range(optimizer, spec):
            with pytest.raises(ValueError, match=rf"^{owner}\.{field.name} must"):
                dataclasses.replace(optimizer, **{field.name: value})
            checked += 1
    assert checked >= len(config_fields(optimizer))


@pytest.mark.parametrize("name", NAMES)
def test_declared_defaults_and_registered_values_pass_their_own_checks(name: str):
    optimizer = get_optimizer(name)
    again = dataclasses.replace(optimizer)
    assert again == optimizer


def test_messages_keep_their_wording():
    with pytest.raises(ValueError) as info:
        ModifiedBSO(n_clusters=40)
    assert str(info.value) == "ModifiedBSO.n_clusters must be an integer in [1, 30], got 40"
    with pytest.raises(ValueError) as info:
        ModifiedBSO(weight_map="x")
    allowed = ", ".join(m.name.lower() for m in ChaoticMap)
    assert str(info.value) == f"ModifiedBSO.weight_map must be one of {allowed}, got 'x'"
    with pytest.raises(ValueError) as info:
        ModifiedBSO(slope=0.0)
    assert str(info.value) == "ModifiedBSO.slope must be a finite number in (0.0, inf), got 0.0"
    with pytest.raises(ValueError) as info:
        ModifiedBSO(population_size=1)
    assert str(info.value) == "ModifiedBSO.population_size must be an integer >= 2, got 1"


def test_values_are_normalised():
    optimizer = ModifiedBSO(
        population_size=np.int64(20),
        slope=np.float32(4),
        weight_map="Tent",
        normalise_weights=np.True_,
    )
    assert type(optimizer.population_size) is int and optimizer.population_size == 20
    assert type(optimizer.slope) is float and optimizer.slope == 4.0
    assert optimizer.weight_map is ChaoticMap.TENT
    assert optimizer.normalise_weights is True


def test_a_cross_field_limit_reads_the_other_field():
    assert ModifiedBSO(population_size=8, n_clusters=8).n_clusters == 8
    with pytest.raises(ValueError, match=r"n_clusters must be an integer in \[1, 8\], got 9"):
        ModifiedBSO(population_size=8, n_clusters=9)


@dataclasses.dataclass(frozen=True)
class Example:
    count: int = setting(3, low=1, high=lambda obj: int(2 * obj.size), doc="A count")
    size: float = setting(1.5, low=0.0, high=2.0, high_open=True, doc="A size")
    limit: int | None = setting(None, kind=int, optional=True, low=0, doc="An optional limit")
    mode: str = setting("a", choices=("a", "b"), doc="A mode")
    pair: tuple[int, int] = setting((1, 2), allowed="two integers", doc="A pair")

    def __post_init__(self) -> None:
        validate_fields(self)


def test_open_ends_optional_values_callables_and_choices():
    assert Example(size=1.99).size == 1.99
    with pytest.raises(ValueError, match=r"Example\.size must be a finite number in \[0.0, 2.0\)"):
        Example(size=2.0)
    assert Example(limit=None).limit is None and Example(limit=4).limit == 4
    with pytest.raises(ValueError, match=r"Example\.limit must be an integer >= 0, got -1"):
        Example(limit=-1)
    with pytest.raises(ValueError, match=r"Example\.count must be an integer in \[1, 3\]"):
        Example(count=4)  # count is checked before size: the limit reads the given size
    with pytest.raises(ValueError, match=r"Example\.mode must be one of a, b, got 'c'"):
        Example(mode="c")
    infos = {i.name: i for i in describe_fields(Example)}
    assert infos["size"].allowed == "finite number in [0.0, 2.0)"
    assert infos["limit"].allowed == "integer >= 0, or None"
    assert infos["mode"].allowed == "one of a, b"
    assert infos["pair"].allowed == "two integers"
    assert infos["count"].type == "int" and infos["count"].default == 3


def test_describe_fields_of_a_registered_configuration():
    infos = {i.name: i for i in describe_fields(get_optimizer("modified-bso-tent"))}
    assert infos["n_clusters"].allowed == "integer in [1, population_size]"
    assert infos["weight_map"].default is ChaoticMap.LOGISTIC
    assert infos["weight_map"].value is ChaoticMap.TENT
    assert infos["weight_map"].type == "ChaoticMap"


def test_a_setting_needs_a_one_line_doc_and_a_known_kind():
    with pytest.raises(ValueError, match="one-line doc"):
        setting(1, low=0, doc="")
    with pytest.raises(TypeError, match="kind"):
        setting([1], doc="a list")
    with pytest.raises(ValueError, match="needs low"):
        setting(1, doc="no low")


def test_the_old_helpers_are_still_importable_from_base():
    for name in ("check_int", "check_real", "check_bool", "coerce_enum"):
        assert getattr(base, name) is getattr(fields, name)


# --- the registry: every name still maps to the configuration it had -------------------------
# Written out rather than computed so that a default or a variant changed while its settings
# were moved into declarations shows up here: for every registered name, the class, the
# description and the fields that differ from the class's defaults, and every class's defaults
# (enum members by lower-case name).

REGISTERED = {
    "chaotic-pso": (
        "PSO",
        "Chaotic PSO (after Alatas et al. 2009): logistic r1, r2 and chaotic inertia weight",
        {"chaotic_coefficients": True, "chaotic_inertia": True},
    ),
    "chaotic-pso-coefficients": (
        "PSO",
        "Chaotic PSO: logistic sequences for r1, r2 only (linear inertia 0.9 -> 0.4)",
        {"chaotic_coefficients": True},
    ),
    "chaotic-pso-inertia": (
        "PSO",
        "Chaotic PSO: Feng et al.'s chaotic inertia weight only (uniform r1, r2)",
        {"chaotic_inertia": True},
    ),
    "cls-bso": (
        "ChaoticLocalSearchBSO",
        "Shi's BSO + chaotic local search around the best idea (after CBSO, Yu et al. 2018)",
        {},
    ),
    "cma-es": (
        "CMAES",
        "CMA-ES (Hansen's tutorial, active) with pycma's constants and BoundTransform, "
        "sigma0 0.2 x range, restarts same lambda",
        {},
    ),
    "cma-es-bipop": (
        "CMAES",
        "BIPOP-CMA-ES: large and small population restarts interleaved (Hansen 2009)",
        {"restarts": "bipop"},
    ),
    "cma-es-ipop": (
        "CMAES",
        "IPOP-CMA-ES: restarts doubling the population (Auger & Hansen 2005)",
        {"restarts": "ipop"},
    ),
    "cma-es-warm": (
        "CMAES",
        "CMA-ES for a nearly right warm start: sigma0 0.02 x range (tuned on the validation split)",
        {"sigma0": 0.02},
    ),
    "de": (
        "DifferentialEvolution",
        "Differential evolution DE/rand/1/bin (Storn & Price 1997), N = 30, F = 0.5, CR = 0.9",
        {},
    ),
    "de-current-to-best": (
        "DifferentialEvolution",
        "Differential evolution DE/current-to-best/1/bin, N = 30, F = 0.5, CR = 0.9",
        {"strategy": "current_to_best_1_bin"},
    ),
    "de-immediate": (
        "DifferentialEvolution",
        "Differential evolution DE/rand/1/bin, N = 30, F = 0.5, CR = 0.9, immediate updating "
        "(each trial selected before the next is made: scipy's default)",
        {"updating": "immediate"},
    ),
    "de-immediate-warm": (
        "DifferentialEvolution",
        "de-immediate with 90% of the initial population drawn around the warm start (std "
        "0.02 x range), the rest uniform",
        {"updating": "immediate", "warm_start_share": 0.9, "warm_start_spread": 0.02},
    ),
    "ipopt": (
        "IpoptOptimizer",
        "IPOPT (CasADi nlpsol) on eq. (14), single shooting, warm primal + dual start; baseline",
        {},
    ),
    "ltv-osqp": (
        "LtvOsqpOptimizer",
        "Linear time-varying MPC: QP linearised about the shifted plan, OSQP, 1 SQP round; "
        "baseline",
        {},
    ),
    "modified-bso": (
        "ModifiedBSO",
        "Modified BSO of the paper: chaotic centre replacement + chaotic all-centre weighting",
        {},
    ),
    "modified-bso-chebyshev": (
        "ModifiedBSO",
        "Modified BSO with the chebyshev map as f_rmap and f_hmap",
        {"replacement_map": "chebyshev", "weight_map": "chebyshev"},
    ),
    "modified-bso-circle": (
        "ModifiedBSO",
        "Modified BSO with the circle map as f_rmap and f_hmap",
        {"replacement_map": "circle", "weight_map": "circle"},
    ),
    "modified-bso-gauss": (
        "ModifiedBSO",
        "Modified BSO with the gauss map as f_rmap and f_hmap",
        {"replacement_map": "gauss", "weight_map": "gauss"},
    ),
    "modified-bso-iterative": (
        "ModifiedBSO",
        "Modified BSO with the iterative map as f_rmap and f_hmap",
        {"replacement_map": "iterative", "weight_map": "iterative"},
    ),
    "modified-bso-no-all-centre": (
        "ModifiedBSO",
        "Modified BSO ablation: Shi's idea selection instead of all-centre weighting (eqs. 8-9)",
        {"all_centre_weighting": False},
    ),
    "modified-bso-no-chaos-replacement": (
        "ModifiedBSO",
        "Modified BSO ablation: without the chaotic centre replacement (eqs. 6-7)",
        {"chaos_replacement": False},
    ),
    "modified-bso-no-modifications": (
        "ModifiedBSO",
        "Modified BSO with both modifications off (Shi's BSO without random centre replacement)",
        {"all_centre_weighting": False, "chaos_replacement": False},
    ),
    "modified-bso-piecewise": (
        "ModifiedBSO",
        "Modified BSO with the piecewise map as f_rmap and f_hmap",
        {"replacement_map": "piecewise", "weight_map": "piecewise"},
    ),
    "modified-bso-raw-weights": (
        "ModifiedBSO",
        "Modified BSO with the raw, unnormalised chaotic weights printed in eq. (9)",
        {"normalise_weights": False},
    ),
    "modified-bso-sine": (
        "ModifiedBSO",
        "Modified BSO with the sine map as f_rmap and f_hmap",
        {"replacement_map": "sine", "weight_map": "sine"},
    ),
    "modified-bso-singer": (
        "ModifiedBSO",
        "Modified BSO with the singer map as f_rmap and f_hmap",
        {"replacement_map": "singer", "weight_map": "singer"},
    ),
    "modified-bso-sinusoidal": (
        "ModifiedBSO",
        "Modified BSO with the sinusoidal map as f_rmap and f_hmap",
        {"replacement_map": "sinusoidal", "weight_map": "sinusoidal"},
    ),
    "modified-bso-tent": (
        "ModifiedBSO",
        "Modified BSO with the tent map as f_rmap and f_hmap",
        {"replacement_map": "tent", "weight_map": "tent"},
    ),
    "original-bso": (
        "OriginalBSO",
        "Shi's (2011) BSO as published: k-means, random-point centre replacement, "
        "logsig N(0,1) step",
        {},
    ),
    "original-bso-range-step": (
        "OriginalBSO",
        "Shi's BSO with the modified BSO's step (0.1 x range instead of N(0, 1))",
        {"step_relative_to_range": True, "step_scale": 0.1},
    ),
    "original-bso-warm": (
        "OriginalBSO",
        "original-bso with 90% of the initial ideas drawn around the warm start (std 0.005 x "
        "range), the rest uniform; not Shi's start",
        {"warm_start_share": 0.9, "warm_start_spread": 0.005},
    ),
    "pso": (
        "PSO",
        "Global-best PSO, inertia 0.9 -> 0.4, c1 = c2 = 2, velocity clamp 0.2 x range, clip",
        {},
    ),
    "pso-constriction": (
        "PSO",
        "Global-best PSO with Clerc-Kennedy constriction (chi = 0.7298, c1 = c2 = 1.49618)",
        {"c1": 1.49618, "c2": 1.49618, "inertia_end": 0.7298, "inertia_start": 0.7298},
    ),
    "random-search": (
        "RandomSearch",
        "Uniform random search, 30 points per batch (the floor every optimiser must beat)",
        {},
    ),
    # the adapters (registered when their library is installed: the adapters extra)
    "mealpy-bso": (
        "MealpyOptimizer",
        "mealpy's OriginalBSO (Shi's BSO as mealpy publishes it), pop 30",
        {},
    ),
    "mealpy-gwo": (
        "MealpyOptimizer",
        "mealpy's grey wolf optimizer (OriginalGWO), pop 30",
        {"algorithm": "OriginalGWO"},
    ),
    "modified-bso-warm": (
        "ModifiedBSO",
        "modified-bso with 90% of the initial population drawn around the warm start (std "
        "0.005 x range), the rest uniform; not the paper's start",
        {"warm_start_share": 0.9, "warm_start_spread": 0.005},
    ),
    "ng-de": (
        "NevergradOptimizer",
        "nevergrad's TwoPointsDE (its DE for parallel settings), 30 per batch",
        {"algorithm": "TwoPointsDE"},
    ),
    "ng-ngopt": (
        "NevergradOptimizer",
        "nevergrad's NGOpt (picks its algorithm for the dimension and budget), 30 per batch",
        {},
    ),
    "pso-warm": (
        "PSO",
        "pso with 90% of the initial swarm drawn around the warm start (std 0.005 x range), "
        "the rest uniform",
        {"warm_start_share": 0.9, "warm_start_spread": 0.005},
    ),
    "pycma": (
        "PyCMA",
        "pycma's CMA-ES (BoundTransform, default popsize), restarts with the same popsize",
        {},
    ),
}

CLASS_DEFAULTS = {
    "CMAES": {
        "active": True,
        "bound_handling": "transform",
        "constants": "pycma",
        "lamarckian": False,
        "max_evaluations": 1230,
        "population_size": None,
        "restarts": "same",
        "sigma0": 0.2,
        "tol_fun": 1e-12,
        "tol_x": 1e-12,
    },
    "ChaoticLocalSearchBSO": {
        "bound_handling": "clip",
        "kmeans_max_iter": 100,
        "local_map": "logistic",
        "local_radius_end": 0.001,
        "local_radius_start": 0.1,
        "max_iterations": 40,
        "n_clusters": 5,
        "n_local": 5,
        "p_one_centre": 0.4,
        "p_one_cluster": 0.8,
        "p_replace": 0.2,
        "p_two_centres": 0.5,
        "population_size": 25,
        "slope": 20.0,
        "step_relative_to_range": False,
        "step_scale": 1.0,
        "warm_start_share": 0.0,
        "warm_start_spread": 0.05,
    },
    "DifferentialEvolution": {
        "bound_handling": "resample",
        "crossover_rate": 0.9,
        "differential_weight": 0.5,
        "max_iterations": 40,
        "population_size": 30,
        "strategy": "rand_1_bin",
        "updating": "deferred",
        "warm_start_share": 0.0,
        "warm_start_spread": 0.05,
    },
    "IpoptOptimizer": {
        "acceptable_tol": 0.0001,
        "bound_push": 1e-06,
        "ipopt_options": (),
        "jit": False,
        "max_iter": 100,
        "mu_init": 0.0001,
        "mu_strategy": "adaptive",
        "shooting": "single",
        "tol": 1e-06,
        "warm_start_duals": True,
    },
    "LtvOsqpOptimizer": {
        "eps_abs": 0.0001,
        "eps_rel": 0.0001,
        "form": "condensed",
        "max_iter": 20000,
        "polishing": None,
        "sqp_iterations": 1,
    },
    "ModifiedBSO": {
        "all_centre_weighting": True,
        "bound_handling": "clip",
        "chaos_replacement": True,
        "clustering": "compiled",
        "kmeans_max_iter": 100,
        "max_iterations": 40,
        "n_clusters": 5,
        "n_replace": 10,
        "n_weight_iterations": 10,
        "normalise_weights": True,
        "p_one_centre": 0.4,
        "p_one_cluster": 0.8,
        "p_replace": 0.2,
        "p_two_centres": 0.5,
        "population_size": 30,
        "replacement_map": "logistic",
        "slope": 20.0,
        "step_relative_to_range": True,
        "step_scale": 0.1,
        "weight_map": "logistic",
        "warm_start_share": 0.0,
        "warm_start_spread": 0.05,
    },
    "OriginalBSO": {
        "bound_handling": "clip",
        "kmeans_max_iter": 100,
        "max_iterations": 40,
        "n_clusters": 5,
        "p_one_centre": 0.4,
        "p_one_cluster": 0.8,
        "p_replace": 0.2,
        "p_two_centres": 0.5,
        "population_size": 30,
        "slope": 20.0,
        "step_relative_to_range": False,
        "step_scale": 1.0,
        "warm_start_share": 0.0,
        "warm_start_spread": 0.05,
    },
    "PSO": {
        "bound_handling": "clip",
        "c1": 2.0,
        "c2": 2.0,
        "chaotic_coefficients": False,
        "chaotic_inertia": False,
        "coefficient_map": "logistic",
        "inertia_end": 0.4,
        "inertia_map": "logistic",
        "inertia_start": 0.9,
        "max_iterations": 40,
        "population_size": 30,
        "velocity_clamp": 0.2,
        "warm_start_share": 0.0,
        "warm_start_spread": 0.05,
    },
    "RandomSearch": {
        "max_iterations": 40,
        "population_size": 30,
    },
    "MealpyOptimizer": {
        "algorithm": "OriginalBSO",
        "max_evaluations": 1230,
        "population_size": 30,
    },
    "NevergradOptimizer": {
        "algorithm": "NGOpt",
        "batch_size": 30,
        "max_evaluations": 1230,
    },
    "PyCMA": {
        "max_evaluations": 1230,
        "population_size": None,
        "sigma0": 0.2,
    },
}


def plain(value: object) -> object:
    return value.name.lower() if isinstance(value, enum.Enum) else value


def field_values(obj: object) -> dict[str, object]:
    return {f.name: plain(getattr(obj, f.name)) for f in config_fields(obj)}


def test_the_registry_holds_the_same_names():
    # an adapter whose library is not installed is noted as missing instead
    assert sorted(OPTIMIZERS) == sorted(set(REGISTERED) - set(OPTIMIZERS.missing()))


@pytest.mark.parametrize("name", sorted(REGISTERED))
def test_a_registered_name_maps_to_the_same_configuration(name: str):
    if name in OPTIMIZERS.missing():
        pytest.skip(f"{name}: {OPTIMIZERS.missing()[name]}")
    class_name, description, overrides = REGISTERED[name]
    entry = OPTIMIZERS[name]
    assert type(entry.optimizer).__name__ == class_name
    assert entry.description == description
    assert field_values(entry.optimizer) == {**CLASS_DEFAULTS[class_name], **overrides}


@pytest.mark.parametrize("class_name", sorted(CLASS_DEFAULTS))
def test_declared_defaults_are_the_previous_defaults(class_name: str):
    optimizer = next(
        (e.optimizer for e in OPTIMIZERS.values() if type(e.optimizer).__name__ == class_name),
        None,
    )
    if optimizer is None:
        pytest.skip(f"no {class_name} is registered here (an adapter whose library is missing)")
    assert field_values(type(optimizer)()) == CLASS_DEFAULTS[class_name]


@dataclasses.dataclass(frozen=True)
class _DeclaredOnly(base.Optimizer):
    """Declares its setting but never validates it itself (no ``Validated``)."""

    population_size: int = setting(4, low=1, doc="Points per iteration")

    @property
    def default_budget(self) -> base.Budget:
        return base.Budget(max_iterations=1)

    def minimize(self, objective, bounds, rng, budget=None, x0=None):  # pragma: no cover
        raise AssertionError("only registered and configured here, never asked to solve")


@dataclasses.dataclass(frozen=True)
class _Undeclared(_DeclaredOnly):
    max_iterations: int = 3


def test_the_registry_checks_declared_settings_and_refuses_undeclared_ones():
    from formation_bench.optimizers import register

    try:
        register("declared-only", _DeclaredOnly(), "settings checked by the registry")
        assert get_optimizer("declared-only", population_size=2).population_size == 2
        with pytest.raises(ValueError, match=r"_DeclaredOnly\.population_size must be an integer"):
            get_optimizer("declared-only", population_size=0)
        with pytest.raises(ValueError, match=r"_DeclaredOnly\.population_size must be"):
            register("declared-bad-default", _DeclaredOnly(population_size=0), "a bad default")
        with pytest.raises(TypeError, match=r"declare max_iterations of _Undeclared with"):
            register("undeclared", _Undeclared(), "a field without setting()")
        assert "declared-bad-default" not in OPTIMIZERS and "undeclared" not in OPTIMIZERS
    finally:
        OPTIMIZERS.pop("declared-only", None)
