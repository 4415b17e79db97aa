"""The modified BSO's iteration as compiled kernels (driven by :mod:`.modified_bso`).

One iteration of :class:`~formation_bench.optimizers.modified_bso.ModifiedBSO` is one call of
:func:`modified_bso_iteration` besides the objective calls: at a population of
30 a Python-level call into a kernel costs about as much as its arithmetic, so
the selection of the previous ideas, the k-means step, the centre replacement
and the new ideas are fused. Like :mod:`formation_bench.optimizers.bso_ops`, the kernels are
pure: random numbers come in as arrays and inputs are never modified.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from formation_bench.fields import Validated, kernel_settings_class, setting
from formation_bench.optimizers.bound_handling import BoundHandling
from formation_bench.optimizers.bso_ops import (
    SHI_UNIFORMS_PER_IDEA,
    chaotic_candidates,
    cluster_population,
    generate_ideas,
    install_best,
    logsig_factor,
    random_centre,
)
from formation_bench.optimizers.chaos import ChaoticMap
from formation_bench.optimizers.clustering import DEFAULT_MAX_ITER, ClusteringBackend
from formation_bench.optimizers.compiled import NFEV, evaluate, evaluate_prefix, remaining
from formation_bench.optimizers.original_bso_kernels import PER_SOLVE
from formation_bench.optimizers.population import greedy_select


@dataclass(frozen=True)
class ModifiedBSOConfig(Validated):
    """The settings of :class:`~formation_bench.optimizers.modified_bso.ModifiedBSO`, declared once.

    Declared next to the kernels that read them: the fields marked
    ``kernel=True`` make :class:`KernelSettings`, which the kernels rebuild and
    read by name (numba's cache is invalidated when this file changes).
    """

    population_size: int = setting(30, low=2, doc="N, ideas per iteration")
    n_clusters: int = setting(
        5, low=1, high="population_size", kernel=True, doc="m, k-means clusters"
    )
    max_iterations: int = setting(
        40, low=0, doc="T_max when the caller gives no budget; the default budget"
    )
    slope: float = setting(
        20.0, low=0.0, low_open=True, kernel=True,
        doc="k, slope of the logsig step-size schedule of eq. (10)",
    )  # fmt: skip
    p_replace: float = setting(
        0.2, low=0.0, high=1.0,
        doc="p_r, probability per iteration of a chaotic centre replacement",
    )  # fmt: skip
    n_replace: int = setting(10, low=1, doc="n_r, chaotic candidates per replacement")
    n_weight_iterations: int = setting(
        10, low=0, kernel=True,
        doc="n_h, iterations of the weight map from the random seed ch(0)",
    )  # fmt: skip
    replacement_map: ChaoticMap = setting(
        ChaoticMap.LOGISTIC, doc="f_rmap, chaotic map of the replacement candidates (eq. 6)"
    )
    weight_map: ChaoticMap = setting(
        ChaoticMap.LOGISTIC, kernel=True, doc="f_hmap, chaotic map of the centre weights (eq. 8)"
    )
    normalise_weights: bool = setting(
        True, kernel=True,
        doc="Scale each idea's weights to sum to one (False: the raw weights printed in eq. 9)",
    )  # fmt: skip
    step_scale: float = setting(
        0.1, low=0.0, low_open=True, doc="Multiplier of the N(0, 1) step of eq. (10)"
    )
    step_relative_to_range: bool = setting(
        True, doc="Multiply step_scale by each coordinate's range upper - lower"
    )
    bound_handling: BoundHandling = setting(
        BoundHandling.CLIP, kernel=True, doc="How ideas outside the bounds are brought back"
    )
    clustering: ClusteringBackend = setting(
        ClusteringBackend.COMPILED, doc="k-means implementation"
    )
    kmeans_max_iter: int = setting(
        DEFAULT_MAX_ITER, low=1, kernel=True, doc="Cap on Lloyd iterations per clustering"
    )
    p_one_cluster: float = setting(
        0.8, low=0.0, high=1.0, kernel=True,
        doc="Shi's p_6b: idea from one cluster rather than two (all-centre weighting off)",
    )  # fmt: skip
    p_one_centre: float = setting(
        0.4, low=0.0, high=1.0, kernel=True,
        doc="Shi's p_6biii: one-cluster idea is the centre, else a random member",
    )  # fmt: skip
    p_two_centres: float = setting(
        0.5, low=0.0, high=1.0, kernel=True,
        doc="Shi's p_6c: two-cluster idea mixes the centres, else random members",
    )  # fmt: skip
    chaos_replacement: bool = setting(
        True, doc="Ablation switch: chaotic centre replacement (eqs. 6-7)"
    )
    all_centre_weighting: bool = setting(
        True, kernel=True,
        doc="Ablation switch: all-centre auxiliary solutions (eqs. 8-9), else Shi's selection",
    )  # fmt: skip


KernelSettings = kernel_settings_class(
    "KernelSettings",
    __name__,
    ModifiedBSOConfig,
    PER_SOLVE,
    """What the kernels read, fixed during a solve: the kernel fields of
    :class:`ModifiedBSOConfig` (enums as integers), then T_max, the per-coordinate multiplier of
    the eq. (10) step and the bounds (private writable copies: numba compiles read-only arrays
    separately).""",
)


# inline: a thin layer. Every compiled call boundary re-optimises the whole callee tree
# below it when the caller is built, so thin layers cost cold-start seconds; see docs/design.md
@njit(cache=True, inline="always")
def ideas_from_clusters(
    x: np.ndarray,
    f: np.ndarray,
    labels: np.ndarray,
    centre_index: np.ndarray,
    sizes: np.ndarray,
    u: np.ndarray,
    normals: np.ndarray,
    replace: bool,
    candidates: np.ndarray,
    candidate_costs: np.ndarray,
    iteration: int,
    packed: tuple,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One iteration after the clustering: ``(x, f, ideas)``.

    With ``replace``, the best of the evaluated chaotic ``candidates`` takes
    the place of a random centre (eq. 7); then the N ideas of eqs. (8)-(10)
    (or Shi's selection when all-centre weighting is off) are made from the
    clusters, with the logsig factor of ``iteration`` out of T_max. ``u`` is the
    iteration's uniforms in the layout of :meth:`ModifiedBSO.step`;
    ``candidates`` and ``candidate_costs`` are read only with ``replace``.
    ``packed`` is :meth:`ModifiedBSO.kernel_settings`.
    """
    s = KernelSettings(*packed)
    n, d = x.shape
    m = s.n_clusters
    width = m if s.all_centre_weighting else SHI_UNIFORMS_PER_IDEA
    ideas_at = m + 2 + d
    rand_at = ideas_at + n * width
    resample_at = rand_at + n
    if replace:
        slot = random_centre(centre_index, u[m + 1])
        x, f = install_best(x, f, slot, candidates, candidate_costs)
    resample = u[resample_at:].reshape(n, d) if u.shape[0] > resample_at else normals
    ideas = generate_ideas(
        x,
        labels,
        centre_index,
        sizes,
        u[ideas_at:rand_at].reshape(n, width),
        all_centre_weighting=s.all_centre_weighting,
        weight_map=s.weight_map,
        n_weight_iterations=s.n_weight_iterations,
        normalise_weights=s.normalise_weights,
        p_one_cluster=s.p_one_cluster,
        p_one_centre=s.p_one_centre,
        p_two_centres=s.p_two_centres,
        factor=logsig_factor(iteration, t_max=s.t_max, slope=s.slope),
        rand=u[rand_at:resample_at],
        normals=normals,
        scale=s.scale,
        lower=s.lower,
        upper=s.upper,
        bound_handling=s.bound_handling,
        resample_uniforms=resample,
    )
    return x, f, ideas


# inline: the compiled solve loop (modified_bso_block) is its usual caller, and a run that
# solves only through that loop then never builds this kernel on its own
@njit(cache=True, inline="always")
def modified_bso_iteration(
    x: np.ndarray,
    f: np.ndarray,
    ideas: np.ndarray,
    idea_costs: np.ndarray,
    u: np.ndarray,
    normals: np.ndarray,
    replace: bool,
    candidates: np.ndarray,
    candidate_costs: np.ndarray,
    iteration: int,
    packed: tuple,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A whole iteration except the evaluations, in one call: ``(x, f, ideas)``.

    The slot-wise selection of the last ``ideas`` over ``(x, f)``, the k-means
    step (from ``n_clusters`` distinct members drawn with the first
    ``n_clusters`` entries of ``u``), then :func:`ideas_from_clusters`, whose
    arguments these are.
    """
    s = KernelSettings(*packed)
    x, f, _ = greedy_select(x, f, ideas, idea_costs)
    labels, centre_index, sizes = cluster_population(
        x, f, u[: s.n_clusters], kmeans_max_iter=s.kmeans_max_iter
    )
    return ideas_from_clusters(
        x, f, labels, centre_index, sizes, u, normals, replace, candidates, candidate_costs,
        iteration, packed,
    )  # fmt: skip


@njit(cache=True)
def modified_bso_block(
    address: int,
    data: np.ndarray,
    counts: np.ndarray,
    best: np.ndarray,
    x: np.ndarray,
    f: np.ndarray,
    ideas: np.ndarray,
    idea_costs: np.ndarray,
    uniforms: np.ndarray,
    normals: np.ndarray,
    nit: int,
    first_iteration: int,
    iteration_limit: int,
    replacement: tuple,
    packed: tuple,
    history_nfev: np.ndarray,
    history_fun: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int]:
    """Iterations ``nit + 1``, ... of a compiled solve, one per row of the random block.

    Each is :meth:`ModifiedBSO.step` with the objective called through ``address``/``data``
    (see :mod:`~formation_bench.optimizers.compiled`); the block stops early at the iteration
    limit or when no evaluation is left. ``replacement`` is ``(chaos_replacement, p_replace,
    n_replace, replacement_map)``. Returns ``(x, f, ideas, idea_costs, iterations done,
    replacements)``; the history arrays get one entry per iteration done.
    """
    chaos_replacement, p_replace, n_replace, replacement_map = replacement
    s = KernelSettings(*packed)
    m = s.n_clusters
    d = x.shape[1]
    done = 0
    replacements = 0
    row = nit + 1 - first_iteration
    while nit < iteration_limit and row < uniforms.shape[0] and remaining(counts) > 0:
        nit += 1
        u = uniforms[row]
        replace = chaos_replacement and u[m] < p_replace and remaining(counts) >= n_replace
        if replace:
            candidates = chaotic_candidates(
                replacement_map, u[m + 2 : m + 2 + d], n_replace, s.lower, s.upper
            )
            candidate_costs = evaluate(address, data, candidates, n_replace, counts, best)
            replacements += 1
        else:
            candidates, candidate_costs = x, f
        x, f, ideas = modified_bso_iteration(
            x, f, ideas, idea_costs, u, normals[row], replace, candidates, candidate_costs,
            nit, packed,
        )  # fmt: skip
        idea_costs = evaluate_prefix(address, data, ideas, counts, best)
        history_nfev[done] = counts[NFEV]
        history_fun[done] = best[0]
        done += 1
        row += 1
    return x, f, ideas, idea_costs, done, replacements
