"""Predictive sampling: the nominal plan and Gaussian samples around it, the best kept.

Howell, Gileadi, Tunyasuvunakool, Zakka, Erez & Tassa, "Predictive Sampling: Real-time
Behaviour Synthesis with MuJoCo", arXiv:2212.00541, 2022 (MuJoCo MPC's sampling planner). An
iteration draws ``N`` samples ``clip(u + sigma Z_i)`` around the nominal plan ``u``, ``Z_i``
standard normal, evaluates them, and the best of the nominal and the samples becomes the new
nominal. The paper runs one iteration per control step from the shifted previous plan; here a
solve runs as many as the budget allows from the warm start (the harness's shifted plan), else
from the box centre, which is evaluated first, so the result is never worse than the warm
start.

Choices the paper leaves open, as made here:

* **noise**: one standard deviation per channel of the stage-major plan, ``noise_std`` times
  the channel's range, the same for every stage (:class:`~.plan_sampling.PlanShape`). MJPC's
  default is 0.1 in control units, for actuators whose range is mostly [-1, 1]: 0.05 of the
  range, far too wide here (see below);
* **bounds**: the samples are clipped to the box (MJPC clamps them to the control range);
* **plan**: the decision vector is the spline's parameters with zero-order interpolation
  (one value per stage and channel); the harness shifts it between control steps, so the
  nominal is not resampled in time here;
* **nominal**: the objective is deterministic, so the nominal's cost is kept rather than
  re-evaluated (MJPC rolls it out again because the state has moved): an iteration spends
  ``N`` evaluations, the paper's ``N + 1`` candidates. A sample replaces the nominal only when
  strictly better (NaN and infinite costs never), the first of equal samples. A batch the
  budget cuts short competes with its evaluated samples.

**Defaults.** ``N = 9``: MJPC's 10 rollouts, the nominal among them. ``noise_std`` was chosen
on the instance library's validation split (293 problems, 2 seeds, default budget; median
normalised gap): 0.001, 0.002, 0.003, 0.005, 0.0075, 0.01, 0.02, 0.05 gave 0.10, 0.075, 0.069,
0.070, 0.076, 0.084, 0.12, 0.25 (MJPC's equivalent, 0.05, is the last). N = 5, 10, 20, 30 at
the same budget: 0.066, 0.068, 0.075, 0.092.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

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
from formation_bench.optimizers.plan_sampling import NominalStart, PlanShape, plan_samples
from formation_bench.optimizers.population import POPULATION_SEARCH
from formation_bench.optimizers.registry import register

PER_SOLVE = ("noise", "lower", "upper")
"""The kernel settings fixed per solve: the noise standard deviation per coordinate and the box."""


@dataclass(frozen=True)
class PredictiveSamplingConfig(PlanShape, Validated):
    """The settings of :class:`PredictiveSampling`, declared once."""

    population_size: int = setting(
        9, low=1, search=POPULATION_SEARCH, doc="N, samples around the nominal per iteration"
    )
    max_iterations: int = budget_setting(
        136,
        doc="Iterations when the caller gives no budget; the default budget is 1 + N T",
    )  # fmt: skip
    noise_std: float = setting(
        0.005, low=0.0, high=1.0, low_open=True, search=Search(0.0002, 0.2, log=True),
        doc="Standard deviation of the samples, per channel, as a share of its range",
    )  # fmt: skip


PredictiveSamplingSettings = kernel_settings_class(
    "PredictiveSamplingSettings",
    __name__,
    PredictiveSamplingConfig,
    PER_SOLVE,
    """What the kernels read: the noise standard deviation per coordinate and the box.""",
)


class PredictiveSamplingState(NamedTuple):
    """The nominal plan between iterations."""

    nominal: np.ndarray
    """``u``, shape (D,)."""
    cost: float
    """Its cost (``+inf`` if not finite or not evaluated)."""
    updates: int
    """Iterations whose best sample replaced the nominal."""


@njit(cache=True, inline="always")
def predictive_sampling_ask(state, params, uniforms, normals, iteration, remaining):  # type: ignore[no-untyped-def]
    """The ``N`` clipped samples around the nominal from the ``(N, D)`` ``normals``."""
    s = PredictiveSamplingSettings(*params)
    samples = plan_samples(state.nominal, normals, noise=s.noise, lower=s.lower, upper=s.upper)
    return state, samples, True


@njit(cache=True, inline="always")
def predictive_sampling_tell(state, params, candidates, costs, iteration):  # type: ignore[no-untyped-def]
    """The best evaluated sample replaces the nominal if strictly better."""
    best, cost = -1, state.cost
    for i in range(costs.shape[0]):
        if costs[i] < cost:
            best, cost = i, costs[i]
    # one return: each exit would count references to the state's arrays again
    if best < 0:
        nominal, updates = state.nominal, state.updates
    else:
        nominal, updates = candidates[best].copy(), state.updates + 1
    return PredictiveSamplingState(nominal, cost, updates)


register_kernels(PredictiveSamplingState, predictive_sampling_ask, predictive_sampling_tell)


@njit(cache=True)
def predictive_sampling_iterate(state, params, block, nit, rows):  # type: ignore[no-untyped-def]
    """:func:`~formation_bench.optimizers.ask_tell.iterate` with the predictive sampling
    kernels."""
    return iterate(state, params, block, nit, rows)


@dataclass(frozen=True)
class PredictiveSampling(PredictiveSamplingConfig, NominalStart, AskTellOptimizer):
    """Predictive sampling over a plan; see the module docstring for the source and the
    choices made."""

    compile_cpu_s = 3.0
    kernels = Kernels(predictive_sampling_ask, predictive_sampling_tell,
                      predictive_sampling_iterate)  # fmt: skip

    def params(self, bounds: Bounds, t_max: int) -> tuple:
        return pack_settings(
            PredictiveSamplingSettings, self, noise=self.stage_noise(bounds, self.noise_std),
            lower=np.array(bounds.lower), upper=np.array(bounds.upper),
        )  # fmt: skip

    def start(
        self, points: np.ndarray, costs: np.ndarray, rng: np.random.Generator, params: tuple
    ) -> PredictiveSamplingState:
        return PredictiveSamplingState(points[0].copy(), float(costs[0]), 0)

    def draw_plan(self, n: int, d: int) -> DrawPlan:
        return DrawPlan(0, normal_shape=(self.population_size, d))

    def result_info(self, state: PredictiveSamplingState) -> dict[str, Any]:
        return {"nominal_updates": int(state.updates)}


register(
    "predictive-sampling",
    PredictiveSampling(),
    "Predictive sampling (Howell et al. 2022): 9 samples around the nominal, noise 0.005 x "
    "range, the best kept",
)
