"""CMA-ES with restarts: the (mu/mu_w, lambda)-CMA-ES of Hansen's tutorial, IPOP and BIPOP.

Hansen, N. (2016). *The CMA Evolution Strategy: A Tutorial*. arXiv:1604.00772.
Each generation samples lambda points ``m + sigma B D z`` (z standard
normal), evaluates them in one batch, and updates the mean from the mu best
with the tutorial's recombination weights, the step size by cumulative
step-size adaptation, and the covariance matrix by the rank-one and rank-mu
updates (active: the worst steps get negative weights, as in the tutorial's
defaults). The eigendecomposition of C is refreshed lazily, after
``0.5 lambda / (n (c_1 + c_mu))`` evaluations, as in Hansen's pure-Python
reference implementation. The update rules are in :mod:`.cma_ops`, written once as the
ask/tell kernels :func:`cma_ask` and :func:`cma_tell`, which both solve loops drive; the
runs and restarts are in :mod:`.cma_restarts`.

**Coordinates.** The search runs in the box normalised to [0, 1]^n, so the
initial covariance is the identity there and ``sigma0`` is a fraction of
each coordinate's range (0.2: the sigma0 = 2 on [-5, 5]^n of Hansen's BBOB
experiments).

**Start.** The first run's mean is the warm start ``x0`` when one is given
(it is evaluated first, so the result is never worse), else a uniform point
of the box (also evaluated).

**Bounds.** ``bound_handling`` brings the samples into the box: a repair (``clip``,
``reflect``, ``resample``; optionally ``lamarckian``) or pycma's BoundTransform
(``transform``, the default). No penalty is added, so the reported cost is always the
objective at the reported point, which is always inside. The choices and their measured
effect are described in :mod:`.cma_transform`.

``constants`` picks the strategy constants: ``tutorial`` (Table 1 of the
tutorial) or ``pycma`` (the default; those of pycma 4: ``c_sigma = (mueff + 2)
/ (n + mueff + 3)`` against the tutorial's ``n + mueff + 5`` -- 0.3196 against
0.2844 at n = lambda = 10 --, ``d_sigma = 1 + c_sigma`` there, ``c_1`` damped
below lambda = 6, and the h_sigma test on the squared length of ``p_sigma``;
see :func:`~.cma_ops.cma_parameters`). The two were level on the validation
split (median normalised gap 0.017 with pycma's, 0.019 with the tutorial's,
p = 0.25), but with the tutorial's the search is significantly behind pycma on
a bounded 10-D sphere (its smaller c_sigma adapts the step size more slowly),
so pycma's are the default: ``cma-es`` is pycma's algorithm at pycma's
settings. ``cma-es-warm`` is ``cma-es`` with ``sigma0 = 0.02``, for a warm
start that is nearly right (the closed loop's shifted plan): chosen on the
validation split from 0.005, 0.01, 0.02, 0.05 and 0.1 (median normalised gaps
0.0019, 0.0018, 0.0016, 0.0023, 0.0046).

**Restarts** (:mod:`.cma_restarts`): same lambda, IPOP or BIPOP. On the paper problem at the
default budget (1230 evaluations, lambda = 10) a run rarely stops, so the three variants
usually give identical solves there.

**Budget.** A generation the evaluation budget cuts short evaluates its
first samples only and is not learned from; the solve ends with it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

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
from formation_bench.optimizers.base import (
    Bounds,
    Budget,
    budget_setting,
)
from formation_bench.optimizers.cma_ops import (
    RUNNING,
    CMABoundHandling,
    CMAConstants,
    default_population_size,
    injection_cap,
    learn,
    owned,
    sample,
    told,
)
from formation_bench.optimizers.cma_restarts import (
    CampaignDraws,
    CMAState,
    Restarts,
    campaign_info,
    first_run,
)
from formation_bench.optimizers.registry import register

PER_SOLVE = ("cap", "lower", "width", "upper", "unit_lower", "unit_upper")
"""The kernel settings fixed per solve rather than per configuration, after the declared ones."""


@dataclass(frozen=True)
class CMAConfig(Validated):
    """The settings of :class:`CMAES`, declared once: the fields marked ``kernel=True`` make
    :class:`CMASettings`, which the kernels rebuild and read by name."""

    population_size: int | None = setting(
        None, kind=int, optional=True, low=2,
        doc="lambda, samples per generation of the first run; None: 4 + floor(3 ln n)",
    )  # fmt: skip
    sigma0: float = setting(
        0.2, low=0.0, high=1.0, low_open=True, search=Search(0.001, 1.0, log=True),
        doc="Initial step size as a fraction of each coordinate's range",
    )  # fmt: skip
    max_evaluations: int = budget_setting(
        1230, doc="Evaluations when the caller gives no budget (the default budget)"
    )
    active: bool = setting(
        True, doc="Negative recombination weights for the worst steps (active CMA, as the tutorial)"
    )
    restarts: Restarts = setting(
        Restarts.SAME,
        doc="After a stop criterion: same (same lambda), ipop (double lambda) or bipop",
    )
    bound_handling: CMABoundHandling = setting(
        CMABoundHandling.TRANSFORM, kernel=True, search=Search(),
        doc="How samples are brought into the box: clip, reflect, resample, or transform (pycma's)",
    )  # fmt: skip
    constants: CMAConstants = setting(
        CMAConstants.PYCMA, kernel=True,
        doc="Strategy constants and h_sigma test: tutorial (Hansen's Table 1) or pycma (pycma 4's)",
    )  # fmt: skip
    lamarckian: bool = setting(
        False, kernel=True, search=Search(),
        doc="Learn from the repaired points (steps capped, Hansen 2011), not the sampled steps",
    )  # fmt: skip
    tol_fun: float = setting(
        1e-12, low=0.0, kernel=True,
        doc="TolFun: stop a run when recent best costs and the last generation span less",
    )  # fmt: skip
    tol_x: float = setting(
        1e-12, low=0.0, kernel=True,
        doc="TolX: stop a run when all standard deviations fall below tol_x times sigma0",
    )  # fmt: skip


CMASettings = kernel_settings_class(
    "CMASettings",
    __name__,
    CMAConfig,
    PER_SOLVE,
    """What the kernels read, fixed during a solve: the kernel fields of :class:`CMAConfig`
    (enums as integers), then the Mahalanobis cap of a Lamarckian step, the box (lower,
    width, upper) and the normalised box's bounds (zeros and ones).""",
)


@njit(cache=True, inline="always")
def cma_ask(state, params, uniforms, normals, iteration, remaining):  # type: ignore[no-untyped-def]
    """Learn from the told generation (if any), then sample the next from ``normals`` (and,
    with RESAMPLE, ``uniforms``), both ``(lambda, n)``, advancing the run's arrays in place
    (:func:`cma_iterate` gives a block its own copy).

    The update waits for the next generation so that a solve's last generation, which no
    generation follows, is not learned from, and a run is checked for a stop only when
    budget is left to restart it. A run that stops samples nothing (0 candidates) and keeps
    doing so: the solve loop restarts it (:class:`~.cma_restarts.CampaignDraws`).
    """
    # one return and no early ones: each exit would count references to all the state's arrays
    run = state.run
    s = CMASettings(*params)
    if run.progress.stop == RUNNING and told(run.samples):
        run = learn(run, s, state.plan, iteration)
    if run.progress.stop == RUNNING:
        sample(run.distribution, normals, uniforms, s, run.samples)
        candidates = run.samples.points
    else:
        candidates = np.empty((0, run.distribution.mean.shape[0]))
    return CMAState(run, state.plan, state.campaign), candidates, True


@njit(cache=True, inline="always")
def cma_tell(state, params, candidates, costs, iteration):  # type: ignore[no-untyped-def]
    """Keep the candidates' costs for the next :func:`cma_ask` (+inf for rows the budget left
    unevaluated), in the cost array :func:`~.cma_ops.sample` made for this generation: the
    state keeps its parts (rebuilding it would count references to all of its arrays)."""
    # no early return for a stopped run's 0 candidates: the loops do nothing then
    told = state.run.samples.costs
    for r in range(costs.shape[0]):
        told[r] = costs[r]
    for r in range(costs.shape[0], candidates.shape[0]):
        told[r] = np.inf
    return state


register_kernels(CMAState, cma_ask, cma_tell)


@njit(cache=True)
def cma_iterate(state, params, block, nit, rows):  # type: ignore[no-untyped-def]
    """:func:`~formation_bench.optimizers.ask_tell.iterate` with the CMA-ES kernels, on a copy
    of the run that the block then advances in place (:func:`~.cma_ops.owned`)."""
    state = CMAState(owned(state.run), state.plan, state.campaign)
    return iterate(state, params, block, nit, rows)


@dataclass(frozen=True)
class CMAES(CMAConfig, AskTellOptimizer):
    """CMA-ES with restarts; see the module docstring for the algorithm and its sources."""

    compile_cpu_s = 18.0
    kernels = Kernels(cma_ask, cma_tell, cma_iterate)

    @property
    def default_budget(self) -> Budget:
        return Budget(max_evaluations=self.max_evaluations)

    def evaluations_per_step(self) -> int:
        """lambda if set; else the default lambda of n = 10 (the paper problem's size).

        Only an estimate when lambda is left to the dimension, which is not
        known before a solve; nothing in CMA-ES depends on it (see
        :meth:`planned_iterations`).
        """
        return self.population_size or default_population_size(10)

    def initial_evaluations(self) -> int:
        return 1

    def planned_iterations(self, budget: Budget) -> int:
        """The iteration budget if there is one, else a large number.

        CMA-ES follows no schedule over the iterations; the number only bounds
        how far random numbers are drawn ahead (with the evaluations left).
        """
        return int(budget.max_iterations) if budget.max_iterations is not None else 2**62

    def params(self, bounds: Bounds, t_max: int) -> tuple:
        n = bounds.dim
        return pack_settings(
            CMASettings, self, cap=injection_cap(n), lower=np.array(bounds.lower),
            width=np.array(bounds.width), upper=np.array(bounds.upper), unit_lower=np.zeros(n),
            unit_upper=np.ones(n),
        )  # fmt: skip

    def start(
        self, points: np.ndarray, costs: np.ndarray, rng: np.random.Generator, params: tuple
    ) -> CMAState:
        """The first run, centred on the evaluated ``points[0]``."""
        settings = CMASettings(*params)
        return first_run(self, settings.lower, settings.width, points[0])

    def draw_plan(self, n: int, d: int) -> DrawPlan:
        """Not used (see :meth:`block_source`): lambda changes at restarts, so
        :class:`~.cma_restarts.CampaignDraws` draws the numbers (see :mod:`.cma_restarts`)."""
        raise TypeError("CMA-ES draws its random numbers run by run (cma_restarts.draw)")

    def result_info(self, state: CMAState) -> dict[str, Any]:
        return campaign_info(state)

    def initial_points(
        self, bounds: Bounds, rng: np.random.Generator, x0: np.ndarray | None
    ) -> np.ndarray:
        """The start alone: ``x0``, else a uniform point of the box (drawn only then)."""
        return bounds.sample(rng, 1) if x0 is None else x0[None].copy()

    def block_source(self, bounds: Bounds, shape: tuple[int, ...], t_max: int) -> CampaignDraws:
        """The runs' numbers and the restarts between them (:class:`~.cma_restarts.
        CampaignDraws`)."""
        return CampaignDraws(self, bounds, t_max)


register(
    "cma-es",
    CMAES(),
    "CMA-ES (Hansen's tutorial, active) with pycma's constants and BoundTransform, "
    "sigma0 0.2 x range, restarts same lambda",
)
register(
    "cma-es-ipop",
    CMAES(restarts=Restarts.IPOP),
    "IPOP-CMA-ES: restarts doubling the population (Auger & Hansen 2005)",
)
register(
    "cma-es-bipop",
    CMAES(restarts=Restarts.BIPOP),
    "BIPOP-CMA-ES: large and small population restarts interleaved (Hansen 2009)",
)
register(
    "cma-es-warm",
    CMAES(sigma0=0.02),
    "CMA-ES for a nearly right warm start: sigma0 0.02 x range (tuned on the validation split)",
)
