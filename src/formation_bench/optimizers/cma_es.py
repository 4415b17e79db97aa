"""CMA-ES with restarts: the (mu/mu_w, lambda)-CMA-ES of Hansen's tutorial, IPOP and BIPOP.

Hansen, N. (2016). *The CMA Evolution Strategy: A Tutorial*. arXiv:1604.00772.
Each generation samples lambda points ``m + sigma B D z`` (z standard
normal), evaluates them in one batch, and updates the mean from the mu best
with the tutorial's recombination weights, the step size by cumulative
step-size adaptation, and the covariance matrix by the rank-one and rank-mu
updates (active: the worst steps get negative weights, as in the tutorial's
defaults). The eigendecomposition of C is refreshed lazily, after
``0.5 lambda / (n (c_1 + c_mu))`` evaluations, as in Hansen's pure-Python
reference implementation. The update rules are in :mod:`.cma_ops`; one
compiled call per generation does all of a generation's own work. With an
objective that offers a compiled handle (see
:mod:`~formation_bench.optimizers.compiled`), whole blocks of
generations run in one compiled call (:func:`.cma_block`); Python draws the
random numbers and restarts the runs, at the moments the Python loop does, so
both give the same solve to the bit.

**Coordinates.** The search runs in the box normalised to [0, 1]^n, so the
initial covariance is the identity there and ``sigma0`` is a fraction of
each coordinate's range (0.2: the sigma0 = 2 on [-5, 5]^n of Hansen's BBOB
experiments).

**Start.** The first run's mean is the warm start ``x0`` when one is given
(it is evaluated first, so the result is never worse), else a uniform point
of the box (also evaluated).

**Bounds.** ``bound_handling`` brings the samples into the box, in one of
two ways; no penalty is added, so the reported cost is always the objective
at the reported point, which is always inside.

* A repair (``clip``, ``reflect``, ``resample``): a
  sample outside the box is brought in by the project's repair and that point
  is evaluated. The update learns from the *sampled* step, so CMA-ES minimises
  ``f(repair(x))`` over the whole space: with reflect a periodic fold,
  continuous across the faces. With ``lamarckian=True`` the update learns from
  the repaired points instead, their steps ``(x_repaired - m) / sigma``
  shortened to the Mahalanobis length ``sqrt(n) + 2n / (n + 2)`` as Hansen
  (arXiv:1110.4181) does for solutions not sampled from the distribution.
  Measured (median of 7 seeds, d = 10): with an optimum in the corner of
  [-1, 1]^10 (cost 40 there) the Lamarckian repair loses its step size at the
  faces and ends at 43.5 after 1230 evaluations, the default at 40.006; with
  clip the cost beyond a face is flat, so an optimum just inside a face (4.9
  in [-5, 5]) ends at 0.08 after 3000 evaluations, against 2e-15 with
  reflect. Resample makes the cost beyond a face random; it suits only the
  Lamarckian mode.
* ``transform`` (the default): pycma's BoundTransform (the default bound
  handling of pycma, and so of the ``pycma`` adapter), reimplemented in
  :func:`~.cma_ops.linquad_value`. Every sample, inside or not, is mapped
  into the box by a periodic, continuously differentiable map that is the
  identity but for a margin of 5 % of the range along each face (pycma's
  default margins in the normalised box, as the adapter uses it), where it
  bends quadratically onto the face; the mapped point is evaluated and the
  update learns from the sample. Unlike the repairs it has a smooth minimum
  *at* a face: an optimum on a face is the bottom of a parabola in the sample
  space, not the edge of a fold, so the search can converge onto it. The
  first mean is the inverse image of the start (as pycma's ``x0``), so the
  start is also the distribution's mapped centre. Measured on the instance
  library (v1, 504 problems from their warm starts, default budget): on the
  121 whose best-known point touches a bound the transform beat reflect on
  112 and lost on 9 (median relative gap 4.5e-5 against 2.2e-3) and was level
  with pycma (56 better, 65 worse, Wilcoxon p = 0.49); on the 383 others the
  two bound handlings were level (p = 0.31). On the validation split of
  library v2 (293 problems, one seed) it lowered the median normalised gap
  from 0.032 (``reflect``) to 0.019 (Wilcoxon p = 2.5e-4), so it is the
  default. With ``lamarckian=True`` the update learns from the mapped points
  instead (capped as above).

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

**Stopping and restarts.** A solve always spends its budget. When a run
meets one of the tutorial's stop criteria (TolFun, TolX, NoEffectAxis,
NoEffectCoord, ConditionCov, TolUpSigma; not Stagnation) before the budget
is spent, a new run starts from a uniform point of the box with the
initial step size:

* ``restarts=same`` (``cma-es``): with the same population size;
* ``restarts=ipop`` (``cma-es-ipop``): each restart doubles lambda
  (Auger & Hansen, *A restart CMA evolution strategy with increasing
  population size*, CEC 2005);
* ``restarts=bipop`` (``cma-es-bipop``): Hansen, *Benchmarking a
  BI-population CMA-ES on the BBOB-2009 function testbed*, GECCO 2009, with
  the budget accounting of pycma's ``fmin(bipop=True)``: the first run counts
  as small; a small run follows while the small runs have used fewer
  evaluations than the large ones, with ``lambda_s = floor(lambda_def
  (lambda_l / lambda_def)^(U^2))`` (lambda_l: the latest large run's),
  ``sigma0 10^(-2 U')`` and at most half the large runs' evaluations;
  otherwise a large run doubles lambda.

Doubling stops at 2^9 times the default lambda. On the paper problem at the
default budget (1230 evaluations, lambda = 10) a run rarely stops, so the
three variants usually give identical solves there.

**Budget.** A generation the evaluation budget cuts short evaluates its
first samples only and is not learned from; the solve ends with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from time import perf_counter
from typing import Any, NamedTuple

import numpy as np

from formation_bench.fields import setting, validate_fields
from formation_bench.optimizers.base import (
    Bounds,
    Budget,
    EvaluationCounter,
    OptimizeResult,
    PopulationOptimizer,
)
from formation_bench.optimizers.cma_ops import (
    RUN_EVALUATIONS,
    RUNNING,
    SIGMA,
    STOP,
    STOP_NAMES,
    CMABoundHandling,
    CMAConstants,
    cma_block,
    cma_generation,
    default_population_size,
    linquad_inverse,
    new_run,
    run_template,
)
from formation_bench.optimizers.compiled import (
    NFEV,
    CompiledObjective,
    new_tally,
    remaining,
)
from formation_bench.optimizers.compiled import evaluate_prefix as compiled_evaluate_prefix
from formation_bench.optimizers.population import (
    ROWS_AHEAD,
    CompiledStart,
    compiled_iteration_limit,
    compiled_result,
    evaluate_prefix,
)
from formation_bench.optimizers.registry import register

MAX_DOUBLINGS = 9
"""Most doublings of the default population size by IPOP and BIPOP restarts."""


class Restarts(IntEnum):
    """What follows a run that met a stop criterion, while budget is left."""

    SAME = 0
    """A new run with the same population size."""
    IPOP = 1
    """A new run with twice the previous population size (Auger & Hansen 2005)."""
    BIPOP = 2
    """Large (doubling) and small (random, local) runs interleaved (Hansen 2009)."""


class RunPlan(NamedTuple):
    """The population and step size of one run, and its evaluation allowance."""

    population_size: int
    sigma0: float
    """Initial step size in the normalised box."""
    large: bool
    """Counts in BIPOP's large-population budget (the first run counts as small)."""
    limit: float
    """Evaluations the run may learn from before it is stopped (small BIPOP runs), else inf."""


class Campaign(NamedTuple):
    """What a solve keeps across its runs."""

    t_max: int
    """Planned iterations of the solve (the iteration budget, or a large number)."""
    default_lambda: int
    """lambda of the first run."""
    large_evaluations: int = 0
    """Evaluations of the finished runs counted as large (BIPOP)."""
    small_evaluations: int = 0
    """Evaluations of the finished runs counted as small (BIPOP)."""
    doublings: int = 0
    """Population doublings so far (IPOP and BIPOP's large runs)."""
    finished: tuple[tuple[int, int, str], ...] = ()
    """``(lambda, evaluations learned from, why it stopped)`` of each finished run."""


class CMAState(NamedTuple):
    """The current run between generations (arrays are never modified in place).

    The last generation's costs are learned from at the start of the next
    step, in the same compiled call that samples the next generation.
    """

    run: np.ndarray
    """The last generation's result: its lambda points, then the run's core
    (:mod:`~formation_bench.optimizers.cma_ops`)."""
    costs: np.ndarray
    """The points' costs (+inf where the budget left one unevaluated); empty before the
    run's first generation."""
    normals: np.ndarray
    """Standard normals drawn ahead, one (lambda, n) block per generation."""
    uniforms: np.ndarray
    """Uniforms of the RESAMPLE bound handling, laid out as ``normals`` (else ``normals``)."""
    first_iteration: int
    """Iteration whose random numbers are block 0."""
    plan: RunPlan
    campaign: Campaign


@dataclass(frozen=True)
class CMAES(PopulationOptimizer[CMAState]):
    """CMA-ES with restarts; see the module docstring for the algorithm and its sources."""

    population_size: int | None = setting(
        None, kind=int, optional=True, low=2,
        doc="lambda, samples per generation of the first run; None: 4 + floor(3 ln n)",
    )  # fmt: skip
    sigma0: float = setting(
        0.2, low=0.0, high=1.0, low_open=True,
        doc="Initial step size as a fraction of each coordinate's range",
    )  # fmt: skip
    max_evaluations: int = setting(
        1230, low=1, doc="Evaluations when the caller gives no budget (the default budget)"
    )
    active: bool = setting(
        True, doc="Negative recombination weights for the worst steps (active CMA, as the tutorial)"
    )
    restarts: Restarts = setting(
        Restarts.SAME,
        doc="After a stop criterion: same (same lambda), ipop (double lambda) or bipop",
    )
    bound_handling: CMABoundHandling = setting(
        CMABoundHandling.TRANSFORM,
        doc="How samples are brought into the box: clip, reflect, resample, or transform (pycma's)",
    )
    constants: CMAConstants = setting(
        CMAConstants.PYCMA,
        doc="Strategy constants and h_sigma test: tutorial (Hansen's Table 1) or pycma (pycma 4's)",
    )
    lamarckian: bool = setting(
        False,
        doc="Learn from the repaired points (steps capped, Hansen 2011), not the sampled steps",
    )
    tol_fun: float = setting(
        1e-12, low=0.0,
        doc="TolFun: stop a run when recent best costs and the last generation span less",
    )  # fmt: skip
    tol_x: float = setting(
        1e-12, low=0.0,
        doc="TolX: stop a run when all standard deviations fall below tol_x times sigma0",
    )  # fmt: skip

    def __post_init__(self) -> None:
        validate_fields(self)

    # --- interface -------------------------------------------------------------------------------

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

    def result_info(self, state: CMAState) -> dict[str, Any]:
        """Restarts, why each run stopped, every run's lambda and evaluations, the last sigma.

        A run's evaluations are those it learned from (the last generation of
        a solve is evaluated but not learned from); sigma is in normalised
        coordinates.
        """
        lam = state.plan.population_size
        last = (lam, int(core_value(state.run, lam, RUN_EVALUATIONS)), "")
        return {
            "restarts": len(state.campaign.finished),
            "stops": [why for _, _, why in state.campaign.finished],
            "runs": [
                {"population_size": p, "evaluations": e, "stop": why or None}
                for p, e, why in (*state.campaign.finished, last)
            ],
            "population_size": lam,
            "sigma": core_value(state.run, lam, SIGMA),
        }

    def init(
        self,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        x0: np.ndarray | None,
        max_iterations: int,
    ) -> CMAState:
        """The first run, centred on ``x0`` (or a uniform point), which is evaluated."""
        start = bounds.sample(rng, 1) if x0 is None else x0[None].copy()
        evaluate_prefix(counter, start)
        return self.first_run(bounds, start, max_iterations)

    def first_run(self, bounds: Bounds, start: np.ndarray, max_iterations: int) -> CMAState:
        """The first run of a solve, centred on the evaluated ``start`` (one row)."""
        default_lambda = default_population_size(bounds.dim)
        plan = RunPlan(self.population_size or default_lambda, self.sigma0, False, math.inf)
        mean = (start[0] - bounds.lower) / bounds.width
        return self.start_run(bounds, mean, plan, Campaign(max_iterations, default_lambda))

    def step(
        self,
        state: CMAState,
        counter: EvaluationCounter,
        bounds: Bounds,
        rng: np.random.Generator,
        iteration: int,
    ) -> CMAState:
        # one unpacking instead of a dozen attribute reads: this runs once per generation
        run, costs, normals, uniforms, first_iteration, plan, campaign = state
        row = iteration - first_iteration
        if row >= normals.shape[0]:
            state, row = self.draw(state, rng, counter.remaining, iteration), 0
            normals, uniforms, first_iteration = state.normals, state.uniforms, iteration
        run = cma_generation(run, costs, normals, uniforms, row)
        lam = plan.population_size
        stop = run.item(lam, 0)  # the core's first entry: STOP
        if stop != RUNNING:
            state = self.restart(state, run, bounds, rng, STOP_NAMES[int(stop)])
            state = self.draw(state, rng, counter.remaining, iteration)
            run, _, normals, uniforms, first_iteration, plan, campaign = state
            run = cma_generation(run, state.costs, normals, uniforms, 0)
            lam = plan.population_size
        points = run[:lam]
        # the usual case, a whole generation within the budget, without evaluate_prefix's call
        costs = counter(points) if counter.remaining >= lam else evaluate_prefix(counter, points)
        return CMAState(run, costs, normals, uniforms, first_iteration, plan, campaign)

    # --- the compiled solve loop -----------------------------------------------------------------

    def has_compiled_loop(self) -> bool:
        return True

    def minimize_compiled(
        self,
        objective: CompiledObjective,
        bounds: Bounds,
        rng: np.random.Generator,
        budget: Budget,
        x0: np.ndarray | None,
    ) -> OptimizeResult:
        """The solve of :meth:`minimize` with its generations in :func:`.cma_block` calls.

        Python draws the random numbers and does the restarts, at the moments ``step``
        does them (a block's normals when the last are used up; a restart's draws when a
        run stops, then the new run's normals), so both loops make the same Generator
        calls in the same order and give the same result.
        """
        counts, best = new_tally(bounds.dim, budget.max_evaluations)
        started = perf_counter()
        start = bounds.sample(rng, 1) if x0 is None else x0[None].copy()
        compiled_evaluate_prefix(objective.address, objective.data, start, counts, best)
        state = self.first_run(bounds, start, self.planned_iterations(budget))
        history_nfev = [int(counts[NFEV])]
        history_fun = [float(best[0])]
        iteration_limit = compiled_iteration_limit(budget)
        message = "iteration budget reached"
        nit = 0
        deadline_s = budget.deadline_s
        while nit < iteration_limit:
            if remaining(counts) <= 0:
                message = "evaluation budget reached"
                break
            # checked before every generation, as the Python loop does: one per call then
            if deadline_s is not None and perf_counter() - started >= deadline_s:
                message = "deadline reached"
                break
            if nit + 1 - state.first_iteration >= state.normals.shape[0]:
                state = self.draw(state, rng, int(remaining(counts)), nit + 1)
            rows = state.normals.shape[0]
            block_nfev = np.empty(rows, dtype=np.int64)
            block_fun = np.empty(rows)
            run, costs, done, stopped = cma_block(
                objective.address, objective.data, counts, best, state.run, state.costs,
                state.normals, state.uniforms, nit, state.first_iteration,
                nit + 1 if deadline_s is not None else iteration_limit, block_nfev, block_fun,
            )  # fmt: skip
            history_nfev.extend(block_nfev[:done].tolist())
            history_fun.extend(block_fun[:done].tolist())
            nit += done
            state = state._replace(run=run, costs=costs)
            if stopped:
                # the new run's first generation only samples (no costs to learn from), so it
                # cannot stop: the next block call does iteration nit + 1 with it
                why = STOP_NAMES[int(core_value(run, state.plan.population_size, STOP))]
                state = self.restart(state, run, bounds, rng, why)
                state = self.draw(state, rng, int(remaining(counts)), nit + 1)
        else:
            if remaining(counts) <= 0:
                message = "evaluation budget reached"
        return compiled_result(
            CompiledStart(counts, best, started), nit, message, history_nfev, history_fun,
            self.result_info(state),
        )  # fmt: skip

    # --- runs and restarts -----------------------------------------------------------------------

    def start_run(
        self, bounds: Bounds, mean: np.ndarray, plan: RunPlan, campaign: Campaign
    ) -> CMAState:
        """A run centred on ``mean`` (normalised coordinates), with nothing drawn ahead yet."""
        n, lam = bounds.dim, plan.population_size
        template = run_template(
            n, lam, self.active, self.tol_fun, self.tol_x, int(self.bound_handling),
            self.lamarckian, int(self.constants),
        )  # fmt: skip
        if self.bound_handling is CMABoundHandling.TRANSFORM:
            # as pycma starts from inverse(x0): the transform maps the first mean onto the start
            mean = linquad_inverse(mean, np.zeros(n), np.ones(n))
        run = new_run(template, lam, mean, plan.sigma0, bounds.lower, bounds.upper, plan.limit)
        nothing = np.empty((0, lam, n))
        return CMAState(run, np.empty(0), nothing, nothing, 1, plan, campaign)

    def draw(
        self, state: CMAState, rng: np.random.Generator, left_evaluations: int, iteration: int
    ) -> CMAState:
        """Random numbers for the next generations from ``iteration`` on, in one call per kind.

        As far ahead as the ``left_evaluations`` of the budget reach (at most
        :data:`~formation_bench.optimizers.population.ROWS_AHEAD` generations):
        resample uniforms first (if used), then normals.
        """
        lam, n = state.plan.population_size, state.run.shape[1]
        left = min(state.campaign.t_max - iteration + 1, -(-left_evaluations // lam))
        rows = min(max(left, 1), ROWS_AHEAD)
        resample = self.bound_handling is CMABoundHandling.RESAMPLE
        uniforms = rng.random((rows, lam, n)) if resample else None
        normals = rng.standard_normal((rows, lam, n))
        return state._replace(
            normals=normals,
            uniforms=normals if uniforms is None else uniforms,
            first_iteration=iteration,
        )

    def restart(
        self, state: CMAState, run: np.ndarray, bounds: Bounds, rng: np.random.Generator, why: str
    ) -> CMAState:
        """The next run after ``run`` stopped for ``why``, from a uniform point of the box."""
        campaign = state.campaign
        used = int(core_value(run, state.plan.population_size, RUN_EVALUATIONS))
        large = campaign.large_evaluations + (used if state.plan.large else 0)
        small = campaign.small_evaluations + (0 if state.plan.large else used)
        doublings = campaign.doublings
        default = campaign.default_lambda
        if self.restarts is Restarts.SAME:
            plan = RunPlan(default, self.sigma0, True, math.inf)
        elif self.restarts is Restarts.IPOP or small >= max(1, large):
            doublings = min(doublings + 1, MAX_DOUBLINGS)
            plan = RunPlan(default * 2**doublings, self.sigma0, True, math.inf)
        else:
            u = rng.random(2)
            lam = math.floor(default * (2.0**doublings) ** (u[0] ** 2))
            plan = RunPlan(lam, self.sigma0 * 10.0 ** (-2.0 * u[1]), False, 0.5 * large)
        campaign = campaign._replace(
            large_evaluations=large,
            small_evaluations=small,
            doublings=doublings,
            finished=(*campaign.finished, (state.plan.population_size, used, why)),
        )
        return self.start_run(bounds, rng.random(bounds.dim), plan, campaign)


def core_value(run: np.ndarray, lam: int, index: int) -> float:
    """Scalar ``index`` of the core of ``run`` (a generation's result with ``lam`` point rows)."""
    n = run.shape[1]
    return float(run[lam + index // n, index % n])


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
