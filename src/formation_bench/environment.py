"""The environment variables formation-bench reads, each declared once with its values.

An environment variable is an input like an option: a module that reads one declares it
with :func:`environment_variable` (its name, the enum of its values, the value when it is
unset and a one-line doc) and reads it through :meth:`EnvironmentVariable.value`; every
command checks them all (:func:`check_environment`) before it starts any work, so a bad
value ends in one line instead of a failure per run. Nothing else in the package reads
``os.environ`` (a test checks this).

Neutral on purpose, like :mod:`formation_bench.fields`: it imports nothing of the package.
"""

from __future__ import annotations

import enum
import functools
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

from formation_bench.fields import member_text

E = TypeVar("E", bound=enum.Enum)


class EnvironmentValueError(ValueError):
    """An environment variable with a value that is not allowed, or not usable here (one
    line naming the variable and its allowed values)."""


@dataclass(frozen=True)
class EnvironmentVariable(Generic[E]):
    """One environment variable the package reads."""

    name: str
    values: type[E]
    """Its allowed values: the text of each member (:func:`~formation_bench.fields.member_text`),
    in any case and with surrounding blanks ignored."""
    unset: E
    """The value when the variable is not set (an empty value is not allowed)."""
    doc: str
    usable: Callable[[E], str | None] | None = None
    """Why an allowed value cannot be used on this machine (None: it can), checked with the
    value so that it is refused before any work too."""

    @property
    def allowed(self) -> str:
        """The allowed values in words."""
        return ", ".join(member_text(member) for member in self.values)

    def value(self) -> E:
        """The value the environment sets (:attr:`unset` when it is not set)."""
        text = os.environ.get(self.name)
        return self.unset if text is None else _parsed(self, text)

    def check(self) -> None:
        """Raise :class:`EnvironmentValueError` when the value is not allowed or not usable."""
        value = self.value()
        problem = None if self.usable is None else self.usable(value)
        if problem is not None:
            raise EnvironmentValueError(f"{self.name}={member_text(value)}: {problem}")


@functools.cache
def _parsed(variable: EnvironmentVariable, text: str) -> enum.Enum:
    # cached: a solve asks for its cost kernel, and the text seldom changes within a process
    wanted = text.strip().lower()
    for member in variable.values:
        if member_text(member) == wanted:
            return member
    raise EnvironmentValueError(
        f"{variable.name} must be one of {variable.allowed} (unset: "
        f"{member_text(variable.unset)}), got {text!r}"
    )


DECLARED: dict[str, EnvironmentVariable] = {}
"""Every declared variable, by name."""


def environment_variable(
    name: str,
    values: type[E],
    unset: E,
    doc: str,
    usable: Callable[[E], str | None] | None = None,
) -> EnvironmentVariable[E]:
    """Declare the environment variable ``name`` (once) and return it."""
    if name in DECLARED:
        raise ValueError(f"environment variable {name} is declared twice")
    variable = EnvironmentVariable(name, values, unset, doc, usable)
    DECLARED[name] = variable
    return variable


def check_environment() -> None:
    """Check every declared variable; raises :class:`EnvironmentValueError` for the first
    bad one."""
    for variable in DECLARED.values():
        variable.check()
