"""Model predictive path integral control (MPPI) as an optimiser of one plan.

Williams, Wagener, Goldfain, Drews, Rehg, Boots & Theodorou, "Information theoretic MPC for
model-based reinforcement learning", ICRA 2017 (Algorithm 2). An iteration perturbs the
nominal plan ``u`` by ``K`` Gaussian steps ``eps_k ~ N(0, Sigma)`` and evaluates the samples
``v_k = u + eps_k``; with the sample costs

    ``S_k = J(v_k) + gamma u^T Sigma^-1 eps_k``,   ``gamma = control_cost * lambda``,

it weighs them ``w_k = exp(-(S_k - min S) / lambda) / eta`` and moves the nominal by the
weighted mean of the perturbations, ``u <- u + sum_k w_k eps_k``. The paper runs one such
iteration per control step from the shifted previous plan; here a solve runs as many as the
budget allows from the warm start (the harness's shifted plan), else from the box centre.

Choices the paper leaves open, as made here:

* **noise**: ``Sigma`` diagonal, one standard deviation per channel of the stage-major plan,
  ``noise_std`` times the channel's range, the same for every stage
  (:class:`~.plan_sampling.PlanShape`);
* **bounds**: the samples are clipped to the box, and ``eps_k`` is the *clipped* perturbation
  ``v_k - u`` (in the control term and the update), so that the costs belong to the steps the
  update takes: without smoothing the new nominal is the weighted mean of the evaluated
  samples, inside the box;
* **control term**: ``control_cost`` is the paper's ``gamma / lambda`` (1: ``gamma = lambda``,
  the information-theoretic cost of ``R = lambda Sigma^-1``; 0: the costs alone); it pulls the
  plan towards zero controls, a regulariser the benchmark's cost does not have. Only the
  weights see it: the result is judged by ``J``;
* **temperature**: ``lambda = temperature`` times a scale of the iteration's costs ``J``
  (``temperature_scale``; relative by default, since the costs' size varies by problem; taken
  from ``J`` without the control term, which itself depends on ``lambda``); non-finite costs
  get weight 0;
* **smoothing** (``smoothing_window``): the update ``sum w_k eps_k`` is averaged over a
  centred window of stages, per channel (:func:`~.plan_sampling.smooth_stages`), then the new
  nominal is clipped to the box; the paper's successors smooth with a Savitzky-Golay filter;
* **nominal**: each new nominal is evaluated in the next iteration's batch (its first row,
  ``evaluate_nominal``) so the best-so-far includes it; it is not one of the weighted samples.
  The warm start is evaluated first, so the result is never worse than it. A batch the budget
  cuts short gives its unevaluated samples weight 0.

**Defaults.** The paper's K, Sigma and lambda are task-specific; these were chosen on the
instance library's validation split (293 problems, 2 seeds, default budget; median normalised
gap, 0.084 at the defaults), varying one at a time: ``noise_std`` 0.002, 0.005, 0.02, 0.05,
0.1 (0.12, 0.087, 0.11, 0.24, 0.57); ``temperature`` 0.003, 0.03, 0.1, 0.3, 1 of the spread
(0.083, 0.11, 0.17, 0.26, 0.36; 0.03 of the MAD: 0.082); K = 10, 20, 60, 100 (0.10, 0.087,
0.11, 0.14). The control term hurts (``control_cost`` 1, 0.1, 0.01: 0.50, 0.21, 0.089), so it
is off; the nominal left unevaluated: 0.096; ``mppi-smooth`` (window 3): 0.17, smoother plans.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from formation_bench.fields import (
    Search,
    Validated,
    kernel_settings_class,
    pack_settings,
    setting,
)
from formation_bench.kernel_cache import njit
from formation_bench.optimizers.ask_tell import (
    AskTellOptimizer,
    DrawPlan,
    Kernels,
    iterate,
    register_kernels,
)
from formation_bench.optimizers.base import Bounds, budget_setting
from formation_bench.optimizers.plan_sampling import (
    NominalStart,
    PlanShape,
    TemperatureScale,
    check_window,
    path_integral_weights,
    plan_samples,
    smooth_stages,
    temperature_of,
)
from formation_bench.optimizers.population import POPULATION_SEARCH
from formation_bench.optimizers.registry import register

PER_SOLVE = ("stages", "noise", "lower", "upper")
"""The kernel settings fixed per solve rather than per configuration, after the declared ones."""


@dataclass(frozen=True)
class MPPIConfig(PlanShape, Validated):
    """The settings of :class:`MPPI`, declared once."""

    population_size: int = setting(
        30, low=1, search=POPULATION_SEARCH, doc="K, perturbed plans sampled per iteration"
    )
    max_iterations: int = budget_setting(
        40,
        doc="Iterations when the caller gives no budget; the default budget is 1 + K + "
        "(T - 1) (K + 1) with the nominal evaluated",
    )  # fmt: skip
    noise_std: float = setting(
        0.01, low=0.0, high=1.0, low_open=True, search=Search(0.0005, 0.2, log=True),
        doc="Standard deviation of the perturbations, per channel, as a share of its range",
    )  # fmt: skip
    temperature: float = setting(
        0.01, low=0.0, low_open=True, kernel=True, search=Search(0.0001, 1.0, log=True),
        doc="lambda, in the units temperature_scale says",
    )  # fmt: skip
    temperature_scale: TemperatureScale = setting(
        TemperatureScale.SPREAD, kernel=True,
        doc="lambda relative to: absolute (cost units), spread (max - min cost) or mad "
        "(median absolute deviation) of the iteration's costs",
    )  # fmt: skip
    control_cost: float = setting(
        0.0, low=0.0, high=1.0, kernel=True, search=Search(0.0, 1.0),
        doc="gamma / lambda, the share of the control term lambda u^T Sigma^-1 eps in the "
        "sample costs; 0: off",
    )  # fmt: skip
    smoothing_window: int = setting(
        0, check=check_window, allowed="0 or 1 (off), or an odd integer >= 3", kernel=True,
        doc="Stages of the centred moving average of each update along the plan; 0 or 1: off",
    )  # fmt: skip
    evaluate_nominal: bool = setting(
        True, kernel=True,
        doc="Evaluate each new nominal plan in the next batch, so the best-so-far includes it",
    )  # fmt: skip


MPPISettings = kernel_settings_class(
    "MPPISettings",
    __name__,
    MPPIConfig,
    PER_SOLVE,
    """What the kernels read: the kernel fields of :class:`MPPIConfig` (enums as integers),
    then the plan's stages, the noise standard deviation per coordinate and the box.""",
)


class MPPIState(NamedTuple):
    """The nominal plan between iterations."""

    nominal: np.ndarray
    """``u``, shape (D,)."""
    evaluated: bool
    """Whether ``u`` has been evaluated (the warm start; a nominal after its batch)."""
    samples: np.ndarray
    """The last iteration's clipped samples ``v_k``, shape (K, D) (empty before the first)."""


@njit(cache=True)
def mppi_update(nominal, samples, costs, s):  # type: ignore[no-untyped-def]
    """The next nominal from the samples ``v_k`` around ``nominal`` and their costs ``J(v_k)``
    (``+inf`` if not evaluated): ``clip(u + smooth(sum_k w_k eps_k))``, ``eps_k = v_k - u``;
    ``s`` is the solve's :class:`MPPISettings`."""
    k, d = samples.shape
    steps = samples - nominal
    inverse_variance = 1.0 / (s.noise * s.noise)
    lam = temperature_of(costs, temperature=s.temperature, temperature_scale=s.temperature_scale)
    scores = costs.copy()
    if s.control_cost > 0.0:
        for i in range(k):
            scores[i] += s.control_cost * lam * np.sum(nominal * inverse_variance * steps[i])
    weights = path_integral_weights(scores, costs, lam)
    step = np.zeros(d)
    for i in range(k):
        if weights[i] > 0.0:
            step += weights[i] * steps[i]
    moved = nominal + smooth_stages(step, stages=s.stages, smoothing_window=s.smoothing_window)
    lower, upper = s.lower, s.upper
    return np.minimum(np.maximum(moved, lower), upper)


@njit(cache=True, inline="always")
def mppi_ask(state, params, uniforms, normals, iteration, remaining):  # type: ignore[no-untyped-def]
    """The ``K`` clipped samples around the nominal from the ``(K, D)`` ``normals``, after the
    nominal itself when it is new and ``evaluate_nominal``."""
    s = MPPISettings(*params)
    samples = plan_samples(state.nominal, normals, noise=s.noise, lower=s.lower, upper=s.upper)
    k, d = samples.shape
    # one return: each exit would count references to the state's arrays again
    if state.evaluated or not s.evaluate_nominal:
        batch = samples
    else:
        batch = np.empty((k + 1, d))
        # element loops: a row assignment compiles a shape-mismatch error path (a slower cold
        # start)
        for c in range(d):
            batch[0, c] = state.nominal[c]
            for i in range(k):
                batch[i + 1, c] = samples[i, c]
    evaluated = state.evaluated or s.evaluate_nominal
    return MPPIState(state.nominal, evaluated, samples), batch, True


@njit(cache=True, inline="always")
def mppi_tell(state, params, candidates, costs, iteration):  # type: ignore[no-untyped-def]
    """The next nominal (:func:`mppi_update`) from the samples' costs, those after the
    nominal's row when the batch led with it."""
    s = MPPISettings(*params)
    k = state.samples.shape[0]
    first = candidates.shape[0] - k
    sample_costs = np.full(k, np.inf)
    for i in range(max(costs.shape[0] - first, 0)):
        sample_costs[i] = costs[first + i]
    nominal = mppi_update(state.nominal, state.samples, sample_costs, s)
    return MPPIState(nominal, False, state.samples)


register_kernels(MPPIState, mppi_ask, mppi_tell)


@njit(cache=True)
def mppi_iterate(state, params, block, nit, rows):  # type: ignore[no-untyped-def]
    """:func:`~formation_bench.optimizers.ask_tell.iterate` with the MPPI kernels."""
    return iterate(state, params, block, nit, rows)


@dataclass(frozen=True)
class MPPI(MPPIConfig, NominalStart, AskTellOptimizer):
    """MPPI over a plan; see the module docstring for the source and the choices made."""

    compile_cpu_s = 11.0
    kernels = Kernels(mppi_ask, mppi_tell, mppi_iterate)

    def params(self, bounds: Bounds, t_max: int) -> tuple:
        return pack_settings(
            MPPISettings, self, stages=self.stages(bounds.dim),
            noise=self.stage_noise(bounds, self.noise_std), lower=np.array(bounds.lower),
            upper=np.array(bounds.upper),
        )  # fmt: skip

    def evaluations_per_step(self) -> int:
        """K samples and the new nominal (when evaluated)."""
        return self.population_size + int(self.evaluate_nominal)

    def start(
        self, points: np.ndarray, costs: np.ndarray, rng: np.random.Generator, params: tuple
    ) -> MPPIState:
        return MPPIState(points[0].copy(), True, np.empty((0, points.shape[1])))

    def draw_plan(self, n: int, d: int) -> DrawPlan:
        return DrawPlan(0, normal_shape=(self.population_size, d))


register(
    "mppi",
    MPPI(),
    "MPPI (Williams et al. 2017): 30 samples, noise 0.01 x range, lambda 0.01 x cost spread, "
    "no control term",
)
register(
    "mppi-smooth",
    MPPI(smoothing_window=3),
    "mppi with each update averaged over 3 stages (moving average along the plan)",
)
