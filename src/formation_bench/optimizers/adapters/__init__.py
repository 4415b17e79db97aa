"""Adapters that run other libraries' optimisers through the formation-bench interface.

nevergrad (``ng-*``), pycma (``pycma``) and mealpy (``mealpy-*``), all installed by
the ``adapters`` extra (:data:`~.common.INSTALL_HINT`). Importing this
package imports none of them (they take seconds to load): each configuration is
registered when its library can be found, and otherwise noted as missing, so that
asking for it names the extra to install. A library is imported when a solve starts.
"""

from formation_bench.optimizers.adapters.common import INSTALL_HINT, library_available
from formation_bench.optimizers.adapters.mealpy_adapter import MealpyOptimizer
from formation_bench.optimizers.adapters.nevergrad_adapter import NevergradOptimizer
from formation_bench.optimizers.adapters.pycma_adapter import PyCMA
from formation_bench.optimizers.base import Optimizer
from formation_bench.optimizers.registry import OPTIMIZERS, register

__all__ = ["ADAPTERS", "MealpyOptimizer", "NevergradOptimizer", "PyCMA"]

ADAPTERS: dict[str, tuple[str, Optimizer, str]] = {
    "ng-ngopt": (
        "nevergrad",
        NevergradOptimizer(),
        "nevergrad's NGOpt (picks its algorithm for the dimension and budget), 30 per batch",
    ),
    "ng-de": (
        "nevergrad",
        NevergradOptimizer(algorithm="TwoPointsDE"),
        "nevergrad's TwoPointsDE (its DE for parallel settings), 30 per batch",
    ),
    "pycma": (
        "cma",
        PyCMA(),
        "pycma's CMA-ES (BoundTransform, default popsize), restarts with the same popsize",
    ),
    "mealpy-bso": (
        "mealpy",
        MealpyOptimizer(),
        "mealpy's OriginalBSO (Shi's BSO as mealpy publishes it), pop 30",
    ),
    "mealpy-gwo": (
        "mealpy",
        MealpyOptimizer(algorithm="OriginalGWO"),
        "mealpy's grey wolf optimizer (OriginalGWO), pop 30",
    ),
}
"""Every adapter configuration: its name, the library it needs, the optimiser, one line."""

for _name, (_library, _optimizer, _description) in ADAPTERS.items():
    if library_available(_library):
        register(_name, _optimizer, _description)
    else:
        OPTIMIZERS.add_missing(_name, f"it needs the {_library!r} package: {INSTALL_HINT}")
