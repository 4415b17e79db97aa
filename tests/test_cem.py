"""CEM and iCEM: the kernels against the paper's equations in plain numpy, the coloured noise
against a direct FFT, and the budget, warm start, deadline, seeding and settings."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from helpers import Recorder
from test_cost_and_problem import random_problem
from test_iteration_kernels import attributes_read, settings_passed_on

from formation_bench.mpc.scenario import PAPER
from formation_bench.optimizers import clock as solve_clock
from formation_bench.optimizers import get_optimizer
from formation_bench.optimizers.base import Bounds, Budget
from formation_bench.optimizers.cem import CEM, CEMSettings, cem_ask, cem_tell
from formation_bench.optimizers.cem_update import batch_size
from formation_bench.optimizers.coloured_noise import coloured_normals, noise_matrix

NAMES = ["cem", "icem", "icem-white"]
D = 6
BOX = Bounds(
    np.array([-2.0, -1.0, -2.0, -1.0, -2.0, -1.0]), np.array([2.0, 3.0, 2.0, 3.0, 2.0, 3.0])
)
X0 = np.array([0.5, 0.0, -0.3, 0.8, 1.0, 1.2])


def quadratic(x: np.ndarray) -> np.ndarray:
    return ((x - np.linspace(-1.0, 1.5, D)) ** 2 * np.arange(1.0, D + 1)).sum(axis=1)


def rosenbrock(x: np.ndarray) -> np.ndarray:
    return (100.0 * (x[:, 1:] - x[:, :-1] ** 2) ** 2 + (1.0 - x[:, :-1]) ** 2).sum(axis=1)


# --- the paper's equations in plain numpy ------------------------------------------------------


def fft_coloured(z: np.ndarray, beta: float) -> np.ndarray:
    """One series of Timmer & Koenig's construction as ``colorednoise`` computes it, fed by
    ``z``: the real parts of frequencies 0 .. h // 2, then the imaginary parts of 1 ..
    (h - 1) // 2; scaled to unit variance with the variance of the inverse real FFT."""
    h = z.shape[0]
    f = np.fft.rfftfreq(h)
    scale = np.where(f < 1.0 / h, 1.0 / h, f) ** (-beta / 2)
    n_freq = h // 2 + 1
    real, imag = z[:n_freq] * scale, np.zeros(n_freq)
    imag[1 : 1 + (h - 1) // 2] = z[n_freq:] * scale[1 : 1 + (h - 1) // 2]
    real[0] *= math.sqrt(2)
    if h % 2 == 0:
        real[-1] *= math.sqrt(2)
    series = np.fft.irfft(real + 1j * imag, n=h)
    # var(y_t) = (2 s_0^2 + 4 sum_{0 < k < h/2} s_k^2 + [h even] 2 s_{h/2}^2) / h^2
    inner = scale[1 : 1 + (h - 1) // 2]
    variance = 2 * scale[0] ** 2 + 4 * np.sum(inner**2) + (2 * scale[-1] ** 2 if h % 2 == 0 else 0)
    return series / math.sqrt(variance / h**2)


def noise_of(z: np.ndarray, beta: float, channels: int) -> np.ndarray:
    """The noise of one sample: one series per channel over the stages (stage-major)."""
    if beta == 0:
        return z
    block = z.reshape(-1, channels)
    return np.stack([fft_coloured(block[:, c], beta) for c in range(channels)], axis=1).ravel()


def reference_cem(f, opt: CEM, normals, t_max: int, evaluations: int):
    """Algorithm 1 of Pinneri et al. (2020) for one control step, from the warm start X0:
    the batches evaluated and the final mean and std. ``normals(i, m)`` gives iteration
    ``i``'s ``(m, D)`` standard normals."""
    n, k, alpha = opt.population_size, opt.elite_count, opt.momentum
    keep = int(opt.keep_elites * k + 1e-9)
    mean, std = X0.copy(), opt.initial_std * BOX.width
    kept, kept_f = X0[None][:keep], f(X0[None])[:keep]
    left, batches = evaluations - 1, []
    for i in range(t_max):
        n_i = min(n, max(math.floor(n * opt.sample_decay**-i), 2 * k))
        add_mean = opt.sample_mean_last and (i + 1 == t_max or left <= n_i + 1)
        drawn = min(n_i, left - add_mean)
        noise = [noise_of(z, opt.noise_exponent, opt.plan_channels) for z in normals(i, drawn)]
        x = np.clip(mean + std * np.reshape(noise, (drawn, D)), BOX.lower, BOX.upper)
        if add_mean:
            x = np.vstack([x, mean])
        costs = f(x)
        left -= x.shape[0]
        batches.append(x)
        pool, pool_f = np.vstack([x, kept]), np.concatenate([costs, kept_f])
        order = np.argsort(pool_f, kind="stable")
        elites = pool[order[:k]]
        mean = alpha * mean + (1 - alpha) * elites.mean(axis=0)
        std = alpha * std + (1 - alpha) * elites.std(axis=0)
        kept, kept_f = elites[:keep], pool_f[order[:keep]]
        if left <= 0:
            break
    return batches, mean, std


def kernel_cem(f, opt: CEM, normals: np.ndarray, t_max: int, evaluations: int):
    """The same, with the compiled ``ask`` and ``tell`` driven by the same normals."""
    params = opt.params(BOX, t_max)
    start = opt.initial_points(BOX, np.random.default_rng(0), X0)
    state = opt.start(start, f(start), np.random.default_rng(0), params)
    left, batches = evaluations - 1, []
    for i in range(t_max):
        state, x, last = cem_ask(state, params, np.empty(0), normals[i], i + 1, left)
        assert last and x.shape[0] <= left
        state = cem_tell(state, params, x, f(x), i + 1)
        left -= x.shape[0]
        batches.append(x)
        if left <= 0:
            break
    return batches, state.mean, state.std


CONFIGS = {
    "cem": CEM(population_size=10, elite_count=3),
    "momentum-0.5": CEM(population_size=10, elite_count=4, momentum=0.5, initial_std=0.4),
    "coloured": CEM(population_size=10, elite_count=3, noise_exponent=2.0),
    "kept": CEM(population_size=10, elite_count=4, keep_elites=0.5),
    "icem": CEM(
        population_size=14,
        elite_count=3,
        noise_exponent=2.5,
        keep_elites=0.7,
        sample_decay=1.25,
        sample_mean_last=True,
    ),
}
# three stages of two channels: the noise is white at any beta (the mean takes the scale of
# the one frequency); six stages of one channel are coloured
CONFIGS["coloured-6-stages"] = dataclasses.replace(CONFIGS["coloured"], plan_channels=1)
CONFIGS["icem-6-stages"] = dataclasses.replace(CONFIGS["icem"], plan_channels=1)


@pytest.mark.parametrize("objective", [quadratic, rosenbrock], ids=["quadratic", "rosenbrock"])
@pytest.mark.parametrize("name", list(CONFIGS))
@pytest.mark.parametrize(("t_max", "evaluations"), [(5, 10_000), (9, 60)])
def test_kernels_are_the_papers_equations(name, objective, t_max, evaluations) -> None:
    opt = CONFIGS[name]
    normals = np.random.default_rng(11).standard_normal((t_max, opt.population_size, D))
    ours = kernel_cem(objective, opt, normals, t_max, evaluations)
    theirs = reference_cem(objective, opt, lambda i, m: normals[i, :m], t_max, evaluations)
    assert [b.shape for b in ours[0]] == [b.shape for b in theirs[0]]
    for a, b in zip(ours[0], theirs[0], strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ours[1], theirs[1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(ours[2], theirs[2], rtol=0, atol=1e-12)
    assert not np.allclose(ours[1], X0)  # the distribution moved


@pytest.mark.parametrize("name", ["cem", "icem", "icem-6-stages"])
def test_a_solve_evaluates_the_reference_batches_on_the_normals_of_its_samples(name) -> None:
    """The solve draws the standard normals of its samples, in order, and no others."""
    opt = CONFIGS[name]
    evaluations, t_max = 80, opt.planned_iterations(Budget(max_evaluations=80))
    rec = Recorder(rosenbrock)
    rng = np.random.default_rng(5)
    res = opt.minimize(rec, BOX, rng, Budget(max_evaluations=evaluations), X0)
    stream = np.random.default_rng(5)
    batches, _, _ = reference_cem(
        rosenbrock, opt, lambda i, m: stream.standard_normal((m, D)), t_max, evaluations
    )
    np.testing.assert_allclose(rec.points, np.vstack([X0[None], *batches]), rtol=0, atol=1e-12)
    assert res.nfev == evaluations and res.nit == t_max == len(batches)
    assert res.fun == rosenbrock(rec.points).min()
    assert rng.bit_generator.state == stream.bit_generator.state


@pytest.mark.parametrize("name", NAMES)
def test_the_numbers_do_not_depend_on_how_the_iterations_are_blocked(name) -> None:
    """A deadline is checked inside a block of iterations; a far one changes nothing."""
    opt = get_optimizer(name)
    a, b = (
        opt.minimize(quadratic, BOX, np.random.default_rng(3), budget, X0)
        for budget in (Budget(max_evaluations=900), Budget(max_evaluations=900, deadline_s=1e6))
    )
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.history_fun, b.history_fun)
    assert (a.fun, a.nfev, a.nit) == (b.fun, b.nfev, b.nit)


# --- the coloured noise ------------------------------------------------------------------------


@pytest.mark.parametrize("stages", [2, 3, 4, 5, 8, 11])
@pytest.mark.parametrize("beta", [0.5, 1.0, 2.0, 2.5])
def test_noise_matrix_is_the_direct_fft_with_unit_variance(stages, beta) -> None:
    matrix = noise_matrix(beta, stages)
    z = np.random.default_rng(stages).standard_normal((7, stages))
    direct = np.array([fft_coloured(row, beta) for row in z])
    np.testing.assert_allclose(z @ matrix.T, direct, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.sum(matrix**2, axis=1), 1.0, rtol=0, atol=1e-12)
    # red noise: neighbouring stages correlate, more so for larger beta (up to 3 stages the
    # mean takes the scale of the one frequency, and the noise is white at any beta)
    if stages > 3:
        neighbours = np.sum(matrix[:-1] * matrix[1:], axis=1)
        redder = noise_matrix(beta + 1, stages)
        assert np.all(neighbours > 0)
        assert np.all(neighbours < np.sum(redder[:-1] * redder[1:], axis=1))


def test_white_noise_is_the_normals_themselves_and_colorednoise_is_off_at_short_horizons():
    np.testing.assert_array_equal(noise_matrix(0.0, 5), np.eye(5))
    np.testing.assert_array_equal(noise_matrix(2.0, 1), np.eye(1))
    # colorednoise's "theoretical" sigma (2 sqrt(sum w^2) / h, w the scales after f = 0, the
    # last halved for even h) against the actual one: 1.18 times too small at h = 5, beta = 2
    h, beta = 5, 2.0
    scale = np.maximum(np.fft.rfftfreq(h), 1 / h) ** (-beta / 2)
    theirs = 2 * math.sqrt(np.sum(scale[1:] ** 2)) / h
    actual = math.sqrt(2 * scale[0] ** 2 + 4 * np.sum(scale[1:] ** 2)) / h
    assert actual / theirs == pytest.approx(1.183, abs=1e-3)


def test_coloured_normals_colour_each_channel_over_the_stages() -> None:
    matrix = noise_matrix(2.0, 3)
    normals = np.random.default_rng(1).standard_normal((4, D))
    ours = coloured_normals(normals, matrix)
    for j in range(4):
        np.testing.assert_allclose(ours[j].reshape(3, 2), matrix @ normals[j].reshape(3, 2),
                                   rtol=0, atol=1e-14)  # fmt: skip


# --- budget, warm start, deadline, seeding ----------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("evaluations", [1, 2, 3, 21, 22, 23, 100, 457, 1230, 5000])
def test_the_evaluation_budget_is_spent_exactly_as_planned(name, evaluations) -> None:
    opt = get_optimizer(name)
    rec = Recorder(quadratic)
    budget = Budget(max_evaluations=evaluations)
    res = opt.minimize(rec, BOX, np.random.default_rng(2), budget, X0)
    assert res.nfev == rec.points.shape[0] == evaluations
    assert res.nit == opt.planned_iterations(budget) == len(rec.batches) - 1


def test_an_iteration_budget_draws_the_decaying_sample_sizes_and_the_mean_last() -> None:
    opt = get_optimizer("icem")
    n, k = opt.population_size, opt.elite_count
    rec = Recorder(quadratic)
    res = opt.minimize(rec, BOX, np.random.default_rng(2), Budget(max_iterations=12), X0)
    sizes = [max(math.floor(n * 1.25**-i), 2 * k) for i in range(12)]
    assert sizes[0] == n and sizes[-1] == 2 * k  # decays to its floor within the budget
    assert rec.calls == [1, *sizes[:-1], sizes[-1] + 1]
    assert res.nit == 12 and res.nfev == sum(rec.calls)


def test_the_default_budget_is_that_of_the_other_population_methods() -> None:
    for name in NAMES:
        res = get_optimizer(name).minimize(quadratic, BOX, np.random.default_rng(3))
        assert res.nfev == 1230 and res.message == "evaluation budget reached"


@pytest.mark.parametrize("name", ["cem", "icem"])
def test_the_warm_start_is_never_worsened(name) -> None:
    opt = get_optimizer(name, initial_std=0.5)
    for seed in range(10):
        x0 = np.clip(np.ones(D) + 0.01 * np.random.default_rng(seed).standard_normal(D),
                     BOX.lower, BOX.upper)  # fmt: skip
        res = opt.minimize(rosenbrock, BOX, np.random.default_rng(seed),
                           Budget(max_evaluations=40), x0)  # fmt: skip
        assert res.fun <= rosenbrock(x0[None])[0]
        assert BOX.contains(res.x)


@pytest.mark.parametrize("name", ["cem", "icem"])
def test_a_deadline_returns_the_best_point_so_far(name, monkeypatch) -> None:
    """A clock that each objective call advances by 1 ms (no waiting): a 10.5 ms deadline
    ends the solve after the start and ten iterations."""
    now_ns = [0]
    monkeypatch.setattr(solve_clock, "SOLVE_CLOCK", solve_clock.python_clock(lambda: now_ns[0]))

    def slow(x: np.ndarray) -> np.ndarray:
        now_ns[0] += 1_000_000
        return rosenbrock(x)

    rec = Recorder(slow)
    budget = Budget(max_iterations=10_000, deadline_s=0.0105)
    res = get_optimizer(name).minimize(rec, BOX, np.random.default_rng(4), budget, X0)
    assert res.message == "deadline reached" and res.nit == 10
    costs = rosenbrock(rec.points)
    assert res.fun == costs.min() == res.history_fun[-1]
    np.testing.assert_array_equal(res.x, rec.points[np.argmin(costs)])


@pytest.mark.parametrize("name", ["cem", "icem"])
def test_the_python_and_the_compiled_objective_give_the_same_solve(name) -> None:
    problem = random_problem(np.random.default_rng(6), PAPER)
    x0 = problem.bounds.sample(np.random.default_rng(7), 1)[0]
    opt = get_optimizer(name)
    results, states = [], []
    for objective in (problem, lambda x: problem(x)):
        rng = np.random.default_rng(8)
        results.append(opt.minimize(objective, problem.bounds, rng, Budget(max_evaluations=300),
                                    x0))  # fmt: skip
        states.append(rng.bit_generator.state)
    compiled, plain = results
    np.testing.assert_array_equal(compiled.x, plain.x)
    assert (compiled.fun, compiled.nfev, compiled.nit) == (plain.fun, plain.nfev, plain.nit)
    np.testing.assert_array_equal(compiled.history_fun, plain.history_fun)
    assert states[0] == states[1]
    assert compiled.fun < problem(x0[None])[0]
    again = opt.minimize(problem, problem.bounds, np.random.default_rng(8),
                         Budget(max_evaluations=300), x0)  # fmt: skip
    other = opt.minimize(problem, problem.bounds, np.random.default_rng(9),
                         Budget(max_evaluations=300), x0)  # fmt: skip
    assert again.fun == compiled.fun and other.fun != compiled.fun


# --- settings ----------------------------------------------------------------------------------


def test_a_plan_whose_length_is_not_a_multiple_of_the_channels_is_refused() -> None:
    box = Bounds(np.zeros(7), np.ones(7))
    for name in ("cem", "icem"):
        with pytest.raises(ValueError, match=r"CEM\.plan_channels = 2 .* dimension 7"):
            get_optimizer(name).minimize(quadratic, box, np.random.default_rng(0))
    res = get_optimizer("icem", plan_channels=7).minimize(
        lambda x: (x**2).sum(axis=1), box, np.random.default_rng(0), Budget(max_evaluations=50)
    )
    assert res.nfev == 50


@pytest.mark.parametrize(
    ("field", "value"),
    [("elite_count", 101), ("elite_count", 0), ("population_size", 1), ("momentum", 1.0),
     ("initial_std", 0.0), ("noise_exponent", -1.0), ("keep_elites", 1.5),
     ("sample_decay", 0.8), ("plan_channels", 0), ("max_evaluations", 0)],
)  # fmt: skip
def test_bad_settings_are_refused_naming_the_field(field, value) -> None:
    with pytest.raises(ValueError, match=rf"CEM\.{field} must be"):
        CEM(**{field: value})


def test_registered_configurations() -> None:
    icem = get_optimizer("icem")
    assert (icem.noise_exponent, icem.momentum, icem.keep_elites, icem.sample_decay,
            icem.elite_count, icem.sample_mean_last) == (2.0, 0.1, 0.3, 1.25, 10, True)  # fmt: skip
    assert icem.kept_count() == 3
    cem = get_optimizer("cem")
    assert (cem.noise_exponent, cem.keep_elites, cem.sample_decay, cem.sample_mean_last) == (
        0.0, 0.0, 1.0, False,
    )  # fmt: skip


def test_the_kernels_read_every_kernel_setting_and_hand_them_on_by_name() -> None:
    kernels = (cem_ask, cem_tell, batch_size)
    assert attributes_read(kernels, "s") == set(CEMSettings._fields)
    positional, by_keyword = settings_passed_on(kernels, "s")
    assert positional == [] and by_keyword
    assert all(keyword == field for keyword, field in by_keyword)
