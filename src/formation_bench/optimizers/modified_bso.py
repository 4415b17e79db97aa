"""The paper's modified Brain Storm Optimization (section 2.3), with its ablations.

Per iteration: k-means of the population into ``m`` clusters (initial centres
are ``m`` distinct members drawn at random); the best member of each cluster
is its centre; with probability ``p_r`` a random centre is replaced by the
best of ``n_r`` chaotic points (eqs. 6-7); every one of the ``N`` slots gets
a new idea from a chaotic weighting of all centres (eqs. 8-9, eq. 8 corrected as
described in docs/explanation/paper.md) moved by the logsig step of eq. (10), which
replaces the slot's member only when strictly better.

Switching off ``all_centre_weighting`` uses Shi's (2011) idea selection
instead; switching off ``chaos_replacement`` drops the replacement. With both
off the algorithm is Shi's BSO without its random-point centre replacement.

The paper starts from N uniform points with the warm start as one of them, and so does
``modified-bso``. ``modified-bso-warm``, not part of the paper, draws a share of them around
the warm start (:class:`~formation_bench.optimizers.population.WarmStartInit`).

The iteration is written once, as the ask/tell kernels of
:mod:`~formation_bench.optimizers.modified_bso_kernels`, which both solve loops of
:mod:`~formation_bench.optimizers.ask_tell` drive, with the random numbers drawn ahead
(:func:`~formation_bench.optimizers.population.iteration_randoms`). The scikit-learn k-means
(``clustering = "sklearn"``, the reference the compiled k-means is checked against) runs in
Python before each ask and hands its labels to the same ask kernel (:func:`sklearn_ask`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from formation_bench.fields import pack_settings
from formation_bench.optimizers.ask_tell import AskTellOptimizer, DrawPlan, Kernels
from formation_bench.optimizers.base import Bounds
from formation_bench.optimizers.bound_handling import BoundHandling
from formation_bench.optimizers.bso_ops import (
    SHI_UNIFORMS_PER_IDEA,
    distinct_indices,
    uniforms_per_iteration,
)
from formation_bench.optimizers.chaos import ChaoticMap
from formation_bench.optimizers.clustering import ClusteringBackend, sklearn_kmeans
from formation_bench.optimizers.modified_bso_kernels import (
    STARTING,
    KernelSettings,
    ModifiedBSOConfig,
    ModifiedBSOState,
    modified_bso_ask,
    modified_bso_iterate,
    modified_bso_tell,
)
from formation_bench.optimizers.population import WarmStartInit, step_scale
from formation_bench.optimizers.registry import register


def sklearn_ask(
    state: ModifiedBSOState,
    params: tuple,
    uniforms: np.ndarray,
    normals: np.ndarray,
    iteration: int,
    remaining: int,
) -> tuple[ModifiedBSOState, np.ndarray, bool]:
    """:func:`~formation_bench.optimizers.modified_bso_kernels.modified_bso_ask` on the labels of
    scikit-learn's k-means, from the initial centres the compiled k-means would take."""
    s = KernelSettings(*params)
    x = state.x
    initial = x[distinct_indices(uniforms[: s.n_clusters], x.shape[0])]
    labels, _ = sklearn_kmeans(x, initial, s.kmeans_max_iter)
    return modified_bso_ask(
        state._replace(labels=labels), params, uniforms, normals, iteration, remaining
    )


# WarmStartInit leads the bases because dataclass fields follow the reversed MRO: its settings
# then come after the method's own, whose positions and listing order stay as they were
@dataclass(frozen=True)
class ModifiedBSO(WarmStartInit, ModifiedBSOConfig, AskTellOptimizer):
    """The paper's modified BSO; the settings are those of
    :class:`~formation_bench.optimizers.modified_bso_kernels.ModifiedBSOConfig` and, for the
    initial population, :class:`~formation_bench.optimizers.population.WarmStartInit`."""

    compile_cpu_s = 17.0

    @property
    def kernels(self) -> Kernels:  # type: ignore[override]
        if self.clustering is ClusteringBackend.SKLEARN:
            return Kernels(sklearn_ask, modified_bso_tell, None)
        return Kernels(modified_bso_ask, modified_bso_tell, modified_bso_iterate)

    def evaluations_per_step(self) -> int:
        """N, plus the expected replacement evaluations ``round(p_r * n_r)`` when enabled.

        Counting the replacements' expected cost makes the planned T_max (and
        so the logsig schedule) match the iterations an evaluation budget
        actually allows.
        """
        extra = round(self.p_replace * self.n_replace) if self.chaos_replacement else 0
        return self.population_size + int(extra)

    def initial_evaluations(self) -> int:
        return self.population_size

    def params(self, bounds: Bounds, t_max: int) -> tuple:
        return pack_settings(
            KernelSettings, self, t_max=int(t_max),
            scale=step_scale(bounds, self.step_scale, self.step_relative_to_range),
            lower=np.array(bounds.lower), upper=np.array(bounds.upper),
        )  # fmt: skip

    def start(
        self, points: np.ndarray, costs: np.ndarray, rng: np.random.Generator, params: tuple
    ) -> ModifiedBSOState:
        d = points.shape[1]
        return ModifiedBSOState(points, costs, STARTING, np.empty((0, d)), np.empty(0),
                                np.empty(0, dtype=np.int64), 0)  # fmt: skip

    def draw_plan(self, n: int, d: int) -> DrawPlan:
        width = self.n_clusters if self.all_centre_weighting else SHI_UNIFORMS_PER_IDEA
        resample = self.bound_handling is BoundHandling.RESAMPLE
        return DrawPlan(uniforms_per_iteration(n, d, self.n_clusters, width, resample), (n, d))

    def result_info(self, state: ModifiedBSOState) -> dict[str, Any]:
        return {"chaotic_replacements": state.replacements}

    def has_compiled_loop(self) -> bool:
        return self.clustering is ClusteringBackend.COMPILED


WARM_START_SHARE = 0.9
"""``warm_start_share`` of ``modified-bso-warm``: chosen with the spread on the instance
library's validation split (docs/explanation/optimizers.md, "Initial population around the
warm start")."""
WARM_START_SPREAD = 0.005
"""``warm_start_spread`` of ``modified-bso-warm``, chosen with the share."""

register(
    "modified-bso",
    ModifiedBSO(),
    "Modified BSO of the paper: chaotic centre replacement + chaotic all-centre weighting",
)
register(
    "modified-bso-warm",
    ModifiedBSO(warm_start_share=WARM_START_SHARE, warm_start_spread=WARM_START_SPREAD),
    f"modified-bso with {WARM_START_SHARE:.0%} of the initial population drawn around the "
    f"warm start (std {WARM_START_SPREAD:g} x range), the rest uniform; not the paper's start",
)
register(
    "modified-bso-no-chaos-replacement",
    ModifiedBSO(chaos_replacement=False),
    "Modified BSO ablation: without the chaotic centre replacement (eqs. 6-7)",
)
register(
    "modified-bso-no-all-centre",
    ModifiedBSO(all_centre_weighting=False),
    "Modified BSO ablation: Shi's idea selection instead of all-centre weighting (eqs. 8-9)",
)
register(
    "modified-bso-no-modifications",
    ModifiedBSO(chaos_replacement=False, all_centre_weighting=False),
    "Modified BSO with both modifications off (Shi's BSO without random centre replacement)",
)
register(
    "modified-bso-raw-weights",
    ModifiedBSO(normalise_weights=False),
    "Modified BSO with the raw, unnormalised chaotic weights printed in eq. (9)",
)
for _map in ChaoticMap:
    if _map is not ChaoticMap.LOGISTIC:
        register(
            f"modified-bso-{_map.name.lower()}",
            ModifiedBSO(replacement_map=_map, weight_map=_map),
            f"Modified BSO with the {_map.name.lower()} map as f_rmap and f_hmap",
        )
del _map
