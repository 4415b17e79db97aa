"""A plain registry of named optimiser configurations.

Variants are registered as named *configurations* of one class (an ablation
is ``ModifiedBSO(chaos_replacement=False)`` under its own name), never as
copies of code. Names are unique: registering a name twice is an error.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from formation_bench.fields import declared, validate_fields
from formation_bench.optimizers.base import Optimizer
from formation_bench.plugins import OPTIMIZER_GROUP, Registry


@dataclass(frozen=True)
class RegisteredOptimizer:
    """One registry entry."""

    name: str
    """Unique name used on the command line and in results."""
    optimizer: Optimizer
    """The configured optimiser (an immutable dataclass instance)."""
    description: str
    """One line for ``formation-bench list``."""


def _check_entry(name: str, entry: RegisteredOptimizer) -> None:
    if not dataclasses.is_dataclass(entry.optimizer) or isinstance(entry.optimizer, type):
        raise TypeError(f"{name!r}: registered optimizers must be dataclass instances")
    if not isinstance(entry.optimizer, Optimizer):
        raise TypeError(
            f"{name!r}: registered optimizers must implement formation_bench.optimizers.Optimizer"
        )
    # a setting without a declaration could be neither checked nor listed: a bad --set value
    # would then fail in the middle of a run instead of at the command line
    undeclared = [f.name for f in dataclasses.fields(entry.optimizer) if declared(f) is None]
    if undeclared:
        raise TypeError(
            f"{name!r}: declare {', '.join(undeclared)} of {type(entry.optimizer).__name__} "
            "with formation_bench.fields.setting(default, doc=..., low=...), so that its "
            "values are checked and listed"
        )
    validate_fields(entry.optimizer)


OPTIMIZERS: Registry[RegisteredOptimizer] = Registry("optimizer", OPTIMIZER_GROUP, _check_entry)
"""Every registered optimiser by name; plugins of the ``formation_bench.optimizers``
entry-point group are loaded on first lookup."""


def register(name: str, optimizer: Optimizer, description: str) -> Optimizer:
    """Register ``optimizer`` under ``name``; refuses a name already taken."""
    OPTIMIZERS.add(name, RegisteredOptimizer(name, optimizer, description))
    return optimizer


def get_optimizer(name: str, /, **overrides: Any) -> Optimizer:
    """The optimiser registered as ``name``, with config fields replaced by ``overrides``.

    Unknown names and unknown fields raise ``KeyError``/``ValueError`` naming
    the allowed values; field values are validated by the dataclass itself.
    """
    if name not in OPTIMIZERS:
        raise OPTIMIZERS.unknown(name)
    optimizer = OPTIMIZERS[name].optimizer
    if not overrides:
        return optimizer
    fields = {f.name for f in dataclasses.fields(optimizer)}  # type: ignore[arg-type]
    unknown = sorted(set(overrides) - fields)
    if unknown:
        raise ValueError(
            f"unknown field(s) {', '.join(unknown)} for optimizer {name!r}; "
            f"fields: {', '.join(sorted(fields))}"
        )
    configured = dataclasses.replace(optimizer, **overrides)  # type: ignore[type-var]
    validate_fields(configured)  # also for a class that does not do it in __post_init__
    # under the rule every budget follows, also where a plugin declared its limit otherwise
    configured.default_budget  # noqa: B018
    return configured


def optimizer_names() -> list[str]:
    """Registered names, sorted."""
    return sorted(OPTIMIZERS)
