"""The modified BSO's iteration as compiled kernels (driven by :mod:`.modified_bso`).

One iteration of :class:`~formation_bench.optimizers.modified_bso.ModifiedBSO` is one call of
:func:`modified_bso_iteration` besides the objective calls: at a population of
30 a Python-level call into a kernel costs about as much as its arithmetic, so
the selection of the previous ideas, the k-means step, the centre replacement
and the new ideas are fused. Like :mod:`formation_bench.optimizers.bso_ops`, the kernels are
pure: random numbers come in as arrays and inputs are never modified.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from formation_bench.optimizers.bso_ops import (
    SHI_UNIFORMS_PER_IDEA,
    cluster_population,
    generate_ideas,
    greedy_select,
    install_best,
    logsig_factor,
    random_centre,
)


class KernelSettings(NamedTuple):
    """The kernels' arguments that stay fixed during a solve, in their order.

    Built once per solve (:meth:`ModifiedBSO.kernel_settings`) and passed as
    ``*settings``: a tuple argument would go through numba's slow type
    inference at every call, separate scalars through its fast path.
    """

    t_max: int
    """Planned iterations: T_max of the logsig schedule."""
    slope: float
    """k, slope of the logsig schedule."""
    n_clusters: int
    """m, k-means clusters."""
    kmeans_max_iter: int
    """Cap on Lloyd iterations."""
    all_centre: bool
    """All-centre weighting (eqs. 8-9), else Shi's idea selection."""
    weight_map: int
    """f_hmap as a :class:`~formation_bench.optimizers.chaos.ChaoticMap` value."""
    n_weight_iterations: int
    """n_h."""
    normalise: bool
    """Normalise each idea's weights to sum to one."""
    p_one_cluster: float
    """Shi's p_6b."""
    p_one_centre: float
    """Shi's p_6biii."""
    p_two_centres: float
    """Shi's p_6c."""
    scale: np.ndarray
    """Per-coordinate multiplier of the eq. (10) step, shape (D,)."""
    lower: np.ndarray
    """Lower bounds (a private writable copy: numba compiles read-only arrays separately)."""
    upper: np.ndarray
    """Upper bounds (same reason)."""
    bound_mode: int
    """A :class:`~formation_bench.optimizers.bound_handling.BoundHandling` value."""


@njit(cache=True)
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
    t_max: int,
    slope: float,
    n_clusters: int,
    kmeans_max_iter: int,
    all_centre: bool,
    weight_map: int,
    n_weight_iterations: int,
    normalise: bool,
    p_one_cluster: float,
    p_one_centre: float,
    p_two_centres: float,
    scale: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    bound_mode: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One iteration after the clustering: ``(x, f, ideas)``.

    With ``replace``, the best of the evaluated chaotic ``candidates`` takes
    the place of a random centre (eq. 7); then the N ideas of eqs. (8)-(10)
    (or Shi's selection when not ``all_centre``) are made from the clusters,
    with the logsig factor of ``iteration`` out of ``t_max``. ``u`` is the
    iteration's uniforms in the layout of :meth:`ModifiedBSO.step`;
    ``candidates`` and ``candidate_costs`` are read only with ``replace``.
    The arguments from ``t_max`` on are the fields of :class:`KernelSettings`
    (``kmeans_max_iter`` is unused here).
    """
    n, d = x.shape
    m = n_clusters
    width = m if all_centre else SHI_UNIFORMS_PER_IDEA
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
        all_centre,
        weight_map,
        n_weight_iterations,
        normalise,
        p_one_cluster,
        p_one_centre,
        p_two_centres,
        logsig_factor(iteration, t_max, slope),
        u[rand_at:resample_at],
        normals,
        scale,
        lower,
        upper,
        bound_mode,
        resample,
    )
    return x, f, ideas


@njit(cache=True)
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
    t_max: int,
    slope: float,
    n_clusters: int,
    kmeans_max_iter: int,
    all_centre: bool,
    weight_map: int,
    n_weight_iterations: int,
    normalise: bool,
    p_one_cluster: float,
    p_one_centre: float,
    p_two_centres: float,
    scale: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    bound_mode: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A whole iteration except the evaluations, in one call: ``(x, f, ideas)``.

    The slot-wise selection of the last ``ideas`` over ``(x, f)``, the k-means
    step (from ``n_clusters`` distinct members drawn with the first
    ``n_clusters`` entries of ``u``), then :func:`ideas_from_clusters`, whose
    arguments these are.
    """
    x, f, _ = greedy_select(x, f, ideas, idea_costs)
    labels, centre_index, sizes = cluster_population(x, f, u[:n_clusters], kmeans_max_iter)
    return ideas_from_clusters(
        x, f, labels, centre_index, sizes, u, normals, replace, candidates, candidate_costs,
        iteration, t_max, slope, n_clusters, kmeans_max_iter, all_centre, weight_map,
        n_weight_iterations, normalise, p_one_cluster, p_one_centre, p_two_centres, scale, lower,
        upper, bound_mode,
    )  # fmt: skip
