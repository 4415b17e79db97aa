"""CMA-ES update rules as pure, compiled functions (driven by :mod:`.cma_es`).

The formulas are those of Hansen's tutorial (N. Hansen, *The CMA Evolution
Strategy: A Tutorial*, arXiv:1604.00772, Table 1 and Fig. 6) with its
default parameters or pycma's (:func:`cma_parameters`, :class:`CMAConstants`).
The search runs in coordinates normalised by the box, ``u = (x - lower) /
(upper - lower)`` in ``[0, 1]^n``, so that one scalar step size fits
coordinates of very different ranges (the paper problem mixes accelerations
in +-7 with turn rates in +-0.25).

**Bounds.** Samples are brought into the box by a repair (clip, reflect,
resample) or by pycma's BoundTransform (:func:`linquad_value`, reimplemented
after ``cma.transformations.BoxConstraintsLinQuadTransformation`` of pycma 4,
with its default margins), applied in the normalised box as the ``pycma``
adapter has pycma do: the distribution lives in the unbounded space of the
samples, the update learns from them, and only their images are evaluated.

Like the other ``*_ops`` modules, every random number comes in as an array
and inputs are never modified; one call of :func:`cma_generation` does a
whole generation's own work: the update from the last generation's costs,
then the next samples. :func:`cma_block` runs a block of generations with a
compiled objective (see :mod:`~formation_bench.optimizers.compiled`), the
evaluations included, for the compiled solve loop.

**One array per run.** At lambda = n = 10 the arithmetic of a generation
takes about 4 µs, while every array passed into or out of a kernel costs
0.1-0.5 µs at the Python boundary. So a run's whole state (strategy
parameters, mean, paths, C and its eigensystem, TolFun history, last steps)
lives in one float array, the *core*, laid out by :func:`layout`, and a
generation's result is one 2-D array: the lambda points to evaluate in its
first rows, the new core after them (:func:`core_of`). :func:`read_run`
gives named copies of its parts for tests and diagnostics.

**Eigendecomposition.** Refreshed lazily, when more than
``0.5 lambda / (n (c_1 + c_mu))`` evaluations passed since the last one (the
gap of Hansen's pure-Python reference implementation, ``purecma``), by a
compiled Householder tridiagonalisation and implicit QL iteration
(:func:`symmetric_eigen`, the EISPACK ``tred2``/``tql2`` algorithm of
Wilkinson & Reinsch's *Handbook for Automatic Computation*, vol. II, 1971;
Hansen's C and Java CMA-ES decompose C the same way). At n = 10 it takes
about 3.5 µs where numpy's LAPACK ``eigh`` takes about 7 µs, both timed in a
compiled loop; with C^(-1/2) a refresh takes about 4 µs, every second
generation at lambda = n = 10, half of a generation's own work.

**Step lengths.** The negative weights of the update are scaled by the
squared Mahalanobis length ``||C^(-1/2) y||^2`` of their steps, which the
sampling keeps: ``||z||^2`` for a sampled step (equal in exact arithmetic,
since the next update's C^(-1/2) belongs to the B and D the step was sampled
with), the capped length of a repaired Lamarckian step.
"""

from __future__ import annotations

import functools
import math
from enum import IntEnum
from typing import NamedTuple

import numpy as np
from numba import njit

from formation_bench.optimizers.bound_handling import BoundHandling, apply_bounds_inplace
from formation_bench.optimizers.compiled import NFEV, evaluate_prefix, remaining

# --- the core: scalars first, then the arrays laid out by layout() ------------------------------
STOP = 0
"""Stop code of the run after its last update (0: running; see :data:`STOP_NAMES`)."""
SIGMA = 1
GENERATION = 2
"""Updates done in this run."""
EIGEN_EVALUATIONS = 3
"""Run evaluations at the last eigendecomposition."""
RUN_EVALUATIONS = 4
"""Evaluations learned from in this run."""
SIGMA0 = 5
MU = 6
MUEFF = 7
C_SIGMA = 8
D_SIGMA = 9
C_C = 10
C_1 = 11
C_MU = 12
CHI_N = 13
EIGEN_GAP = 14
TOL_FUN = 15
TOL_X = 16
BOUND_MODE = 17
CAP = 18
HISTORY = 19
"""Length of the TolFun history."""
LIMIT = 20
"""Evaluations the run may learn from before it stops (RunBudget; inf: no limit)."""
LAMARCKIAN = 21
"""1: learn from the repaired points' steps; 0: from the sampled steps."""
H_SIGMA_TEST = 22
"""A :class:`CMAConstants` value: which test stalls the rank-one path after a long step."""
N_SCALARS = 23


class CMABoundHandling(IntEnum):
    """How CMA-ES brings its samples into the box: a repair, or pycma's BoundTransform."""

    CLIP = int(BoundHandling.CLIP)
    """Project the sample onto the nearest face."""
    REFLECT = int(BoundHandling.REFLECT)
    """Mirror the sample at the faces (a periodic fold, continuous across them)."""
    RESAMPLE = int(BoundHandling.RESAMPLE)
    """Replace each violating coordinate by a uniform value in its range."""
    TRANSFORM = 3
    """pycma's BoundTransform: map every sample by :func:`linquad_transform`, the identity
    inside the box but for a margin along each face, where it bends quadratically onto it."""


class CMAConstants(IntEnum):
    """Whose strategy constants a run uses; they differ in c_sigma, d_sigma and h_sigma."""

    TUTORIAL = 0
    """Hansen's tutorial, Table 1, and its h_sigma test on ``||p_sigma||``."""
    PYCMA = 1
    """pycma 4's: its c_sigma, d_sigma, c_1, c_mu, and its h_sigma test on ``||p_sigma||^2``."""


# Why a run stops (and, in a solve with budget left, restarts).
RUNNING = 0
TOL_FUN_STOP = 1
TOL_X_STOP = 2
NO_EFFECT_AXIS = 3
NO_EFFECT_COORD = 4
CONDITION_COV = 5
TOL_UP_SIGMA = 6
RUN_BUDGET = 7
STOP_NAMES = (
    "running",
    "tolfun",
    "tolx",
    "noeffectaxis",
    "noeffectcoord",
    "conditioncov",
    "tolupsigma",
    "runbudget",
)
"""Names of the stop codes: the criteria as the tutorial (appendix B.3) and pycma call them,
and ``runbudget`` for a run that used its evaluation allowance (small BIPOP runs)."""

MAX_CONDITION = 1e14
"""Largest condition number of C before the run stops (ConditionCov)."""
TOL_UP_SIGMA_FACTOR = 1e20
"""sigma / sigma0 above this times the longest axis stops the run (TolUpSigma)."""


class CMAParameters(NamedTuple):
    """The strategy parameters of one run (tutorial, Table 1)."""

    weights: np.ndarray
    """Recombination weights of the ranked steps, shape (lambda,): the first mu positive
    and summing to 1, the rest negative (active CMA) or zero."""
    mu: int
    """Parents: ``lambda // 2``."""
    mueff: float
    """Variance effective selection mass of the positive weights."""
    c_sigma: float
    """Learning rate of the step-size path."""
    d_sigma: float
    """Damping of the step-size update."""
    c_c: float
    """Learning rate of the rank-one path."""
    c_1: float
    """Learning rate of the rank-one update."""
    c_mu: float
    """Learning rate of the rank-mu update."""
    chi_n: float
    """E||N(0, I)||, approximated as sqrt(n) (1 - 1/(4n) + 1/(21 n^2))."""
    eigen_gap: float
    """Evaluations between two eigendecompositions of C."""
    history: int
    """Generations of best costs TolFun looks back over: 10 + ceil(30 n / lambda)."""


def default_population_size(dim: int) -> int:
    """lambda = 4 + floor(3 ln n), the tutorial's default."""
    return 4 + math.floor(3.0 * math.log(dim))


def cma_parameters(
    dim: int,
    population_size: int,
    active: bool = True,
    constants: CMAConstants = CMAConstants.TUTORIAL,
) -> CMAParameters:
    """The default strategy parameters for dimension ``dim`` and lambda, by ``constants``.

    TUTORIAL: the tutorial's Table 1; ``c_mu`` has the 1/4 offset of its
    current version (as pycma). PYCMA: as pycma 4 computes them (see
    :func:`pycma_step_size_constants`; its ``c_1`` is also scaled by
    ``min(1, lambda / 6)``); ``c_c`` and the weights' formulas are the same.
    With ``active`` the worst ``lambda - mu`` steps get the tutorial's negative
    weights (scaled by ``min(alpha_mu-, alpha_mueff-, alpha_posdef-)``); without
    it they get zero, the classic rank-mu update.
    """
    n, lam = float(dim), population_size
    mu = lam // 2
    prime = math.log((lam + 1) / 2.0) - np.log(np.arange(1, lam + 1))
    positive, negative = prime[:mu], prime[mu:]
    mueff = positive.sum() ** 2 / (positive**2).sum()
    alpha_cov = 2.0
    if constants == CMAConstants.PYCMA:
        c_sigma, d_sigma = pycma_step_size_constants(dim, float(mueff))
        # pycma's sampler damps c_1 for populations smaller than 6 (lambda_lower = 6)
        c_1 = min(1.0, lam / 6.0) * alpha_cov / ((n + 1.3) ** 2 + mueff)
    else:
        c_sigma = (mueff + 2.0) / (n + mueff + 5.0)
        d_sigma = 1.0 + 2.0 * max(0.0, math.sqrt((mueff - 1.0) / (n + 1.0)) - 1.0) + c_sigma
        c_1 = alpha_cov / ((n + 1.3) ** 2 + mueff)
    c_c = (4.0 + mueff / n) / (n + 4.0 + 2.0 * mueff / n)
    c_mu = min(
        1.0 - c_1,
        alpha_cov * (0.25 + mueff + 1.0 / mueff - 2.0) / ((n + 2.0) ** 2 + alpha_cov * mueff / 2.0),
    )
    weights = np.zeros(lam)
    weights[:mu] = positive / positive.sum()
    negative_sum = -negative[negative < 0].sum()
    if active and negative_sum > 0.0:
        mueff_minus = negative.sum() ** 2 / (negative**2).sum()
        scale = min(
            1.0 + c_1 / c_mu,
            1.0 + 2.0 * mueff_minus / (mueff + 2.0),
            (1.0 - c_1 - c_mu) / (n * c_mu),
        )
        weights[mu:] = scale * negative / negative_sum
    chi_n = math.sqrt(n) * (1.0 - 1.0 / (4.0 * n) + 1.0 / (21.0 * n * n))
    eigen_gap = 0.5 * lam / (n * (c_1 + c_mu))
    history = 10 + math.ceil(30.0 * n / lam)
    return CMAParameters(
        weights, mu, float(mueff), c_sigma, d_sigma, c_c, c_1, c_mu, chi_n, eigen_gap, history
    )


def pycma_step_size_constants(dim: int, mueff: float) -> tuple[float, float]:
    """``(c_sigma, d_sigma)`` of pycma 4's cumulative step-size adaptation (CMAAdaptSigmaCSA).

    ``c_sigma = min(1/2, (mueff + 2) / (n + mueff + 3))``, 2 less in the
    denominator than the tutorial's. ``d_sigma = 1 + 2 max(0, a sqrt((mueff - 1)
    / (n + 1)) - 1) + c_sigma`` with ``a = max(1, 3 (1 - 2^(-n/9)))`` where the
    tutorial has ``a = 1``: the damping for a large mueff, attenuated in small
    dimensions. pycma adds a term for mirrored sampling, which it uses below
    lambda = 6 by default; there is none here (as with pycma's ``CMA_mirrors=0``).
    """
    n = float(dim)
    c_sigma = min(0.5, (mueff + 2.0) / (n + mueff + 3.0))
    inner = max(1.0, 3.0 * (1.0 - 0.5 ** (n / 9.0)))
    d_sigma = 1.0 + 2.0 * max(0.0, inner * math.sqrt((mueff - 1.0) / (n + 1.0)) - 1.0) + c_sigma
    return c_sigma, d_sigma


def injection_cap(dim: int) -> float:
    """Largest Mahalanobis length of a repaired step in the update: sqrt(n) + 2n / (n + 2).

    Hansen, *Injecting external solutions into CMA-ES* (arXiv:1110.4181): a
    step that was not sampled from the distribution is shortened to this
    length, so that one repair cannot blow up the paths and C.
    """
    return math.sqrt(dim) + 2.0 * dim / (dim + 2.0)


# --- layout -------------------------------------------------------------------------------------


class Layout(NamedTuple):
    """Offsets of a run's arrays in its core (after the :data:`N_SCALARS` scalars)."""

    mean: int
    path_sigma: int
    path_c: int
    axes: int
    """D: square roots of C's eigenvalues."""
    cov: int
    """C, n x n."""
    eigenvectors: int
    """C's eigenvectors as rows, n x n (row k belongs to axes[k])."""
    inv_sqrt: int
    """C^(-1/2), n x n."""
    history: int
    """Best cost of each recent generation, newest first, nan until filled."""
    steps: int
    """The last generation's steps, lambda x n."""
    lengths: int
    """Squared Mahalanobis lengths ``||C^(-1/2) y||^2`` of the last steps, lambda."""
    weights: int
    lower: int
    width: int
    upper: int
    end: int
    """Length of the core."""


@njit(cache=True)
def layout(n: int, lam: int, history: int) -> Layout:
    """Where each array of a run of dimension ``n``, lambda and TolFun history sits in its core."""
    mean = N_SCALARS
    path_sigma = mean + n
    path_c = path_sigma + n
    axes = path_c + n
    cov = axes + n
    eigenvectors = cov + n * n
    inv_sqrt = eigenvectors + n * n
    hist = inv_sqrt + n * n
    steps = hist + history
    lengths = steps + lam * n
    weights = lengths + lam
    lower = weights + lam
    width = lower + n
    upper = width + n
    return Layout(
        mean, path_sigma, path_c, axes, cov, eigenvectors, inv_sqrt, hist, steps, lengths,
        weights, lower, width, upper, upper + n,
    )  # fmt: skip


@njit(cache=True)
def core_of(state: np.ndarray, lam: int) -> np.ndarray:
    """The core (1-D view) of a generation's result: everything after its ``lam`` point rows."""
    return state[lam:].reshape(-1)


@functools.lru_cache(maxsize=256)
def where_in_core(n: int, lam: int, history: int) -> Layout:
    """:func:`layout` for Python callers (cached: a compiled call returning a tuple costs µs)."""
    return layout.py_func(n, lam, history)


@functools.lru_cache(maxsize=64)
def run_template(
    dim: int,
    lam: int,
    active: bool,
    tol_fun: float,
    tol_x: float,
    bound_mode: int,
    lamarckian: bool = False,
    constants: int = CMAConstants.TUTORIAL,
) -> np.ndarray:
    """The parts of a new run's state that depend on its settings only (read-only, cached).

    Building them takes some 50 µs, a solve at the default budget about 2 ms:
    every solve of a closed loop starts a run with the same settings.
    ``bound_mode`` is a :class:`CMABoundHandling` and ``constants`` a
    :class:`CMAConstants` value.
    """
    params = cma_parameters(dim, lam, active, CMAConstants(constants))
    n = dim
    where = where_in_core(n, lam, params.history)
    state = np.zeros((lam + -(-where.end // n), n))
    core = state[lam:].reshape(-1)
    scalars = {
        MU: params.mu, MUEFF: params.mueff, C_SIGMA: params.c_sigma, D_SIGMA: params.d_sigma,
        C_C: params.c_c, C_1: params.c_1, C_MU: params.c_mu, CHI_N: params.chi_n,
        EIGEN_GAP: params.eigen_gap, TOL_FUN: tol_fun, TOL_X: tol_x, BOUND_MODE: bound_mode,
        CAP: injection_cap(n), HISTORY: params.history, LAMARCKIAN: float(lamarckian),
        H_SIGMA_TEST: float(constants),
    }  # fmt: skip
    for index, value in scalars.items():
        core[index] = value
    core[where.axes : where.axes + n] = 1.0
    for offset in (where.cov, where.eigenvectors, where.inv_sqrt):
        core[offset : offset + n * n] = np.eye(n).reshape(-1)
    core[where.history : where.history + params.history] = np.nan
    core[where.weights : where.weights + lam] = params.weights
    state.setflags(write=False)
    return state


def new_run(
    template: np.ndarray,
    lam: int,
    mean: np.ndarray,
    sigma0: float,
    lower: np.ndarray,
    upper: np.ndarray,
    limit: float = math.inf,
) -> np.ndarray:
    """The state of a run before its first generation: C = I, zero paths, no points yet.

    ``template`` is :func:`run_template`'s for the run's settings and ``lam``;
    ``mean`` is in normalised coordinates; ``limit`` is the run's evaluation
    allowance. The point rows are zero (there is nothing to evaluate before
    the first :func:`cma_generation`).
    """
    n = mean.shape[0]
    state = template.copy()
    core = state[lam:].reshape(-1)
    where = where_in_core(n, lam, int(core[HISTORY]))
    core[SIGMA] = core[SIGMA0] = sigma0
    core[LIMIT] = limit
    core[where.mean : where.mean + n] = mean
    core[where.lower : where.lower + n] = lower
    core[where.width : where.width + n] = upper - lower
    core[where.upper : where.upper + n] = upper
    return state


class RunView(NamedTuple):
    """Named read-only copies of a run's state (for tests and diagnostics)."""

    points: np.ndarray
    mean: np.ndarray
    sigma: float
    path_sigma: np.ndarray
    path_c: np.ndarray
    axes: np.ndarray
    cov: np.ndarray
    eigenvectors: np.ndarray
    inv_sqrt: np.ndarray
    history: np.ndarray
    steps: np.ndarray
    lengths: np.ndarray
    """Squared Mahalanobis lengths of the steps, as the next update reads them."""
    generation: int
    run_evaluations: int
    stop: int


def read_run(state: np.ndarray, lam: int) -> RunView:
    """:class:`RunView` of a generation's result (``lam`` point rows)."""
    n = state.shape[1]
    core = state[lam:].reshape(-1)
    where = where_in_core(n, lam, int(core[HISTORY]))

    def part(offset: int, shape: tuple[int, ...]) -> np.ndarray:
        return core[offset : offset + int(np.prod(shape))].reshape(shape).copy()

    return RunView(
        points=state[:lam].copy(),
        mean=part(where.mean, (n,)),
        sigma=float(core[SIGMA]),
        path_sigma=part(where.path_sigma, (n,)),
        path_c=part(where.path_c, (n,)),
        axes=part(where.axes, (n,)),
        cov=part(where.cov, (n, n)),
        eigenvectors=part(where.eigenvectors, (n, n)),
        inv_sqrt=part(where.inv_sqrt, (n, n)),
        history=part(where.history, (int(core[HISTORY]),)),
        steps=part(where.steps, (lam, n)),
        lengths=part(where.lengths, (lam,)),
        generation=int(core[GENERATION]),
        run_evaluations=int(core[RUN_EVALUATIONS]),
        stop=int(core[STOP]),
    )


# --- the generation ------------------------------------------------------------------------------


class Scratch(NamedTuple):
    """Work arrays of a generation, allocated once per :func:`cma_block` call (or per
    :func:`cma_generation` call), so that a generation allocates nothing."""

    order: np.ndarray
    """Ranking of the last costs, best first (lambda,)."""
    vector: np.ndarray
    """``<y>_w`` (n,)."""
    scaled: np.ndarray
    """c_mu times the (rescaled) weight of each rank (lambda,)."""
    matrix: np.ndarray
    """C / its largest diagonal entry, then the Householder transformation (n, n)."""
    diagonal: np.ndarray
    """Tridiagonal diagonal, then eigenvalues (n,)."""
    off_diagonal: np.ndarray
    """Tridiagonal off-diagonal (n,)."""
    unit: np.ndarray
    """Zeros and ones: the normalised box's lower and upper bounds (2, n)."""


@njit(cache=True)
def new_scratch(n: int, lam: int) -> Scratch:
    """The :class:`Scratch` of a run of dimension ``n`` and population ``lam``.

    Views of one float array (and the int ranking): an allocation costs about as much as
    the arithmetic of a small loop.
    """
    flat = np.empty(n + lam + n * n + 4 * n)
    matrix = flat[n + lam : n + lam + n * n].reshape(n, n)
    rest = n + lam + n * n
    unit = flat[rest + 2 * n :].reshape(2, n)
    unit[0] = 0.0
    unit[1] = 1.0
    return Scratch(
        np.empty(lam, dtype=np.int64), flat[:n], flat[n : n + lam], matrix,
        flat[rest : rest + n], flat[rest + n : rest + 2 * n], unit,
    )  # fmt: skip


@njit(cache=True)
def cma_generation(
    state: np.ndarray, costs: np.ndarray, normals: np.ndarray, uniforms: np.ndarray, row: int
) -> np.ndarray:
    """One generation's own work: learn from the last samples' ``costs``, then sample anew.

    ``state`` is the last generation's result (or :func:`new_run`'s); ``costs``
    are its points' costs, in row order (no entries at the first generation of
    a run: nothing to learn). ``normals[row]`` (lambda x n) are this
    generation's standard normals and ``uniforms[row]`` the uniforms of the
    RESAMPLE bound handling (any array for other modes). Returns a new state
    whose first lambda rows are the points to evaluate; a run that meets a
    stop criterion in the update samples nothing (its point rows are
    undefined, its :data:`STOP` entry says why). The input is not modified.
    """
    lam = normals.shape[1]
    n = state.shape[1]
    out = state.copy()
    core = core_of(out, lam)
    where = layout(n, lam, int(core[HISTORY]))
    advance(out, core, where, new_scratch(n, lam), costs, normals[row], uniforms[row])
    return out


@njit(cache=True)
def advance(
    run: np.ndarray,
    core: np.ndarray,
    where: Layout,
    scratch: Scratch,
    costs: np.ndarray,
    normals: np.ndarray,
    uniforms: np.ndarray,
) -> None:
    """:func:`cma_generation` in place: ``run`` becomes the next generation's result.

    ``core`` is ``core_of(run, lam)`` and ``where`` its layout; ``normals`` and
    ``uniforms`` are this generation's (lambda x n) blocks.
    """
    lam, n = normals.shape
    if costs.shape[0] > 0:
        update_distribution(core, where, costs, n, lam, scratch)
        core[RUN_EVALUATIONS] += lam
        condition = 1.0
        if core[RUN_EVALUATIONS] - core[EIGEN_EVALUATIONS] > core[EIGEN_GAP]:
            condition = refresh_eigensystem(core, where, n, scratch)
            core[EIGEN_EVALUATIONS] = core[RUN_EVALUATIONS]
        core[STOP] = stop_code(core, where, costs, condition, n)
        if core[STOP] != RUNNING:
            return
    sample(core, where, run[:lam], normals, uniforms, n, lam, scratch)


@njit(cache=True)
def cma_block(
    address: int,
    data: np.ndarray,
    counts: np.ndarray,
    best: np.ndarray,
    run: np.ndarray,
    costs: np.ndarray,
    normals: np.ndarray,
    uniforms: np.ndarray,
    nit: int,
    first_iteration: int,
    iteration_limit: int,
    history_nfev: np.ndarray,
    history_fun: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """Generations ``nit + 1``, ... of a compiled solve, one per block of ``normals`` left.

    Each is :func:`cma_generation` with the points evaluated through ``address``/``data``
    (see :mod:`~formation_bench.optimizers.compiled`), as ``CMAES.step`` does without a
    restart; block ``k`` of ``normals`` and ``uniforms`` belongs to iteration
    ``first_iteration + k``. The loop stops at the iteration limit, when no evaluation is
    left, at the end of the blocks, or when the run meets a stop criterion: a restart draws
    from the Generator, so its caller does it and calls again for the new run's first
    generation. Returns ``(run, costs, iterations done, stopped)``; a stopped ``run`` is the
    stopped generation's result (nothing sampled), its iteration not done. The history arrays
    get one entry per iteration done. ``run`` is copied once and then advanced in place (the
    caller's array is not modified).
    """
    lam, n = normals.shape[1], run.shape[1]
    run = run.copy()
    core = core_of(run, lam)
    where = layout(n, lam, int(core[HISTORY]))
    scratch = new_scratch(n, lam)
    done = 0
    row = nit + 1 - first_iteration
    while nit < iteration_limit and row < normals.shape[0] and remaining(counts) > 0:
        advance(run, core, where, scratch, costs, normals[row], uniforms[row])
        if core[STOP] != RUNNING:
            return run, costs, done, True
        nit += 1
        costs = evaluate_prefix(address, data, run[:lam], counts, best)
        history_nfev[done] = counts[NFEV]
        history_fun[done] = best[0]
        done += 1
        row += 1
    return run, costs, done, False


@njit(cache=True)
def ranking(costs: np.ndarray, order: np.ndarray) -> None:
    """Indices of ``costs`` from best to worst into ``order``, ties in index order
    (insertion sort: small)."""
    m = costs.shape[0]
    for k in range(m):
        v = costs[k]
        j = k
        while j > 0 and costs[order[j - 1]] > v:
            order[j] = order[j - 1]
            j -= 1
        order[j] = k


@njit(cache=True)
def update_distribution(
    core: np.ndarray, where: Layout, costs: np.ndarray, n: int, lam: int, scratch: Scratch
) -> None:
    """The tutorial's update (Fig. 6, c_m = 1) of mean, paths, sigma, C and the TolFun history.

    Written into ``core``. ``<y>_w`` comes from the mu best steps; cumulative
    step-size adaptation with ``C^(-1/2)`` of the last eigendecomposition;
    ``h_sigma`` stalls the rank-one path after a long step (the tutorial's
    test ``||p_sigma|| / sqrt(1 - (1 - c_sigma)^(2(g+1))) < (1.4 + 2 / (n +
    1)) E||N(0, I)||`` or pycma's ``||p_sigma||^2 / (1 - (1 - c_sigma)^(2(g+1)))
    / n - 1 < 1 + 4 / (n + 1)``, by the core's H_SIGMA_TEST); the rank-one and
    rank-mu updates of C, a negative weight scaled by ``n / ||C^(-1/2) y||^2``.
    """
    order = scratch.order
    ranking(costs, order)
    steps = core[where.steps : where.steps + lam * n].reshape(lam, n)
    weights = core[where.weights : where.weights + lam]
    mean = core[where.mean : where.mean + n]
    ps = core[where.path_sigma : where.path_sigma + n]
    pc = core[where.path_c : where.path_c + n]
    cov = core[where.cov : where.cov + n * n].reshape(n, n)
    inv_sqrt = core[where.inv_sqrt : where.inv_sqrt + n * n].reshape(n, n)
    sigma = core[SIGMA]
    mu = int(core[MU])
    mueff, c_sigma, d_sigma = core[MUEFF], core[C_SIGMA], core[D_SIGMA]
    c_c, c_1, c_mu, chi_n = core[C_C], core[C_1], core[C_MU], core[CHI_N]

    y_w = scratch.vector
    for i in range(n):
        y_w[i] = 0.0
    for r in range(mu):
        k = order[r]
        for i in range(n):
            y_w[i] += weights[r] * steps[k, i]
    for i in range(n):
        mean[i] += sigma * y_w[i]

    ps_factor = math.sqrt(c_sigma * (2.0 - c_sigma) * mueff)
    ps_norm2 = 0.0
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += inv_sqrt[i, j] * y_w[j]
        ps[i] = (1.0 - c_sigma) * ps[i] + ps_factor * s
        ps_norm2 += ps[i] * ps[i]
    ps_norm = math.sqrt(ps_norm2)
    # p_sigma starts at zero, so its expected length grows to the stationary one only
    # after some generations: both tests divide the bias out
    bias = 1.0 - (1.0 - c_sigma) ** (2.0 * (core[GENERATION] + 1.0))
    if int(core[H_SIGMA_TEST]) == CMAConstants.TUTORIAL:
        short = ps_norm / math.sqrt(bias) < (1.4 + 2.0 / (n + 1.0)) * chi_n
    else:  # pycma compares the squared length, E||N(0, I)||^2 = n
        short = ps_norm2 / bias / n - 1.0 < 1.0 + 4.0 / (n + 1.0)
    h_sigma = 1.0 if short else 0.0
    pc_factor = h_sigma * math.sqrt(c_c * (2.0 - c_c) * mueff)
    for i in range(n):
        pc[i] = (1.0 - c_c) * pc[i] + pc_factor * y_w[i]

    # w° of the tutorial: a negative weight is scaled by n / ||C^(-1/2) y||^2, so that
    # a long unlucky step cannot remove more variance than a typical one
    # (the squared lengths were kept by sample(): see there)
    lengths = core[where.lengths : where.lengths + lam]
    scaled = scratch.scaled
    weight_sum = 0.0
    for r in range(lam):
        w = weights[r]
        weight_sum += w
        if w < 0.0:
            w = w * n / max(lengths[order[r]], 1e-300)
        scaled[r] = c_mu * w
    delta_h = (1.0 - h_sigma) * c_c * (2.0 - c_c)
    decay = 1.0 + c_1 * delta_h - c_1 - c_mu * weight_sum
    for i in range(n):
        for j in range(i, n):
            value = decay * cov[i, j] + c_1 * pc[i] * pc[j]
            for r in range(lam):
                y = steps[order[r]]
                value += scaled[r] * y[i] * y[j]
            cov[i, j] = value
            cov[j, i] = value

    core[SIGMA] = sigma * math.exp((c_sigma / d_sigma) * (ps_norm / chi_n - 1.0))
    core[GENERATION] += 1.0
    history = core[where.history : where.history + int(core[HISTORY])]
    for k in range(history.shape[0] - 1, 0, -1):
        history[k] = history[k - 1]
    history[0] = costs[order[0]]


@njit(cache=True)
def mahalanobis(inv_sqrt: np.ndarray, y: np.ndarray) -> float:
    """``||C^(-1/2) y||``."""
    n = y.shape[0]
    total = 0.0
    for i in range(n):
        s = 0.0
        for j in range(n):
            s += inv_sqrt[i, j] * y[j]
        total += s * s
    return math.sqrt(total)


@njit(cache=True)
def refresh_eigensystem(core: np.ndarray, where: Layout, n: int, scratch: Scratch) -> float:
    """Eigendecompose C into the core's axes, eigenvectors and C^(-1/2); returns cond(C).

    C is scaled by its largest diagonal entry first, so that no square in the
    QL iteration overflows or underflows. Eigenvalues are floored at 1e-20
    times the largest, so a rounding error cannot make an axis length
    imaginary; the returned condition is taken before the floor (``inf`` if
    an eigenvalue is not positive or C is not finite).
    """
    cov = core[where.cov : where.cov + n * n].reshape(n, n)
    scale = 0.0
    for i in range(n):
        scale = max(scale, cov[i, i])
    if not (scale > 0.0 and math.isfinite(scale)):
        return math.inf
    for i in range(n):
        for j in range(n):
            if not math.isfinite(cov[i, j]):
                return math.inf
    matrix = scratch.matrix
    for i in range(n):
        for j in range(n):
            matrix[i, j] = cov[i, j] / scale
    values = scratch.diagonal
    rows = core[where.eigenvectors : where.eigenvectors + n * n].reshape(n, n)
    eigen_into(matrix, values, scratch.off_diagonal, rows)
    largest, smallest = -math.inf, math.inf
    for k in range(n):
        largest = max(largest, values[k])
        smallest = min(smallest, values[k])
    condition = largest / smallest if smallest > 0.0 else math.inf
    floor = max(largest, 1e-300) * 1e-20
    axes = core[where.axes : where.axes + n]
    for k in range(n):
        axes[k] = math.sqrt(max(values[k], floor) * scale)
    inv_sqrt = core[where.inv_sqrt : where.inv_sqrt + n * n].reshape(n, n)
    for i in range(n):
        for j in range(n):
            inv_sqrt[i, j] = 0.0
    for k in range(n):
        scale_k = 1.0 / axes[k]
        for i in range(n):
            a = rows[k, i] * scale_k
            for j in range(n):
                inv_sqrt[i, j] += a * rows[k, j]
    return condition


@njit(cache=True)
def stop_code(core: np.ndarray, where: Layout, costs: np.ndarray, condition: float, n: int) -> int:
    """Which stop criterion of the tutorial's appendix B.3 the updated run meets (0: none).

    TolFun applies once the history is full; TolX is relative to the run's
    initial sigma. Checked in the order of :data:`STOP_NAMES`, the run's
    evaluation allowance last.
    """
    mean = core[where.mean : where.mean + n]
    pc = core[where.path_c : where.path_c + n]
    axes = core[where.axes : where.axes + n]
    cov = core[where.cov : where.cov + n * n].reshape(n, n)
    rows = core[where.eigenvectors : where.eigenvectors + n * n].reshape(n, n)
    history = core[where.history : where.history + int(core[HISTORY])]
    sigma, sigma0 = core[SIGMA], core[SIGMA0]

    full = True
    low, high = math.inf, -math.inf
    for v in history:
        if math.isnan(v):
            full = False
            break
        low, high = min(low, v), max(high, v)
    if full:
        for v in costs:
            low, high = min(low, v), max(high, v)
        if high - low < core[TOL_FUN]:  # False for infinite costs: inf - inf is nan
            return TOL_FUN_STOP

    tol_x = core[TOL_X] * sigma0
    small = True
    for i in range(n):
        if sigma * math.sqrt(max(cov[i, i], 0.0)) >= tol_x or sigma * abs(pc[i]) >= tol_x:
            small = False
            break
    if small:
        return TOL_X_STOP

    axis = int(core[GENERATION]) % n
    no_effect = True
    for i in range(n):
        if mean[i] + 0.1 * sigma * axes[axis] * rows[axis, i] != mean[i]:
            no_effect = False
            break
    if no_effect:
        return NO_EFFECT_AXIS

    for i in range(n):
        if mean[i] + 0.2 * sigma * math.sqrt(max(cov[i, i], 0.0)) == mean[i]:
            return NO_EFFECT_COORD

    if not condition <= MAX_CONDITION:
        return CONDITION_COV

    longest = 0.0
    for k in range(n):
        longest = max(longest, axes[k])
    if sigma / sigma0 > TOL_UP_SIGMA_FACTOR * longest:
        return TOL_UP_SIGMA
    if core[RUN_EVALUATIONS] >= core[LIMIT]:
        return RUN_BUDGET
    return RUNNING


@njit(cache=True)
def sample(
    core: np.ndarray,
    where: Layout,
    points: np.ndarray,
    normals: np.ndarray,
    uniforms: np.ndarray,
    n: int,
    lam: int,
    scratch: Scratch,
) -> None:
    """lambda samples ``m + sigma B (D * z)`` into ``points`` (box coordinates) and their steps.

    ``z`` are the rows of ``normals``. The core's bound mode (a
    :class:`CMABoundHandling` value) brings the samples into [0, 1]^n: a
    repair of those outside (``uniforms``, shaped like ``normals``, are read
    only by RESAMPLE), or pycma's BoundTransform of all of them
    (:func:`linquad_value`, the identity but for the margin along each face);
    the repaired or mapped point is the one evaluated. The step the next
    update learns from is the sampled one (the search minimises
    ``f(repair(x))``, as pycma does with its BoundTransform), or, with the
    core's LAMARCKIAN flag, the evaluated point's ``(u_repaired - m) /
    sigma``, shortened to the Mahalanobis length :func:`injection_cap` if
    longer. Points are mapped to the box as ``lower + width u`` and clipped,
    so that rounding cannot leave it.
    """
    mean = core[where.mean : where.mean + n]
    axes = core[where.axes : where.axes + n]
    rows = core[where.eigenvectors : where.eigenvectors + n * n].reshape(n, n)
    inv_sqrt = core[where.inv_sqrt : where.inv_sqrt + n * n].reshape(n, n)
    steps = core[where.steps : where.steps + lam * n].reshape(lam, n)
    lengths = core[where.lengths : where.lengths + lam]
    lower = core[where.lower : where.lower + n]
    width = core[where.width : where.width + n]
    upper = core[where.upper : where.upper + n]
    sigma = core[SIGMA]
    cap = core[CAP]
    lamarckian = core[LAMARCKIAN] != 0.0

    # ||C^(-1/2) y|| = ||B D^(-1) B^T B D z|| = ||z||: the update's next C^(-1/2) is the one
    # of this B and D (the eigensystem is refreshed only after an update), so a sampled
    # step's Mahalanobis length is that of its normals, n operations instead of n^2
    for s in range(lam):
        y = steps[s]
        y[:] = 0.0
        length2 = 0.0
        for k in range(n):
            length2 += normals[s, k] * normals[s, k]
        lengths[s] = length2
        for k in range(n):
            a = axes[k] * normals[s, k]
            for i in range(n):
                y[i] += rows[k, i] * a
        for i in range(n):
            points[s, i] = mean[i] + sigma * y[i]
    # repaired or mapped in place in the point rows, still in [0, 1] coordinates
    unit = scratch.unit
    mode = int(core[BOUND_MODE])
    if mode == CMABoundHandling.TRANSFORM:
        linquad_transform_inplace(points, unit[0], unit[1])
    else:
        apply_bounds_inplace(points, unit[0], unit[1], mode, uniforms)
    if lamarckian:
        for s in range(lam):
            y = steps[s]
            for i in range(n):
                if points[s, i] != mean[i] + sigma * y[i]:  # moved by the repair
                    for j in range(n):
                        y[j] = (points[s, j] - mean[j]) / sigma
                    length = mahalanobis(inv_sqrt, y)
                    if length > cap:
                        for j in range(n):
                            y[j] *= cap / length
                        length = cap
                    lengths[s] = length * length
                    break
    for s in range(lam):
        for i in range(n):
            points[s, i] = min(max(lower[i] + width[i] * points[s, i], lower[i]), upper[i])


# --- pycma's BoundTransform ---------------------------------------------------------------------


@njit(cache=True)
def linquad_margins(lower: float, upper: float) -> tuple[float, float]:
    """pycma's default margins ``(a_l, a_u)`` of the box ``[lower, upper]`` of one coordinate.

    ``min((upper - lower) / 2, max(1, |bound|) / 20)`` for each bound
    (``cma.transformations.margin_width2``, pycma's ``linquad_margin_width``):
    0.05 on each side of the unit interval.
    """
    half = (upper - lower) / 2.0
    return min(half, max(1.0, abs(lower)) / 20.0), min(half, max(1.0, abs(upper)) / 20.0)


@njit(cache=True)
def linquad_value(v: float, lower: float, upper: float) -> float:
    """pycma's BoundTransform of one coordinate ``v`` into ``[lower, upper]``.

    The transform of ``cma.transformations.BoxConstraintsLinQuadTransformation``:
    periodic with period ``2 (upper - lower + a_l + a_u)`` and symmetric about
    ``lower - a_l`` and ``upper + a_u``; within ``[lower - a_l, upper + a_u]``
    the identity on ``[lower + a_l, upper - a_u]`` and the parabola through
    ``(lower - a_l, lower)`` (``(upper + a_u, upper)``) with slope 0 there and 1
    where it meets the identity. So it is continuously differentiable, and a
    coordinate beyond a face is folded back as by a mirror that stops at the
    face. A value far outside is first shifted by whole periods, by the same
    floor division as pycma's, then mirrored into the interval.
    """
    al, au = linquad_margins(lower, upper)
    width = upper - lower
    start = lower - 2.0 * al - width / 2.0
    if v < start or v > upper + 2.0 * au + width / 2.0:
        period = 2.0 * (width + al + au)
        v -= period * ((v - start) // period)
    if v > upper + au:
        v -= 2.0 * (v - upper - au)
    if v < lower - al:
        v += 2.0 * (lower - al - v)
    if v < lower + al:
        d = v - (lower - al)
        return lower + d * d / 4.0 / al
    if v > upper - au:
        d = v - (upper + au)
        return upper - d * d / 4.0 / au
    return v


@njit(cache=True)
def linquad_transform_inplace(x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> None:
    """:func:`linquad_value` of every entry of the rows of ``x`` (m x n), written into ``x``."""
    m, n = x.shape
    for s in range(m):
        for i in range(n):
            x[s, i] = linquad_value(x[s, i], lower[i], upper[i])


@njit(cache=True)
def linquad_transform(x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """A copy of the points ``x`` (m x n) mapped into the box by :func:`linquad_value`."""
    out = x.copy()
    linquad_transform_inplace(out, lower, upper)
    return out


@njit(cache=True)
def linquad_inverse(y: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """The point of ``[lower - a_l, upper + a_u]`` that :func:`linquad_value` maps to ``y``.

    pycma's ``BoundTransform.inverse``, with which it turns its ``x0`` into the
    first mean; ``y`` is clipped into the box first (pycma raises instead).
    """
    out = np.empty_like(y)
    for i in range(y.shape[0]):
        lo, hi = lower[i], upper[i]
        al, au = linquad_margins(lo, hi)
        v = min(max(y[i], lo), hi)
        if v < lo + al:
            out[i] = (lo - al) + 2.0 * math.sqrt(al * (v - lo))
        elif v < hi - au:
            out[i] = v
        else:
            out[i] = (hi + au) - 2.0 * math.sqrt(au * (hi - v))
    return out


def symmetric_eigen(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(values, rows)``: eigenvalues of the symmetric ``a`` and its eigenvectors as rows.

    :func:`eigen_into` on a copy of ``a``. Eigenvalues are not sorted;
    ``rows[k]`` belongs to ``values[k]``. The caller scales ``a`` so that its
    entries are of order one (the QL step squares them without the guard of
    ``hypot``).
    """
    n = a.shape[0]
    values, rows = np.empty(n), np.empty((n, n))
    eigen_into(np.array(a, dtype=np.float64), values, np.empty(n), rows)
    return values, rows


# error_model="numpy": no zero check per division (the QL step divides only by values it
# has shown to be nonzero), which makes the decomposition about a fifth faster
@njit(cache=True, error_model="numpy")
def eigen_into(v: np.ndarray, d: np.ndarray, e: np.ndarray, w: np.ndarray) -> None:
    """Eigenvalues of the symmetric ``v`` (n x n, destroyed) into ``d``, eigenvectors as rows
    into ``w``; ``e`` is a work array of length n.

    Householder reduction to tridiagonal form with the transformation
    accumulated (``tred2``), then the implicit QL iteration (``tql2``), as in
    Wilkinson & Reinsch's *Handbook* (1971, contributions II/2 and II/3).
    """
    n = v.shape[0]
    for j in range(n):
        d[j] = v[n - 1, j]
    # Householder: row i is reduced using the part left of the diagonal
    for i in range(n - 1, 0, -1):
        scale = 0.0
        h = 0.0
        for k in range(i):
            scale += abs(d[k])
        if scale == 0.0:
            e[i] = d[i - 1]
            for j in range(i):
                d[j] = v[i - 1, j]
                v[i, j] = 0.0
                v[j, i] = 0.0
        else:
            for k in range(i):
                d[k] /= scale
                h += d[k] * d[k]
            f = d[i - 1]
            g = math.sqrt(h)
            if f > 0:
                g = -g
            e[i] = scale * g
            h -= f * g
            d[i - 1] = f - g
            for j in range(i):
                e[j] = 0.0
            for j in range(i):
                f = d[j]
                v[j, i] = f
                g = e[j] + v[j, j] * f
                for k in range(j + 1, i):
                    g += v[k, j] * d[k]
                    e[k] += v[k, j] * f
                e[j] = g
            f = 0.0
            for j in range(i):
                e[j] /= h
                f += e[j] * d[j]
            hh = f / (h + h)
            for j in range(i):
                e[j] -= hh * d[j]
            for j in range(i):
                f = d[j]
                g = e[j]
                for k in range(j, i):
                    v[k, j] -= f * e[k] + g * d[k]
                d[j] = v[i - 1, j]
                v[i, j] = 0.0
        d[i] = h
    # accumulate the transformations
    for i in range(n - 1):
        v[n - 1, i] = v[i, i]
        v[i, i] = 1.0
        h = d[i + 1]
        if h != 0.0:
            for k in range(i + 1):
                d[k] = v[k, i + 1] / h
            for j in range(i + 1):
                g = 0.0
                for k in range(i + 1):
                    g += v[k, i + 1] * v[k, j]
                for k in range(i + 1):
                    v[k, j] -= g * d[k]
        for k in range(i + 1):
            v[k, i + 1] = 0.0
    for j in range(n):
        d[j] = v[n - 1, j]
        v[n - 1, j] = 0.0
    v[n - 1, n - 1] = 1.0
    # QL on the tridiagonal (d, e), rotating the rows of w (contiguous: the loop vectorises)
    for i in range(n):
        for j in range(n):
            w[i, j] = v[j, i]
    for i in range(1, n):
        e[i - 1] = e[i]
    e[n - 1] = 0.0
    f = 0.0
    tst1 = 0.0
    eps = 2.0**-52
    for m0 in range(n):
        tst1 = max(tst1, abs(d[m0]) + abs(e[m0]))
        m = m0
        while m < n - 1:
            if abs(e[m]) <= eps * tst1:
                break
            m += 1
        if m > m0:
            for _ in range(60):
                g = d[m0]
                p = (d[m0 + 1] - g) / (2.0 * e[m0])
                r = math.sqrt(p * p + 1.0)
                if p < 0:
                    r = -r
                d[m0] = e[m0] / (p + r)
                d[m0 + 1] = e[m0] * (p + r)
                dl1 = d[m0 + 1]
                h = g - d[m0]
                for i in range(m0 + 2, n):
                    d[i] -= h
                f += h
                p = d[m]
                c = 1.0
                c2 = c
                c3 = c
                el1 = e[m0 + 1]
                s = 0.0
                s2 = 0.0
                for i in range(m - 1, m0 - 1, -1):
                    c3 = c2
                    c2 = c
                    s2 = s
                    g = c * e[i]
                    h = c * p
                    r = math.sqrt(p * p + e[i] * e[i])
                    e[i + 1] = s * r
                    s = e[i] / r
                    c = p / r
                    p = c * d[i] - s * g
                    d[i + 1] = h + s * (c * g + s * d[i])
                    wi = w[i]
                    wi1 = w[i + 1]
                    for k in range(n):
                        h = wi1[k]
                        wi1[k] = s * wi[k] + c * h
                        wi[k] = c * wi[k] - s * h
                p = -s * s2 * c3 * el1 * e[m0] / dl1
                e[m0] = s * p
                d[m0] = c * p
                if abs(e[m0]) <= eps * tst1:
                    break
        d[m0] = d[m0] + f
        e[m0] = 0.0
