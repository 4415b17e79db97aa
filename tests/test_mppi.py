"""MPPI: the kernels against the paper's equations in numpy, budgets, starts, settings."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers import Recorder
from test_compiled_loop import PlainCallable, same_result
from test_cost_and_problem import random_problem

from formation_bench.mpc.scenario import PAPER
from formation_bench.optimizers import MPPI, Bounds, Budget, get_optimizer
from formation_bench.optimizers.mppi import MPPISettings, mppi_ask, mppi_tell, mppi_update
from formation_bench.optimizers.plan_sampling import TemperatureScale, smooth_stages

LOWER, UPPER = np.tile([-2.0, -0.5], 3), np.tile([2.0, 0.5], 3)
BOX6 = Bounds(LOWER, UPPER)
"""D = 6, a stage-major plan of 3 stages and 2 channels of different ranges."""
X0 = np.array([1.9, 0.45, -1.0, 0.0, 0.5, -0.4])
"""A start near the faces, so that the samples are clipped."""


def quadratic(x: np.ndarray) -> np.ndarray:
    z = x - np.array([0.5, -0.2, 1.0, 0.1, -1.5, 0.3])
    return np.einsum("ij,j,ij->i", z, np.arange(1.0, 7.0), z) + z[:, 0] * z[:, 3]


def rosenbrock(x: np.ndarray) -> np.ndarray:
    return np.sum(100.0 * (x[:, 1:] - x[:, :-1] ** 2) ** 2 + (1.0 - x[:, :-1]) ** 2, axis=1)


def drive(optimizer, ask, tell, f, normals):  # type: ignore[no-untyped-def]
    """The batches ``ask`` gives from the fixed ``normals`` (one block per iteration), told
    their costs by ``f``, and the final state, from the start at :data:`X0` in :data:`BOX6`."""
    params = optimizer.params(BOX6, normals.shape[0])
    points = optimizer.initial_points(BOX6, np.random.default_rng(0), X0)
    state = optimizer.start(points, f(points), np.random.default_rng(0), params)
    batches = []
    for t, block in enumerate(normals, start=1):
        state, batch, last = ask(state, params, np.empty(0), block, t, 10**6)
        assert last
        state = tell(state, params, batch, f(batch), t)
        batches.append(batch)
    return batches, state


def reference_mppi(opt: MPPI, f, normals):  # type: ignore[no-untyped-def]
    """Williams et al. (2017), Algorithm 2, one iteration per block of normals."""
    stages = X0.size // opt.plan_channels
    sigma = np.tile(opt.noise_std * (UPPER - LOWER).reshape(stages, -1).mean(axis=0), stages)
    u, batches = X0.copy(), []
    for t, z in enumerate(normals):
        v = np.clip(u + sigma * z, LOWER, UPPER)
        eps = v - u  # the perturbation actually taken
        batches.append(v if t == 0 or not opt.evaluate_nominal else np.vstack([u, v]))
        cost = f(v)
        scale = {
            TemperatureScale.ABSOLUTE: 1.0,
            TemperatureScale.SPREAD: np.ptp(cost),
            TemperatureScale.MAD: np.median(np.abs(cost - np.median(cost))),
        }[opt.temperature_scale]
        lam = opt.temperature * scale
        s = cost + opt.control_cost * lam * eps @ (u / sigma**2)  # + gamma u^T Sigma^-1 eps
        w = np.exp(-(s - s.min()) / lam)
        du = (w / w.sum()) @ eps
        if opt.smoothing_window >= 3:
            h, steps = opt.smoothing_window // 2, du.reshape(stages, -1)
            du = np.concatenate(
                [steps[max(j - h, 0) : j + h + 1].mean(axis=0) for j in range(stages)]
            )
        u = np.clip(u + du, LOWER, UPPER)
    return batches, u


CONFIGS = {
    "default": MPPI(noise_std=0.2),
    "smooth": MPPI(noise_std=0.2, smoothing_window=3),
    "control-cost": MPPI(noise_std=0.2, control_cost=1.0, temperature=0.5),
    "absolute": MPPI(noise_std=0.2, temperature=3.0, temperature_scale="absolute"),
    "mad": MPPI(noise_std=0.2, temperature_scale="mad", population_size=7),
    "nominal-not-evaluated": MPPI(noise_std=0.2, evaluate_nominal=False, smoothing_window=5),
}


@pytest.mark.parametrize("f", [quadratic, rosenbrock], ids=["quadratic", "rosenbrock"])
@pytest.mark.parametrize("name", list(CONFIGS))
def test_kernels_follow_the_paper_equations(name: str, f) -> None:  # type: ignore[no-untyped-def]
    opt = CONFIGS[name]
    normals = np.random.default_rng(3).standard_normal((4, opt.population_size, 6))
    batches, state = drive(opt, mppi_ask, mppi_tell, f, normals)
    expected, nominal = reference_mppi(opt, f, normals)
    for got, want in zip(batches, expected, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(state.nominal, nominal, rtol=1e-12, atol=1e-12)
    assert np.any(batches[0] == UPPER) and np.any(batches[0] == LOWER)  # clipping happened
    assert not np.allclose(nominal, X0)


def test_smoothing_is_a_moving_average_along_the_stages() -> None:
    values = np.array([1.0, 10.0, 2.0, 20.0, 6.0, 60.0, 3.0, 30.0])  # 4 stages, 2 channels
    np.testing.assert_allclose(
        smooth_stages(values, 4, 3), [1.5, 15.0, 3.0, 30.0, 11 / 3, 110 / 3, 4.5, 45.0]
    )
    np.testing.assert_array_equal(smooth_stages(values, 4, 1), values)


def test_weights_at_zero_temperature_and_non_finite_costs() -> None:
    opt = MPPI()
    s = MPPISettings(*opt.params(BOX6, 1))
    nominal = np.zeros(6)
    samples = np.array([np.full(6, 0.1), np.full(6, -0.2), np.full(6, 0.3)])
    # equal finite costs: lambda = 0 relative to their spread, equal weights on them
    moved = mppi_update(nominal, samples, np.array([1.0, 1.0, math.nan]), s)
    np.testing.assert_allclose(moved, np.full(6, -0.05))
    unchanged = mppi_update(nominal, samples, np.full(3, math.inf), s)
    np.testing.assert_array_equal(unchanged, nominal)


@pytest.mark.parametrize("evaluations", [1, 2, 30, 31, 32, 61, 62, 100, 1240])
def test_spends_the_evaluation_budget_exactly(evaluations: int) -> None:
    rec = Recorder(quadratic)
    res = MPPI().minimize(rec, BOX6, np.random.default_rng(1), Budget(evaluations), X0)
    assert res.nfev == rec.points.shape[0] == evaluations
    np.testing.assert_array_equal(rec.points[0], X0)


def test_default_budget_and_batches() -> None:
    rec = Recorder(quadratic)
    res = get_optimizer("mppi").minimize(rec, BOX6, np.random.default_rng(1), None, X0)
    assert res.nfev == 1 + 30 + 39 * 31 and res.nit == 40
    assert rec.calls == [1, 30] + [31] * 39
    # each later batch leads with the nominal the previous samples moved to
    assert not np.array_equal(rec.batches[2][0], X0)


def test_no_worse_than_the_warm_start_and_deadline_keeps_the_best() -> None:
    for seed in range(5):
        x0 = BOX6.sample(np.random.default_rng(seed), 1)[0]
        res = MPPI().minimize(rosenbrock, BOX6, np.random.default_rng(seed), Budget(200), x0)
        assert res.fun <= rosenbrock(x0[None])[0]
    rec = Recorder(rosenbrock)
    budget = Budget(max_iterations=10**7, deadline_s=0.05)
    res = MPPI().minimize(rec, BOX6, np.random.default_rng(0), budget, X0)
    assert res.message == "deadline reached" and 1 <= res.nit < 10**7
    assert res.fun == rosenbrock(rec.points).min() == rosenbrock(res.x[None])[0]
    assert res.history_fun[-1] == res.fun and res.nfev == rec.points.shape[0]


def test_same_generator_same_answer() -> None:
    a, b, c = (
        MPPI().minimize(rosenbrock, BOX6, np.random.default_rng(seed), Budget(300), X0)
        for seed in (5, 5, 6)
    )
    assert same_result(a, b) and a.fun != c.fun


@pytest.mark.parametrize("name", ["mppi", "mppi-smooth"])
def test_the_python_objective_gives_the_compiled_result(name: str) -> None:
    problem = random_problem(np.random.default_rng(2), PAPER)
    x0 = problem.bounds.sample(np.random.default_rng(3), 1)[0]
    for budget, start in [(None, x0), (Budget(max_evaluations=95), None)]:
        runs = [
            get_optimizer(name).minimize(
                objective, problem.bounds, np.random.default_rng(4), budget, start
            )
            for objective in (problem, PlainCallable(problem))
        ]
        assert math.isnan(runs[0].info["objective_time_s"])
        assert same_result(*runs)


def test_a_plan_whose_length_is_not_a_multiple_of_the_channels_is_refused() -> None:
    box = Bounds(-np.ones(7), np.ones(7))
    with pytest.raises(ValueError, match=r"MPPI\.plan_channels = 2 .* dimension 7"):
        MPPI().minimize(quadratic, box, np.random.default_rng(0))
    assert (
        MPPI(plan_channels=7)
        .minimize(lambda x: np.sum(x * x, axis=1), box, np.random.default_rng(0), Budget(40))
        .nfev
        == 40
    )


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("plan_channels", 0),
        ("population_size", 0),
        ("max_iterations", -1),
        ("noise_std", 0.0),
        ("noise_std", 1.5),
        ("temperature", 0.0),
        ("temperature_scale", "median"),
        ("control_cost", 1.5),
        ("smoothing_window", 2),
        ("smoothing_window", -1),
        ("smoothing_window", True),
        ("evaluate_nominal", "yes"),
    ],
)
def test_invalid_settings_name_the_field(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=rf"MPPI\.{field} must"):
        MPPI(**{field: value})


def test_registered_variants() -> None:
    assert get_optimizer("mppi") == MPPI()
    assert get_optimizer("mppi-smooth") == MPPI(smoothing_window=3)
