"""Optimisers behind one interface, and the registry of named configurations."""

from formation_bench.optimizers.base import (
    BatchObjective,
    Bounds,
    Budget,
    BudgetExhausted,
    EvaluationCounter,
    Optimizer,
    OptimizeResult,
    PopulationOptimizer,
)
from formation_bench.optimizers.registry import OPTIMIZERS, get_optimizer, optimizer_names, register

__all__ = [
    "OPTIMIZERS",
    "BatchObjective",
    "Bounds",
    "Budget",
    "BudgetExhausted",
    "EvaluationCounter",
    "OptimizeResult",
    "Optimizer",
    "PopulationOptimizer",
    "get_optimizer",
    "optimizer_names",
    "register",
]

# Imported after the registry so that optimiser modules can register themselves
# without a circular import; the registrations below are the named configurations.
from formation_bench.optimizers.modified_bso import ModifiedBSO

register(
    "modified-bso",
    ModifiedBSO(),
    "Modified BSO of the paper: chaotic centre replacement + chaotic all-centre weighting",
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

__all__ += ["ModifiedBSO"]

# Shi's original BSO, the PSOs and the chaotic variants (issue 3): named configurations.
from formation_bench.optimizers.chaos import ChaoticMap  # noqa: E402 (after the registrations above)
from formation_bench.optimizers.cls_bso import ChaoticLocalSearchBSO  # noqa: E402 (after the registrations above)
from formation_bench.optimizers.original_bso import OriginalBSO  # noqa: E402 (after the registrations above)
from formation_bench.optimizers.pso import PSO  # noqa: E402 (after the registrations above)

register(
    "original-bso",
    OriginalBSO(),
    "Shi's (2011) BSO as published: k-means, random-point centre replacement, logsig N(0,1) step",
)
register(
    "original-bso-range-step",
    OriginalBSO(step_scale=0.1, step_relative_to_range=True),
    "Shi's BSO with the modified BSO's step (0.1 x range instead of N(0, 1))",
)
register(
    "cls-bso",
    ChaoticLocalSearchBSO(),
    "Shi's BSO + chaotic local search around the best idea (after CBSO, Yu et al. 2018)",
)
register(
    "pso",
    PSO(),
    "Global-best PSO, inertia 0.9 -> 0.4, c1 = c2 = 2, velocity clamp 0.2 x range, clip",
)
register(
    "pso-constriction",
    PSO(inertia_start=0.7298, inertia_end=0.7298, c1=1.49618, c2=1.49618),
    "Global-best PSO with Clerc-Kennedy constriction (chi = 0.7298, c1 = c2 = 1.49618)",
)
register(
    "chaotic-pso",
    PSO(chaotic_coefficients=True, chaotic_inertia=True),
    "Chaotic PSO (after Alatas et al. 2009): logistic r1, r2 and chaotic inertia weight",
)
register(
    "chaotic-pso-coefficients",
    PSO(chaotic_coefficients=True),
    "Chaotic PSO: logistic sequences for r1, r2 only (linear inertia 0.9 -> 0.4)",
)
register(
    "chaotic-pso-inertia",
    PSO(chaotic_inertia=True),
    "Chaotic PSO: Feng et al.'s chaotic inertia weight only (uniform r1, r2)",
)
for _map in ChaoticMap:
    if _map is not ChaoticMap.LOGISTIC:
        register(
            f"modified-bso-{_map.name.lower()}",
            ModifiedBSO(replacement_map=_map, weight_map=_map),
            f"Modified BSO with the {_map.name.lower()} map as f_rmap and f_hmap",
        )
del _map

__all__ += ["PSO", "ChaoticLocalSearchBSO", "ChaoticMap", "OriginalBSO"]
