"""CMA-ES's runs and restarts: the state of a solve across its runs, and the loop that drives
the ask/tell kernels of :mod:`.cma_es` from run to run.

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

Doubling stops at 2^9 times the default lambda.

**Random numbers.** A restart draws from the Generator (the new mean, BIPOP's two uniforms)
and changes lambda, so the numbers of the generations are drawn here, between the kernels'
blocks (:func:`draw`), as far ahead as the budget reaches: the normals of a block are
``(rows, lambda, n)``. A run that stops ends its block early (:class:`CampaignDraws`).
"""

from __future__ import annotations

import math
from enum import IntEnum
from typing import Any, NamedTuple, Protocol

import numpy as np

from formation_bench.optimizers.ask_tell import BlockSource
from formation_bench.optimizers.base import Bounds, Budget
from formation_bench.optimizers.cma_ops import (
    RUNNING,
    STOP_NAMES,
    CMABoundHandling,
    CMARun,
    default_population_size,
    new_run,
    run_parameters,
)
from formation_bench.optimizers.population import ROWS_AHEAD, RandomAhead, standard_normals


class CampaignSettings(Protocol):
    """What the restarts read of a :class:`~formation_bench.optimizers.cma_es.CMAES`
    (a protocol, so that this module does not import the one that imports it)."""

    population_size: int | None
    sigma0: float
    restarts: Restarts
    active: bool
    constants: Any
    bound_handling: CMABoundHandling

    def planned_iterations(self, budget: Budget) -> int: ...

    @property
    def kernels(self) -> Any: ...


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
    """lambda."""
    sigma0: float
    """Initial step size in the normalised box."""
    large: bool
    """Counts in BIPOP's large-population budget (the first run counts as small)."""
    limit: float
    """Evaluations the run may learn from before it is stopped (small BIPOP runs), else inf."""


class Campaign(NamedTuple):
    """What a solve keeps across its runs (the restart bookkeeping)."""

    default_lambda: int
    """lambda of the first run."""
    large_evaluations: int
    """Evaluations of the finished runs counted as large (BIPOP)."""
    small_evaluations: int
    """Evaluations of the finished runs counted as small (BIPOP)."""
    doublings: int
    """Population doublings so far (IPOP and BIPOP's large runs)."""
    finished: np.ndarray
    """``(lambda, evaluations learned from, stop code)`` of each finished run, shape (k, 3)."""


class CMAState(NamedTuple):
    """A solve between generations: the current run, its plan and the solve's campaign."""

    run: CMARun
    plan: RunPlan
    campaign: Campaign


def start_run(
    config: CampaignSettings, mean: np.ndarray, plan: RunPlan, campaign: Campaign
) -> CMAState:
    """A run centred on ``mean`` (normalised coordinates)."""
    strategy = run_parameters(mean.shape[0], plan.population_size, bool(config.active),
                              int(config.constants))  # fmt: skip
    transform = config.bound_handling is CMABoundHandling.TRANSFORM
    return CMAState(new_run(mean, plan.sigma0, strategy, transform), plan, campaign)


def first_run(
    config: CampaignSettings, lower: np.ndarray, width: np.ndarray, start: np.ndarray
) -> CMAState:
    """The first run of a solve, centred on the evaluated ``start`` (a point of the box of
    corner ``lower`` and widths ``width``)."""
    default_lambda = default_population_size(start.shape[0])
    lam = config.population_size or default_lambda
    plan = RunPlan(int(lam), float(config.sigma0), False, math.inf)
    campaign = Campaign(default_lambda, 0, 0, 0, np.zeros((0, 3), dtype=np.int64))
    return start_run(config, (start - lower) / width, plan, campaign)


def restart(
    config: CampaignSettings, state: CMAState, bounds: Bounds, rng: np.random.Generator
) -> CMAState:
    """The next run after the current one stopped, from a uniform point of the box."""
    campaign, plan, progress = state.campaign, state.plan, state.run.progress
    used = progress.run_evaluations
    large = campaign.large_evaluations + (used if plan.large else 0)
    small = campaign.small_evaluations + (0 if plan.large else used)
    doublings = campaign.doublings
    default = campaign.default_lambda
    sigma0 = float(config.sigma0)
    if config.restarts is Restarts.SAME:
        plan = RunPlan(default, sigma0, True, math.inf)
    elif config.restarts is Restarts.IPOP or small >= max(1, large):
        doublings = min(doublings + 1, MAX_DOUBLINGS)
        plan = RunPlan(default * 2**doublings, sigma0, True, math.inf)
    else:
        u = rng.random(2)
        lam = math.floor(default * (2.0**doublings) ** (u[0] ** 2))
        plan = RunPlan(lam, sigma0 * 10.0 ** (-2.0 * u[1]), False, 0.5 * large)
    finished = np.array([[state.plan.population_size, used, progress.stop]], dtype=np.int64)
    campaign = Campaign(default, large, small, doublings,
                        np.concatenate((campaign.finished, finished)))  # fmt: skip
    return start_run(config, rng.random(bounds.dim), plan, campaign)


def draw(
    state: CMAState,
    rng: np.random.Generator,
    left_evaluations: int,
    iteration: int,
    t_max: int,
    resample: bool,
) -> RandomAhead:
    """Random numbers for the generations of the current run from ``iteration`` on.

    As far ahead as the ``left_evaluations`` of the budget reach (at most
    :data:`~formation_bench.optimizers.population.ROWS_AHEAD` generations), in one call per
    kind: the RESAMPLE bound handling's uniforms first (if used; else the normals stand in
    for them), then the normals, each ``(rows, lambda, n)``.
    """
    lam, n = state.plan.population_size, state.run.distribution.mean.shape[0]
    left = min(t_max - iteration + 1, -(-left_evaluations // lam))
    rows = min(max(left, 1), ROWS_AHEAD)
    uniforms = rng.random((rows, lam, n)) if resample else None
    normals = standard_normals(rng, (rows, lam, n))
    return RandomAhead(iteration, normals if uniforms is None else uniforms, normals)


class CampaignDraws(BlockSource):
    """The blocks of a CMA-ES solve: the numbers of :func:`draw` for the current run, and a
    restart (:func:`restart`) before the next generation when the run stopped. The generation
    whose update stopped a run samples nothing and is not done (the kernels leave the block's
    later rows empty, and they are not counted either), so the new run's first generation
    takes its iteration number."""

    def __init__(self, config: CampaignSettings, bounds: Bounds, t_max: int) -> None:
        self.config, self.bounds, self.t_max = config, bounds, t_max
        self.resample = config.bound_handling is CMABoundHandling.RESAMPLE
        self.block: RandomAhead | None = None

    def next_block(
        self, state: CMAState, rng: np.random.Generator, iteration: int, rows: int, left: int
    ) -> tuple[CMAState, np.ndarray, np.ndarray]:
        if state.run.progress.stop != RUNNING:
            state, self.block = restart(self.config, state, self.bounds, rng), None
        block = self.block
        if block is None or iteration - block.first_iteration >= block.normals.shape[0]:
            block = self.block = draw(state, rng, left, iteration, self.t_max, self.resample)
        offset = iteration - block.first_iteration
        rows = min(block.normals.shape[0] - offset, rows)
        return state, block.uniforms[offset : offset + rows], block.normals[offset : offset + rows]

    def iterations_done(self, state: CMAState, nit: int, done: int) -> int:
        stopped_at = state.run.progress.stopped_at
        return stopped_at - 1 - nit if stopped_at > 0 else done


def campaign_info(state: CMAState) -> dict[str, Any]:
    """Restarts, why each run stopped, every run's lambda and evaluations, the last sigma.

    A run's evaluations are those it learned from (the last generation of a solve is
    evaluated but not learned from); sigma is in normalised coordinates.
    """
    finished = [(int(lam), int(used), STOP_NAMES[int(code)])
                for lam, used, code in state.campaign.finished]  # fmt: skip
    lam = state.plan.population_size
    last = (lam, int(state.run.progress.run_evaluations), "")
    return {
        "restarts": len(finished),
        "stops": [why for _, _, why in finished],
        "runs": [
            {"population_size": p, "evaluations": e, "stop": why or None}
            for p, e, why in (*finished, last)
        ],
        "population_size": lam,
        "sigma": float(state.run.distribution.sigma),
    }
