"""Tuned variants: configurations found by ``formation-bench tune``, registered by name.

Each ``*.json`` file in this folder is one tuned variant (the format is written by
:mod:`formation_bench.tuning.variants`): its ``values`` applied to its ``base`` optimiser,
registered as ``name`` (``NAME-tuned`` or ``NAME-tuned-loop``), with the tuning's
provenance kept for ``formation-bench list --fields``. This module is imported after the
optimiser families, so every base it names is registered before it.

A plugin registers a tuned file of its own optimiser with :func:`register_tuned`, after
registering the optimiser itself.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from formation_bench.optimizers.base import Optimizer
from formation_bench.optimizers.registry import OPTIMIZERS, get_optimizer, register

TUNED_FORMAT = 1
"""The version of the tuned-variant file's layout (key ``format``)."""
TUNED_DIR = Path(__file__).parent
"""Where the package's own tuned variants live."""

_TUNED: dict[str, dict[str, Any]] = {}
"""Every registered tuned variant's file contents, by name."""


class TunedFileError(ValueError):
    """A tuned-variant file that cannot be registered (the message names the file)."""


def is_tuned(name: str) -> bool:
    """Whether ``name`` is registered as a tuned variant."""
    return name in _TUNED


def tuned_data(name: str) -> dict[str, Any] | None:
    """The file contents of the tuned variant ``name`` (None: not one)."""
    return _TUNED.get(name)


def tuned_optimizer(data: dict[str, Any], where: str = "a tuned variant") -> Optimizer:
    """The configuration a tuned file describes: its base with its values, validated."""
    if data.get("format") != TUNED_FORMAT:
        raise TunedFileError(f"{where}: format {data.get('format')!r}, expected {TUNED_FORMAT}")
    base = data.get("base")
    if base not in OPTIMIZERS:
        raise TunedFileError(f"{where}: base optimizer {base!r} is not registered")
    try:
        return get_optimizer(base, **data["values"])
    except (ValueError, TypeError, KeyError) as err:
        raise TunedFileError(f"{where}: {err}") from None


def describe(data: dict[str, Any]) -> str:
    """The variant's one line for ``formation-bench list``."""
    objective, tuner = data["objective"], data["tuner"]
    if objective["kind"] == "solve":
        on = f"median normalised gap on the {objective['split']} split of {objective['library']}"
    else:
        on = f"median {objective['metric']} over {len(objective['seeds'])} validation seeds"
    return (
        f"{data['base']} tuned by Optuna {tuner['sampler']} ({tuner['trials']} trials, "
        f"{objective['budget']} evaluations per solve) for the {on}"
    )


def register_tuned(path: Path | str) -> Optimizer:
    """Register the tuned variant of the file ``path`` under its name; returns it."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError) as err:
        raise TunedFileError(f"tuned variant {path}: cannot be read: {err}") from None
    optimizer = tuned_optimizer(data, f"tuned variant {path}")
    name = data.get("name")
    register(name, optimizer, describe(data))
    _TUNED[name] = data
    return optimizer


def register_shipped() -> None:
    """Register every tuned variant shipped in this folder (by file name order)."""
    for path in sorted(TUNED_DIR.glob("*.json")):
        register_tuned(path)


register_shipped()
