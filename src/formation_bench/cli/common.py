"""What the command line's modules share: the one-line usage error, ``--set`` values, the
option types, and the conversion of the budget options into a
:class:`~formation_bench.optimizers.Budget`.

:mod:`.main` (``run``, ``reproduce``, ``list``) and :mod:`.sweep_commands` (``sweep``,
``score``, ``report``, ``export-ioh``) both import this module; it imports neither, so the
imports point one way.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import math
import re
import sys
import textwrap
from collections.abc import Mapping
from typing import Any

from formation_bench.optimizers import OPTIMIZERS, Budget, Optimizer, get_optimizer
from formation_bench.optimizers.base import BUDGET_MINIMUM
from formation_bench.pipeline.checks import MAX_SEED
from formation_bench.pipeline.spec import deadline_s_of_ms


class UsageError(Exception):
    """A problem with what the user asked for (reported in one line, exit 2)."""


HELP_WIDTH = 88
"""Width the commands' descriptions are wrapped to."""
INDENT = " " * 6
"""Indent of what an example does, under its command line."""


def first_sentence(description: str) -> str:
    """A command's one-line help: the first sentence of its description, without the stop."""
    sentence = re.split(r"(?<=\.)\s", description.strip(), maxsplit=1)[0]
    return " ".join(sentence.split()).removesuffix(".")


def add_command(
    commands: argparse._SubParsersAction,
    name: str,
    description: str,
    examples: tuple[tuple[str, str], ...] = (),
) -> argparse.ArgumentParser:
    """A subcommand declared by its description alone: what it does (its first sentence, also
    the one-line help in the list of commands), what it writes and where; then ``examples``
    as (command line, what it does) pairs. Paragraphs are separated by blank lines."""
    paragraphs = [" ".join(p.split()) for p in description.strip().split("\n\n")]
    epilog = None
    if examples:
        epilog = "examples:\n" + "\n".join(
            f"  {line}\n"
            + textwrap.fill(what, HELP_WIDTH, initial_indent=INDENT, subsequent_indent=INDENT)
            for line, what in examples
        )
    return commands.add_parser(
        name,
        help=first_sentence(description),
        description="\n\n".join(textwrap.fill(p, HELP_WIDTH) for p in paragraphs),
        epilog=epilog,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )


def parse_value(text: str) -> Any:
    """A ``--set`` value: a Python literal (number, bool, tuple, ...) or else the plain string."""
    lowered = text.strip().lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        return text


def assignment(text: str) -> tuple[str, str, str, str]:
    """``[TARGET.]FIELD=VALUE`` as ``(name as written, target or '', field, raw value)``."""
    name, sep, raw = text.partition("=")
    if not sep or not name:
        raise UsageError(f"--set expects FIELD=VALUE, got {text!r}")
    target, dot, field = name.partition(".")
    if not dot:
        target, field = "", name
    return name, target, field, raw


def configured_optimizer(name: str, assignments: list[str]) -> tuple[Optimizer, dict[str, Any]]:
    """The registered optimizer ``name`` with ``--set FIELD=VALUE`` overrides of its own
    fields (for commands without a scenario); returns it and the overrides."""
    if name not in OPTIMIZERS:
        allowed = ", ".join(sorted(OPTIMIZERS))
        raise UsageError(f"--optimizer: unknown name {name!r}; allowed: {allowed}")
    fields = sorted(f.name for f in dataclasses.fields(get_optimizer(name)))  # type: ignore[arg-type]
    listed = ", ".join(fields) or "none"
    to_optimizer: dict[str, Any] = {}
    for text in assignments:
        written, target, field, raw = assignment(text)
        if target not in ("", "optimizer"):
            raise UsageError(
                f"--set {written}: only fields of optimizer {name!r} apply here (this command "
                f"has no scenario); its fields: {listed}"
            )
        if field not in fields:
            raise UsageError(
                f"--set {written}: unknown field of optimizer {name!r}; its fields: {listed}"
            )
        to_optimizer[field] = parse_value(raw)
    try:
        return get_optimizer(name, **to_optimizer), to_optimizer
    except (ValueError, TypeError, KeyError) as err:
        raise UsageError(set_error(error_message(err), assignments)) from None


def error_message(err: BaseException) -> str:
    return str(err.args[0]) if err.args else str(err)


# a field check says "Class.field must be ..., got ..."
_FIELD_ERROR = re.compile(r"(?P<cls>\w+)\.(?P<field>\w+) must be (?P<rest>.*)", re.DOTALL)


def set_error(message: str, assignments: list[str]) -> str:
    """A field's error named as the user wrote it: ``--set FIELD: expected ..., got ...``."""
    match = _FIELD_ERROR.fullmatch(message)
    if match is None:
        return f"--set: {message}"
    field = match["field"]
    kind = "scenario" if match["cls"] == "Scenario" else "optimizer"
    written = field
    for text in assignments:
        name = text.partition("=")[0].strip()
        if name in (field, f"{kind}.{field}"):
            written = name
    return f"--set {written}: expected {match['rest']}"


def requested_budget(
    max_evaluations: int | None, max_iterations: int | None, deadline_ms: float | None
) -> Budget | None:
    """The budget options of a command (``--deadline-ms`` in milliseconds) as the
    :class:`Budget` they ask for; None: the optimiser's own."""
    if max_evaluations is None and max_iterations is None and deadline_ms is None:
        return None
    deadline_s = None if deadline_ms is None else deadline_s_of_ms(deadline_ms)
    try:
        return Budget(max_evaluations, max_iterations, deadline_s)
    except ValueError as err:
        raise UsageError(error_message(err)) from None


# --- option types (argparse reports their errors naming the option) ---------------------------


def _integer(text: str, low: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {text!r}") from None
    if value < low:
        raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {value}")
    return value


def positive_int(text: str) -> int:
    return _integer(text, 1)


def budget_limit(text: str) -> int:
    """A budget option's value (evaluations or iterations per solve): the rule of
    :class:`~formation_bench.optimizers.Budget`, an integer >= its minimum."""
    return _integer(text, BUDGET_MINIMUM)


def deadline_ms(text: str) -> float:
    """A ``--deadline-ms`` value: milliseconds > 0 (converted to seconds with the budget)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"must be a number of milliseconds > 0, got {text!r}"
        ) from None
    if not (value > 0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"must be a number of milliseconds > 0, got {text}")
    return value


def seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text!r}") from None
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"must be an integer in [0, 2**128 - 1], got {value}")
    return value


def compile_notice(
    optimizers: Mapping[str, Optimizer], *, harness: bool = True, workers: int = 1
) -> None:
    """Say once on stderr, before work that will compile, what numba compiles and about how
    long it takes (:func:`~formation_bench.pipeline.compiles.pending_compiles`): the harness's
    kernels (``harness``) and those of the optimisers (labels to optimisers) not in numba's
    cache, as on the first run or the first after their source changed, on ``workers``
    processes. Printed in every output mode; no timing holds the compilation (a warm-up runs
    it first)."""
    from formation_bench.pipeline.compiles import pending_compiles

    notice = pending_compiles(optimizers, harness=harness).notice(workers)
    if notice is not None:
        print(notice, file=sys.stderr, flush=True)
