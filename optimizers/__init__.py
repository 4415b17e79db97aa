"""Optimisers behind one interface, and the registry of named configurations."""

from optimizers.base import (
    BatchObjective,
    Bounds,
    Budget,
    BudgetExhausted,
    EvaluationCounter,
    Optimizer,
    OptimizeResult,
    PopulationOptimizer,
)
from optimizers.registry import OPTIMIZERS, get_optimizer, optimizer_names, register

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
from optimizers.modified_bso import ModifiedBSO

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
