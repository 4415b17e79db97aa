"""CMA-ES: strategy constants, a run's named state and its update rules (driven by
:mod:`.cma_es`).

The formulas are those of Hansen's tutorial (N. Hansen, *The CMA Evolution
Strategy: A Tutorial*, arXiv:1604.00772, Table 1 and Fig. 6) with its
default parameters or pycma's (:func:`cma_parameters`, :class:`CMAConstants`).
The search runs in coordinates normalised by the box, ``u = (x - lower) /
(upper - lower)`` in ``[0, 1]^n``, so that one scalar step size fits
coordinates of very different ranges (the paper problem mixes accelerations
in +-7 with turn rates in +-0.25).

**Bounds.** Samples are brought into the box by a repair (clip, reflect,
resample) or by pycma's BoundTransform (:mod:`.cma_transform`).

A run is a :class:`CMARun` of named parts: its :class:`Distribution` (mean, sigma, C, its
eigensystem B and D, C^(-1/2), the paths), its last :class:`Samples`, its
:class:`Progress` (counters, TolFun history, why it stopped) and its constant
:class:`CMAParameters`, and its :class:`Workspace`. Every random number comes in as an array.
:func:`learn` and :func:`sample` advance a run's arrays in place (its scalars, such as sigma
and the counters, come back in new parts): a block of generations copies its run once
(:func:`owned`) and then allocates nothing per generation but the costs of its evaluations.
Rebuilding every array of a run each generation, as a purely functional update would, made a
solve some 10 % slower than writing the same arithmetic in place.

**Compiled once, called.** :func:`learn`, :func:`update_distribution`, :func:`refresh`,
:func:`stop_code` and :func:`sample` are compiled functions of their own that the ask and tell
kernels call, not inlined into them: numba types an inlined body again inside every caller, and
with all five inlined into the solve loop a first run compiled CMA-ES in 55 s of CPU, against
30 s called, with the same solve time and the same numbers.

**Eigendecomposition.** Refreshed lazily, when more than
``0.5 lambda / (n (c_1 + c_mu))`` evaluations passed since the last one (the
gap of Hansen's pure-Python reference implementation, ``purecma``): every second
generation at lambda = n = 10, 60 decompositions in a solve of the paper problem at the
default budget (1230 evaluations). By the compiled tred2/tql2 of :mod:`.cma_eigen`, not
LAPACK's ``eigh``: in a compiled loop (process time) ``eigh`` takes 6.7 µs a decomposition
at n = 10 (24.7 µs at n = 20), tred2/tql2 3.1 µs (11.5 µs), so with ``eigh`` the 60 took
some 0.4 ms, about 30 % of a solve's CPU time, against 0.18 ms.

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

from formation_bench.kernel_cache import njit
from formation_bench.optimizers.bound_handling import BoundHandling, apply_bounds_inplace
from formation_bench.optimizers.cma_eigen import eigen_into
from formation_bench.optimizers.cma_transform import linquad_inverse, linquad_transform_inplace


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


@functools.lru_cache(maxsize=64)
def run_parameters(dim: int, lam: int, active: bool, constants: int) -> CMAParameters:
    """:func:`cma_parameters`, cached: building them takes some 50 µs, and every solve of a
    closed loop starts a run with the same settings. Nothing modifies their weights."""
    return cma_parameters(dim, lam, active, CMAConstants(constants))


# --- a run's state -------------------------------------------------------------------------------


class Distribution(NamedTuple):
    """The search distribution ``N(mean, sigma^2 C)`` and its evolution paths."""

    mean: np.ndarray
    """m, shape (n,), in normalised coordinates (before the BoundTransform, if used)."""
    sigma: float
    """Step size."""
    cov: np.ndarray
    """C, shape (n, n)."""
    eigenvectors: np.ndarray
    """B^T: C's eigenvectors as rows, as of the last eigendecomposition, shape (n, n)."""
    axes: np.ndarray
    """D: square roots of C's eigenvalues (row k of B^T belongs to axes[k]), shape (n,)."""
    inv_sqrt: np.ndarray
    """C^(-1/2) = B D^-1 B^T, shape (n, n)."""
    path_sigma: np.ndarray
    """p_sigma, the conjugate evolution path of the step-size adaptation, shape (n,)."""
    path_c: np.ndarray
    """p_c, the evolution path of the rank-one update, shape (n,)."""


class Samples(NamedTuple):
    """The last generation: its points, the steps the update learns from and their costs."""

    points: np.ndarray
    """The points evaluated (box coordinates), shape (lambda, n)."""
    steps: np.ndarray
    """Their steps ``y`` (normalised coordinates, divided by sigma), shape (lambda, n)."""
    lengths: np.ndarray
    """Squared Mahalanobis lengths ``||C^(-1/2) y||^2`` of the steps, shape (lambda,)."""
    costs: np.ndarray
    """The points' costs (+inf where the budget left one unevaluated): NaN until
    :func:`~.cma_es.cma_tell` writes them into this array, made for them by :func:`sample`;
    empty before the first generation and once learned from."""


class Progress(NamedTuple):
    """A run's counters, its TolFun history and why it stopped."""

    generation: int
    """Updates done in this run."""
    run_evaluations: int
    """Evaluations learned from in this run."""
    eigen_evaluations: int
    """Run evaluations at the last eigendecomposition."""
    history: np.ndarray
    """Best cost of each recent generation, newest first, nan until filled."""
    stop: int
    """Stop code (0: running; see :data:`STOP_NAMES`)."""
    stopped_at: int
    """The iteration whose update stopped the run (not done: it samples nothing), else 0."""


class Workspace(NamedTuple):
    """Scratch of a run's update, kept between generations so that none allocates. Two arrays
    rather than one per use: every array of a run's state costs reference counting each
    time a kernel hands the state on."""

    order: np.ndarray
    """The ranking of the last generation, best first, shape (lambda,) of integers."""
    floats: np.ndarray
    """``<y>_w`` (n), the rank-mu weights times ``c_mu`` (lambda), C scaled for the
    eigendecomposition (n^2), its eigenvalues (n) and the eigensolver's scratch (n): see
    :func:`scratch_of`."""


@njit(cache=True, inline="always")
def scratch_of(work, n, lam):  # type: ignore[no-untyped-def]
    """The views of ``work.floats``: ``(y_w, scaled, matrix, values, eigen_work)``."""
    f = work.floats
    y_w, scaled = f[:n], f[n : n + lam]
    matrix = f[n + lam : n + lam + n * n].reshape(n, n)
    values = f[n + lam + n * n : 2 * n + lam + n * n]
    return y_w, scaled, matrix, values, f[2 * n + lam + n * n :]


class CMARun(NamedTuple):
    """One run between generations: its arrays are advanced in place, its scalars replaced."""

    distribution: Distribution
    samples: Samples
    progress: Progress
    strategy: CMAParameters
    """The run's strategy constants (they depend on its lambda)."""
    work: Workspace


def new_run(mean: np.ndarray, sigma0: float, strategy: CMAParameters, transform: bool) -> CMARun:
    """A run before its first generation: C = I, zero paths, centred on ``mean``.

    With the BoundTransform the mean is the inverse image of ``mean`` (as pycma starts from
    ``inverse(x0)``), so that the transform maps the first mean onto it.
    """
    n, lam = mean.shape[0], strategy.weights.shape[0]
    if transform:
        mean = linquad_inverse(mean, np.zeros(n), np.ones(n))
    eye = np.eye(n)
    distribution = Distribution(
        np.array(mean, dtype=np.float64), float(sigma0), eye.copy(), eye.copy(), np.ones(n),
        eye.copy(), np.zeros(n), np.zeros(n),
    )  # fmt: skip
    samples = Samples(np.zeros((lam, n)), np.zeros((lam, n)), np.zeros(lam), np.full(lam, np.nan))
    progress = Progress(0, 0, 0, np.full(strategy.history, np.nan), RUNNING, 0)
    work = Workspace(np.zeros(lam, dtype=np.int64), np.zeros(3 * n + lam + n * n))
    return CMARun(distribution, samples, progress, strategy, work)


@njit(cache=True)
def owned(run):  # type: ignore[no-untyped-def]
    """A copy of ``run`` whose arrays :func:`learn` and :func:`sample` may advance in place
    (its constants and scratch are shared)."""
    d, s, p = run.distribution, run.samples, run.progress
    distribution = Distribution(d.mean.copy(), d.sigma, d.cov.copy(), d.eigenvectors.copy(),
                                d.axes.copy(), d.inv_sqrt.copy(), d.path_sigma.copy(),
                                d.path_c.copy())  # fmt: skip
    samples = Samples(s.points.copy(), s.steps.copy(), s.lengths.copy(), s.costs.copy())
    progress = Progress(p.generation, p.run_evaluations, p.eigen_evaluations, p.history.copy(),
                        p.stop, p.stopped_at)  # fmt: skip
    return CMARun(distribution, samples, progress, run.strategy, run.work)


@njit(cache=True, inline="always")
def told(samples):  # type: ignore[no-untyped-def]
    """Whether ``samples`` have costs not yet learned from (a cost is never NaN once told)."""
    return not math.isnan(samples.costs[0])


# --- the update ---------------------------------------------------------------------------------


@njit(cache=True)
def ranking(costs: np.ndarray, order: np.ndarray) -> np.ndarray:
    """Indices of ``costs`` from best to worst into ``order``, ties in index order (insertion
    sort: small)."""
    m = costs.shape[0]
    for k in range(m):
        v = costs[k]
        j = k
        while j > 0 and costs[order[j - 1]] > v:
            order[j] = order[j - 1]
            j -= 1
        order[j] = k
    return order


@njit(cache=True)
def learn(run, settings, plan, iteration):  # type: ignore[no-untyped-def]
    """``run`` after the update from its told samples' costs: :func:`update_distribution`,
    the eigendecomposition when it is due, the TolFun history and the stop check
    (:func:`stop_code`, with the initial step size and evaluation allowance of ``plan``).

    ``settings`` are the kernel settings of :mod:`.cma_es`. The run's arrays are advanced in
    place (see the module docstring); its samples are marked learned from (:func:`told`). A
    run that stops records ``iteration`` as ``stopped_at``.
    """
    samples, progress, strategy, work = run.samples, run.progress, run.strategy, run.work
    costs = samples.costs
    lam = costs.shape[0]
    order = ranking(costs, work.order)
    sigma = update_distribution(
        run.distribution, strategy, samples, order, progress.generation,
        settings.constants == CMAConstants.PYCMA, work,
    )  # fmt: skip
    d = run.distribution
    distribution = Distribution(d.mean, sigma, d.cov, d.eigenvectors, d.axes, d.inv_sqrt,
                                d.path_sigma, d.path_c)  # fmt: skip
    history = progress.history
    for k in range(history.shape[0] - 1, 0, -1):
        history[k] = history[k - 1]
    history[0] = costs[order[0]]
    run_evaluations = progress.run_evaluations + lam
    eigen_evaluations = progress.eigen_evaluations
    condition = 1.0
    if run_evaluations - eigen_evaluations > strategy.eigen_gap:
        condition = refresh(distribution, work)
        eigen_evaluations = run_evaluations
    progress = Progress(progress.generation + 1, run_evaluations, eigen_evaluations, history,
                        RUNNING, 0)  # fmt: skip
    stop = stop_code(distribution, progress, costs, condition, settings, plan)
    if stop != RUNNING:
        progress = Progress(progress.generation, run_evaluations, eigen_evaluations, history,
                            stop, iteration)  # fmt: skip
    costs[0] = math.nan  # learned from
    return CMARun(distribution, samples, progress, strategy, work)


@njit(cache=True)
def update_distribution(distribution, strategy, samples, order, generation, pycma_test, work):  # type: ignore[no-untyped-def]
    """The tutorial's update (Fig. 6, c_m = 1) of mean, paths and C, in place, and the new
    sigma (returned; the eigensystem is still the old one).

    ``<y>_w`` comes from the mu best steps (``order`` ranks the samples, best first);
    cumulative step-size adaptation with ``C^(-1/2)`` of the last eigendecomposition;
    ``h_sigma`` stalls the rank-one path after a long step (the tutorial's test
    ``||p_sigma|| / sqrt(1 - (1 - c_sigma)^(2(g+1))) < (1.4 + 2 / (n + 1)) E||N(0, I)||`` or,
    with ``pycma_test``, pycma's ``||p_sigma||^2 / (1 - (1 - c_sigma)^(2(g+1))) / n - 1 < 1 +
    4 / (n + 1)``); the rank-one and rank-mu updates of C, a negative weight scaled by ``n /
    ||C^(-1/2) y||^2``. ``work`` is the run's :class:`Workspace`.
    """
    steps, lengths = samples.steps, samples.lengths
    s = strategy
    weights = s.weights
    lam, n = steps.shape
    sigma = distribution.sigma
    inv_sqrt = distribution.inv_sqrt
    c_sigma, c_c, c_1, c_mu = s.c_sigma, s.c_c, s.c_1, s.c_mu
    y_w, scaled, _, _, _ = scratch_of(work, n, lam)
    d = distribution
    mean, ps, pc, cov = d.mean, d.path_sigma, d.path_c, d.cov

    y_w[:] = 0.0
    for r in range(s.mu):
        k = order[r]
        for i in range(n):
            y_w[i] += weights[r] * steps[k, i]
    for i in range(n):
        mean[i] += sigma * y_w[i]

    ps_factor = math.sqrt(c_sigma * (2.0 - c_sigma) * s.mueff)
    ps_norm2 = 0.0
    for i in range(n):
        total = 0.0
        for j in range(n):
            total += inv_sqrt[i, j] * y_w[j]
        ps[i] = (1.0 - c_sigma) * ps[i] + ps_factor * total
        ps_norm2 += ps[i] * ps[i]
    ps_norm = math.sqrt(ps_norm2)
    # p_sigma starts at zero, so its expected length grows to the stationary one only
    # after some generations: both tests divide the bias out
    bias = 1.0 - (1.0 - c_sigma) ** (2.0 * (generation + 1.0))
    if pycma_test:  # pycma compares the squared length, E||N(0, I)||^2 = n
        short = ps_norm2 / bias / n - 1.0 < 1.0 + 4.0 / (n + 1.0)
    else:
        short = ps_norm / math.sqrt(bias) < (1.4 + 2.0 / (n + 1.0)) * s.chi_n
    h_sigma = 1.0 if short else 0.0
    pc_factor = h_sigma * math.sqrt(c_c * (2.0 - c_c) * s.mueff)
    for i in range(n):
        pc[i] = (1.0 - c_c) * pc[i] + pc_factor * y_w[i]

    # w° of the tutorial: a negative weight is scaled by n / ||C^(-1/2) y||^2, so that
    # a long unlucky step cannot remove more variance than a typical one
    # (the squared lengths were kept by sample(): see there)
    weight_sum = 0.0
    for r in range(lam):
        w = weights[r]
        weight_sum += w
        if w < 0.0:
            w = w * n / max(lengths[order[r]], 1e-300)
        scaled[r] = c_mu * w
    delta_h = (1.0 - h_sigma) * c_c * (2.0 - c_c)
    decay = 1.0 + c_1 * delta_h - c_1 - c_mu * weight_sum
    # in place: entry (i, j >= i) reads only itself, and the mirrored (j, i) is never read
    for i in range(n):
        for j in range(i, n):
            value = decay * cov[i, j] + c_1 * pc[i] * pc[j]
            for r in range(lam):
                y = steps[order[r]]
                value += scaled[r] * y[i] * y[j]
            cov[i, j] = value
            cov[j, i] = value

    return sigma * math.exp((c_sigma / s.d_sigma) * (ps_norm / s.chi_n - 1.0))


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
def refresh(distribution, work):  # type: ignore[no-untyped-def]
    """B, D and C^(-1/2) of ``distribution``'s C, written into its arrays; returns cond(C).

    C is scaled by its largest diagonal entry first, so that no square in the QL iteration
    (:func:`~.cma_eigen.eigen_into`) overflows or underflows. Eigenvalues are floored at
    1e-20 times the largest, so a rounding error cannot make an axis length imaginary; the
    condition is taken before the floor. When C is not finite or its diagonal not positive,
    the eigensystem is kept and the condition is ``inf`` (which stops the run). ``work`` is
    the run's :class:`Workspace`.
    """
    d = distribution
    cov = d.cov
    n = cov.shape[0]
    scale = 0.0
    for i in range(n):
        scale = max(scale, cov[i, i])
    if not (scale > 0.0 and math.isfinite(scale)):
        return math.inf
    for i in range(n):
        for j in range(n):
            if not math.isfinite(cov[i, j]):
                return math.inf
    _, _, matrix, values, eigen_work = scratch_of(work, n, work.order.shape[0])
    rows, axes, inv_sqrt = d.eigenvectors, d.axes, d.inv_sqrt
    for i in range(n):
        for j in range(n):
            matrix[i, j] = cov[i, j] / scale
    eigen_into(matrix, values, eigen_work, rows)
    largest, smallest = -math.inf, math.inf
    for k in range(n):
        largest = max(largest, values[k])
        smallest = min(smallest, values[k])
    condition = largest / smallest if smallest > 0.0 else math.inf
    floor = max(largest, 1e-300) * 1e-20
    for k in range(n):
        axes[k] = math.sqrt(max(values[k], floor) * scale)
    inv_sqrt[:] = 0.0
    for k in range(n):
        scale_k = 1.0 / axes[k]
        for i in range(n):
            a = rows[k, i] * scale_k
            for j in range(n):
                inv_sqrt[i, j] += a * rows[k, j]
    return condition


@njit(cache=True)
def stop_code(distribution, progress, costs, condition, settings, plan):  # type: ignore[no-untyped-def]
    """Which stop criterion of the tutorial's appendix B.3 the updated run meets (0: none).

    ``plan`` gives the run's initial step size and evaluation allowance. TolFun applies once
    the history is full; TolX is relative to the run's initial sigma. Checked in the order of
    :data:`STOP_NAMES`, the run's evaluation allowance last.
    """
    sigma0, limit = plan.sigma0, plan.limit
    d = distribution
    mean, pc, axes, cov, rows, sigma = d.mean, d.path_c, d.axes, d.cov, d.eigenvectors, d.sigma
    n = mean.shape[0]

    full = True
    low, high = math.inf, -math.inf
    for v in progress.history:
        if math.isnan(v):
            full = False
            break
        low, high = min(low, v), max(high, v)
    if full:
        for v in costs:
            low, high = min(low, v), max(high, v)
        if high - low < settings.tol_fun:  # False for infinite costs: inf - inf is nan
            return TOL_FUN_STOP

    tol_x = settings.tol_x * sigma0
    small = True
    for i in range(n):
        if sigma * math.sqrt(max(cov[i, i], 0.0)) >= tol_x or sigma * abs(pc[i]) >= tol_x:
            small = False
            break
    if small:
        return TOL_X_STOP

    axis = progress.generation % n
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
    if progress.run_evaluations >= limit:
        return RUN_BUDGET
    return RUNNING


# --- sampling -----------------------------------------------------------------------------------


@njit(cache=True)
def sample(distribution, normals, uniforms, settings, samples):  # type: ignore[no-untyped-def]
    """lambda samples ``m + sigma B (D * z)``, ``z`` the rows of ``normals`` (lambda x n),
    written into ``samples`` (costs NaN until told), their points in box coordinates.

    The ``bound_handling`` of ``settings`` (a :class:`CMABoundHandling` value) brings the
    samples into [0, 1]^n: a repair of those outside (``uniforms``, shaped like ``normals``,
    are read only by RESAMPLE), or pycma's BoundTransform of all of them (the identity but
    for the margin along each face); the repaired or mapped point is the one evaluated. The
    step the next update learns from is the sampled one (the search minimises
    ``f(repair(x))``, as pycma does with its BoundTransform), or, with ``lamarckian``, the
    evaluated point's ``(u_repaired - m) / sigma``, shortened to the Mahalanobis length
    :func:`injection_cap` (the settings' ``cap``) if longer. Points are mapped to the box as
    ``lower + width u`` and clipped, so that rounding cannot leave it.
    """
    d = distribution
    mean, axes, rows, sigma = d.mean, d.axes, d.eigenvectors, d.sigma
    lam, n = normals.shape
    steps, points, lengths, costs = samples.steps, samples.points, samples.lengths, samples.costs
    costs[:] = math.nan
    steps[:] = 0.0
    # ||C^(-1/2) y|| = ||B D^(-1) B^T B D z|| = ||z||: the update's next C^(-1/2) is the one
    # of this B and D (the eigensystem is refreshed only after an update), so a sampled
    # step's Mahalanobis length is that of its normals, n operations instead of n^2
    for s in range(lam):
        y = steps[s]
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
    # repaired or mapped in place, still in [0, 1] coordinates
    if settings.bound_handling == CMABoundHandling.TRANSFORM:
        linquad_transform_inplace(points, settings.unit_lower, settings.unit_upper)
    else:
        apply_bounds_inplace(points, settings.unit_lower, settings.unit_upper,
                             settings.bound_handling, uniforms)  # fmt: skip
    if settings.lamarckian:
        cap = settings.cap
        for s in range(lam):
            y = steps[s]
            for i in range(n):
                if points[s, i] != mean[i] + sigma * y[i]:  # moved by the repair
                    for j in range(n):
                        y[j] = (points[s, j] - mean[j]) / sigma
                    length = mahalanobis(d.inv_sqrt, y)
                    if length > cap:
                        for j in range(n):
                            y[j] *= cap / length
                        length = cap
                    lengths[s] = length * length
                    break
    lower, width, upper = settings.lower, settings.width, settings.upper
    for s in range(lam):
        for i in range(n):
            points[s, i] = min(max(lower[i] + width[i] * points[s, i], lower[i]), upper[i])
    return samples
