"""Optimisers behind one interface, and the registry of named configurations.

Each optimiser module registers its own named configurations at its bottom;
importing the modules here fills the registry.
"""

# the adapters register only what can run here, without importing the adapted libraries
from formation_bench.optimizers import adapters
from formation_bench.optimizers.base import (
    BatchObjective,
    Bounds,
    Budget,
    BudgetExhausted,
    EvaluationCounter,
    Optimizer,
    OptimizeResult,
    PopulationOptimizer,
    budget_setting,
)
from formation_bench.optimizers.cem import CEM
from formation_bench.optimizers.chaos import ChaoticMap
from formation_bench.optimizers.cls_bso import ChaoticLocalSearchBSO
from formation_bench.optimizers.cma_es import CMAES
from formation_bench.optimizers.differential_evolution import DifferentialEvolution
from formation_bench.optimizers.modified_bso import ModifiedBSO
from formation_bench.optimizers.mppi import MPPI
from formation_bench.optimizers.original_bso import OriginalBSO
from formation_bench.optimizers.predictive_sampling import PredictiveSampling
from formation_bench.optimizers.pso import PSO
from formation_bench.optimizers.random_search import RandomSearch
from formation_bench.optimizers.registry import OPTIMIZERS, get_optimizer, optimizer_names, register

# last: the tuned variants are configurations of the families registered above
from formation_bench.optimizers.tuned import register_tuned  # isort: skip

__all__ = [
    "CEM",
    "CMAES",
    "MPPI",
    "OPTIMIZERS",
    "PSO",
    "BatchObjective",
    "Bounds",
    "Budget",
    "BudgetExhausted",
    "ChaoticLocalSearchBSO",
    "ChaoticMap",
    "DifferentialEvolution",
    "EvaluationCounter",
    "ModifiedBSO",
    "OptimizeResult",
    "Optimizer",
    "OriginalBSO",
    "PopulationOptimizer",
    "PredictiveSampling",
    "RandomSearch",
    "adapters",
    "budget_setting",
    "get_optimizer",
    "optimizer_names",
    "register",
    "register_tuned",
]
