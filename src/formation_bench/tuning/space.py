"""The search space of an optimiser, from the ``search=`` declarations of its settings.

A setting declared with ``setting(..., search=Search(...))`` is tuned; the others keep the
base configuration's value. The space is define-by-run (Optuna's ``trial.suggest_*``): the
fields are suggested in declaration order, and a limit naming another field (or a function
of the configuration) is resolved against the values already suggested, or the base
configuration's for a field that is not searched. Each range is then clipped into the range
the field's own declaration allows there, so every suggested configuration is valid.
Enumerations and bools are suggested as their text (``clip``, ``true``); the base
configuration's value is always among the choices, so that it can be trial 0.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from typing import TYPE_CHECKING, Any, NamedTuple

from formation_bench.fields import Search, Setting, declared, member_text
from formation_bench.optimizers import Optimizer, get_optimizer

if TYPE_CHECKING:
    import optuna


class SearchedField(NamedTuple):
    """One tuned setting of a configuration."""

    name: str
    spec: Setting
    search: Search


def search_space(optimizer: Optimizer) -> tuple[SearchedField, ...]:
    """The settings of ``optimizer`` declared with a search range, in declaration order."""
    searched = []
    for field in dataclasses.fields(optimizer):  # type: ignore[arg-type]
        spec = declared(field)
        if spec is not None and spec.search is not None:
            searched.append(SearchedField(field.name, spec, spec.search))
    return tuple(searched)


class _Partial:
    """The configuration as far as it is suggested: suggested values first, else the base's
    (what a limit naming a field, or a function of the configuration, reads)."""

    def __init__(self, base: Optimizer, suggested: dict[str, Any]) -> None:
        self._base, self._suggested = base, suggested

    def __getattr__(self, name: str) -> Any:
        if name in self._suggested:
            return self._suggested[name]
        return getattr(self._base, name)


def _resolved(limit: Any, partial: _Partial) -> Any:
    if isinstance(limit, str):
        return getattr(partial, limit)
    if callable(limit):
        return limit(partial)
    return limit


def numeric_range(field: SearchedField, partial: _Partial) -> tuple[float, float]:
    """The searched range of an int or real field, resolved and clipped into its valid one."""
    spec, search = field.spec, field.search
    low, high = _resolved(search.low, partial), _resolved(search.high, partial)
    valid_low, valid_high = _resolved(spec.low, partial), _resolved(spec.high, partial)
    if spec.kind == "real":
        valid_low = -math.inf if valid_low is None else float(valid_low)
        valid_high = math.inf if valid_high is None else float(valid_high)
        if spec.low_open:
            valid_low = math.nextafter(valid_low, math.inf)
        if spec.high_open:
            valid_high = math.nextafter(valid_high, -math.inf)
    else:
        valid_high = math.inf if valid_high is None else valid_high
    low = min(max(low, valid_low), valid_high)
    high = max(min(high, valid_high), low)
    if spec.kind == "int":
        low, high = math.ceil(low), max(math.floor(high), math.ceil(low))
    return low, high


def choices(field: SearchedField, base: Optimizer) -> tuple[Any, ...]:
    """The values of a bool, enum or choice field searched, as text, the base's first if the
    declaration leaves it out."""
    spec = field.spec
    if field.search.choices is not None:
        listed = tuple(field.search.choices)
    elif spec.kind == "bool":
        listed = (False, True)
    elif spec.kind == "enum":
        assert spec.enum_type is not None
        listed = tuple(spec.enum_type)
    else:
        listed = tuple(spec.choices() if callable(spec.choices) else spec.choices)
    texts = tuple(as_text(value) for value in listed)
    own = as_text(getattr(base, field.name))
    return texts if own in texts else (own, *texts)


def as_text(value: Any) -> Any:
    """A choice as it is suggested and written: an enum's text, a bool as ``true``/``false``."""
    if isinstance(value, enum.Enum):
        return member_text(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    return value


def from_text(spec: Setting, text: Any) -> Any:
    """A suggested choice as the setting's value: a bool from its text, else the text (the
    configuration coerces an enum's text itself)."""
    if spec.kind == "bool":
        return text == "true"
    return text


def suggest(trial: optuna.Trial, base_name: str, base: Optimizer) -> dict[str, Any]:
    """Suggest every searched setting of ``base`` on ``trial``, in declaration order; returns
    the values as ``--set`` and the tuned file write them (enums as text). Raises ValueError
    naming the field if the configuration they make is not valid."""
    values: dict[str, Any] = {}
    partial = _Partial(base, {})
    for field in search_space(base):
        spec = field.spec
        if spec.kind in ("int", "real"):
            low, high = numeric_range(field, partial)
            if spec.kind == "int":
                value = trial.suggest_int(field.name, int(low), int(high), log=field.search.log)
            else:
                value = trial.suggest_float(field.name, low, high, log=field.search.log)
            natural = value
        else:
            value = from_text(spec, trial.suggest_categorical(field.name, choices(field, base)))
            natural = value if spec.kind != "enum" else getattr_enum(spec, value)
        values[field.name] = value
        partial._suggested[field.name] = natural
    configured(base_name, values)
    return values


def getattr_enum(spec: Setting, text: str) -> enum.Enum:
    """The member of an enum setting written as ``text``."""
    assert spec.enum_type is not None
    return next(m for m in spec.enum_type if member_text(m) == text)


def configured(base_name: str, values: dict[str, Any]) -> Optimizer:
    """``base_name`` with ``values``, checked as ``--set`` checks them."""
    try:
        return get_optimizer(base_name, **values)
    except (ValueError, TypeError) as err:
        raise ValueError(f"a suggested configuration of {base_name} is not valid: {err}") from None


def base_params(base: Optimizer) -> dict[str, Any]:
    """The base configuration's values of its searched settings, as they are suggested:
    trial 0's parameters."""
    return {field.name: as_text(getattr(base, field.name)) for field in search_space(base)}
