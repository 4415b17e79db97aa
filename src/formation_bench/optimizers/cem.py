"""The cross-entropy method over a plan, with the improvements of iCEM as settings.

**CEM** (Rubinstein & Kroese, *The Cross-Entropy Method*, 2004; the planner of Chua et al.,
NeurIPS 2018, iCEM's baseline): a Gaussian with mean ``mu`` and diagonal std ``sigma``. Each
iteration draws samples ``mu + sigma * noise`` clipped to the box (the sources leave it open;
gym clips actions so), evaluates them in one batch, and refits to the ``K`` best (the elites)
with momentum ``alpha``: ``mu <- alpha mu + (1 - alpha) mean(elites)``, ``sigma <- alpha sigma
+ (1 - alpha) std(elites)`` (the maximum-likelihood std, divisor K, of the clipped points; iCEM
smooths the std, Chua et al. the variance).
``mu`` starts at the warm start (else the box centre), evaluated first, so the result (the
best point evaluated, kept by the tally) is never worse; ``sigma`` at ``initial_std`` x range.
The normals drawn are exactly the samples' (:class:`~.cem_update.SampleNormals`).

**iCEM** (Pinneri et al., "Sample-efficient cross-entropy method for real-time planning",
CoRL 2020, arXiv 2008.06389, Algorithm 1); each addition is a setting:

* ``noise_exponent`` beta: coloured noise over the stages of the stage-major plan
  (``plan_channels`` values per stage, one series per channel), the FFT method as a fixed
  matrix on standard normals (:mod:`.coloured_noise`);
* ``keep_elites`` xi: the best ``floor(xi K)`` elites join the next selection. iCEM
  re-evaluates them (its costs, model rollouts from a new state, change); a solve's objective
  is fixed, so here they keep their costs. The first iteration's kept set is the evaluated
  warm start (iCEM's are the previous step's elites shifted; the harness passes the best);
* ``sample_decay`` gamma: iteration ``i = 0, 1, ...`` draws ``N_i = min(N, max(floor(N
  gamma^-i), 2K))`` samples (the paper's, capped at N);
* ``sample_mean_last``: the last iteration also evaluates ``mu`` (after the samples, the batch
  sized to the evaluations left): the planned last (iteration budget) or the one the
  evaluations end; under a deadline the last is not known and gets no mean.

iCEM resets the std every control step and iterates 3-4 times; a solve here is one control
step iterated until the budget ends, and the std shrinks long before. A larger N and smaller
initial std than iCEM's (0.25 x range) did best on the instance library's validation split
(median normalised gap ``cem`` 0.148, 0.95 at N = 30 and std 0.25; ``icem`` 0.118;
``icem-white`` 0.094, the colour not helping on 5-stage plans; ``cma-es`` 0.017).
"""

from __future__ import annotations

import dataclasses
import math
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
from formation_bench.optimizers.base import Bounds, Budget, budget_setting
from formation_bench.optimizers.cem_update import (
    SampleNormals,
    Schedule,
    batch_size,
    elite_refit,
    iterations_within,
)
from formation_bench.optimizers.coloured_noise import coloured_normals, noise_matrix
from formation_bench.optimizers.plan_sampling import NominalStart, PlanShape
from formation_bench.optimizers.registry import register

PER_SOLVE = ("t_max", "kept_count", "noise_matrix", "lower", "upper")
"""The kernel settings fixed per solve rather than per configuration, after the declared ones."""


def elites_search_high(obj: object) -> int:
    """min(population_size // 2, 50)"""
    return min(obj.population_size // 2, 50)  # type: ignore[attr-defined]


@dataclass(frozen=True)
class CEMConfig(PlanShape, Validated):
    """The settings of :class:`CEM`, declared once (defaults: ``cem``)."""

    population_size: int = setting(
        100, low=2, kernel=True, search=Search(10, 300, log=True),
        doc="N, samples drawn per iteration (the first, with decay)",
    )  # fmt: skip
    elite_count: int = setting(
        10, low=1, high="population_size", kernel=True, search=Search(2, elites_search_high),
        doc="K, elites the Gaussian is refit to",
    )  # fmt: skip
    max_evaluations: int = budget_setting(
        1230, doc="Evaluations when the caller gives no budget (the default budget)"
    )
    initial_std: float = setting(
        0.05, low=0.0, low_open=True, high=1.0, search=Search(0.005, 0.5, log=True),
        doc="Initial standard deviation as a share of each coordinate's range",
    )  # fmt: skip
    momentum: float = setting(
        0.1, low=0.0, high=1.0, high_open=True, kernel=True, search=Search(0.0, 0.9),
        doc="alpha: mean and std become alpha old + (1 - alpha) the elites'",
    )  # fmt: skip
    noise_exponent: float = setting(
        0.0, low=0.0, high=6.0,
        doc="beta: noise power over the stages falls as 1 / f^beta; 0: white (plain CEM)",
    )  # fmt: skip
    keep_elites: float = setting(
        0.0, low=0.0, high=1.0,
        doc="xi: share of the K elites (the best floor(xi K)) kept for the next selection",
    )  # fmt: skip
    sample_decay: float = setting(
        1.0, low=1.0, kernel=True,
        doc="gamma: iteration i draws min(N, max(floor(N gamma^-i), 2K)) samples; 1: N always",
    )  # fmt: skip
    sample_mean_last: bool = setting(
        False, kernel=True, doc="The last iteration also evaluates the mean itself (iCEM)"
    )

    def kept_count(self) -> int:
        """``floor(xi K)`` (the small tolerance keeps ``0.3 * 10`` at 3)."""
        return math.floor(self.keep_elites * self.elite_count + 1e-9)


CEMSettings = kernel_settings_class(
    "CEMSettings",
    __name__,
    CEMConfig,
    PER_SOLVE,
    """:class:`CEMConfig`'s kernel fields, T_max, the elites kept, the noise matrix, the box.""",
)


class CEMState(NamedTuple):
    """The sampling distribution and the elites carried between iterations."""

    mean: np.ndarray
    """mu, shape (D,)."""
    std: np.ndarray
    """sigma, the diagonal standard deviation, shape (D,)."""
    kept: np.ndarray
    """Elites kept for the next selection, best first, shape (k, D)."""
    kept_costs: np.ndarray
    """Their costs, shape (k,)."""


@njit(cache=True, inline="always")
def cem_ask(state, params, uniforms, normals, iteration, remaining):  # type: ignore[no-untyped-def]
    """The :func:`~.cem_update.batch_size` samples ``clip(mu + sigma * M Z)`` on the first rows
    of ``normals`` (``(N, D)``), then ``mu`` if it is due."""
    s = CEMSettings(*params)
    drawn, extra = batch_size(s, iteration, remaining)
    noise = coloured_normals(normals[:drawn], noise_matrix=s.noise_matrix)
    d = state.mean.shape[0]
    candidates = np.empty((drawn + extra, d))
    for j in range(drawn + extra):
        for c in range(d):
            value = state.mean[c] + state.std[c] * noise[j, c] if j < drawn else state.mean[c]
            candidates[j, c] = min(max(value, s.lower[c]), s.upper[c])
    return state, candidates, True


@njit(cache=True, inline="always")
def cem_tell(state, params, candidates, costs, iteration):  # type: ignore[no-untyped-def]
    """Refit to the elites of the evaluated candidates and the kept elites."""
    s = CEMSettings(*params)
    refit = elite_refit(state, candidates[: costs.shape[0]], costs, elite_count=s.elite_count,
                        momentum=s.momentum, kept_count=s.kept_count)  # fmt: skip
    return CEMState(*refit)


register_kernels(CEMState, cem_ask, cem_tell)


@njit(cache=True)
def cem_iterate(state, params, block, nit, rows):  # type: ignore[no-untyped-def]
    """:func:`~formation_bench.optimizers.ask_tell.iterate` with the CEM kernels."""
    return iterate(state, params, block, nit, rows)


@dataclass(frozen=True)
class CEM(CEMConfig, NominalStart, AskTellOptimizer):
    """CEM and iCEM; see the module docstring for the method, its sources and choices."""

    compile_cpu_s = 9.0
    kernels = Kernels(cem_ask, cem_tell, cem_iterate)

    @property
    def default_budget(self) -> Budget:
        return Budget(max_evaluations=self.max_evaluations)

    def planned_iterations(self, budget: Budget) -> int:
        """The iterations the budget allows, with the sample sizes of the decay."""
        limits = [] if budget.max_iterations is None else [int(budget.max_iterations)]
        if budget.max_evaluations is not None:
            limits.append(iterations_within(self, budget.max_evaluations - 1))
        return min(limits)

    def params(self, bounds: Bounds, t_max: int) -> tuple:
        return pack_settings(
            CEMSettings, self, t_max=int(t_max), kept_count=self.kept_count(),
            noise_matrix=noise_matrix(self.noise_exponent, self.stages(bounds.dim)),
            lower=np.array(bounds.lower), upper=np.array(bounds.upper),
        )  # fmt: skip

    def start(
        self, points: np.ndarray, costs: np.ndarray, rng: np.random.Generator, params: tuple
    ) -> CEMState:
        """mu at the evaluated start, sigma at ``initial_std`` x range, the start kept."""
        s = CEMSettings(*params)
        keep = min(1, s.kept_count)
        std = self.initial_std * (s.upper - s.lower)
        return CEMState(points[0].copy(), std, points[:keep].copy(), costs[:keep].copy())

    def draw_plan(self, n: int, d: int) -> DrawPlan:
        """Not used: the batch sizes change, and :meth:`block_source` draws their normals."""
        raise TypeError("CEM draws the normals of its samples batch by batch (block_source)")

    def block_source(self, bounds: Bounds, shape: tuple[int, ...], t_max: int) -> SampleNormals:
        """The normals of the samples (:class:`~.cem_update.SampleNormals`)."""
        return SampleNormals(Schedule.of(self, t_max), bounds.dim)


ICEM = CEM(
    population_size=200, initial_std=0.1, noise_exponent=2.0, keep_elites=0.3, sample_decay=1.25,
    sample_mean_last=True,
)  # fmt: skip
"""iCEM at the paper's settings, but N and the initial std (chosen on the validation split)."""

register(
    "cem",
    CEM(),
    "Cross-entropy method (CEM-MPC of Chua et al. 2018): 100 samples, 10 elites, "
    "momentum 0.1, std 0.05 x range, clip",
)
register(
    "icem",
    ICEM,
    "iCEM (Pinneri et al. 2020): coloured noise beta 2, 30% of the 10 elites kept, samples "
    "200 decaying to 20 (gamma 1.25), momentum 0.1, std 0.1 x range, the mean last",
)
register(
    "icem-white",
    dataclasses.replace(ICEM, noise_exponent=0.0),
    "iCEM with white noise (beta 0): the colour does not help on 5-stage plans",
)
