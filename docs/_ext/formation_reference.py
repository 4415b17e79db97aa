"""The reference pages generated from the code's declarations, written when Sphinx starts.

On ``builder-inited`` :func:`write_pages` writes Markdown into ``docs/reference/_generated/``
(ignored by git), which ``docs/reference/index.md`` lists in its toctree:

- ``optimizers.md``: every registered optimiser configuration, grouped by class, each class's
  settings as ``formation-bench list --fields NAME`` describes them
  (:func:`formation_bench.fields.describe_fields`) and each configuration's changes from them;
- ``scenarios.md``: the :class:`~formation_bench.mpc.scenario.Scenario` settings by group and
  every registered scenario's changes from the defaults;
- ``columns.md``: the record columns (one row per run) and the trace columns, from the
  tables their declaring modules write (``columns_table``);
- ``suites.md``: the keys a suite file takes (the key tuples of
  :mod:`formation_bench.experiments.suite`) and every shipped suite, its description and size.

A page is rewritten only when its text changes, so an unchanged build reads nothing again.

The command line's page is committed instead, as ``docs/reference/cli.md``, so that it can be
read on the repository's web view without building the site: every command of the
``formation-bench`` parser (``build_parser``), its description and options, read from the
parser itself. It does not depend on the installed extras. Running this file as a script
(``python docs/_ext/formation_reference.py``) rewrites it; a build whose page differs from
the code warns (an error with ``-W``), and so does ``tests/test_docs_reference.py``.

Sphinx's smart quotes are off on these pages: they would turn ``--out`` into an en dash and
``'list'`` into curly quotes in the text cells, and a command copied from there would fail.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import re
import sys
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

GENERATED = Path("reference") / "_generated"
"""Where the pages go, relative to the documentation's source folder."""

CLI_PAGE = Path("reference") / "cli.md"
"""The committed page of the command line, relative to the documentation's source folder."""

REGENERATE_CLI = "python docs/_ext/formation_reference.py"
"""The command (from the repository's root) that rewrites :data:`CLI_PAGE`."""

USAGE_WIDTH = 80
"""Columns of the usage lines: argparse wraps them to the terminal's width otherwise, and the
committed page must not depend on the terminal it was written from."""

LONG_VALUE = 60
"""A value whose text is longer than this is shown by its length instead."""


# --- Markdown helpers ------------------------------------------------------------------------


_MARKDOWN_SPECIALS = "\\`*_[]<>|$"


def _escaped(value: str) -> str:
    return "".join(f"\\{c}" if c in _MARKDOWN_SPECIALS else c for c in value)


def text(value: str) -> str:
    """``value`` as literal Markdown on one line (a table cell): special characters escaped."""
    return " ".join(_escaped(value).split())


def code(value: str) -> str:
    """``value`` as inline code inside a table cell."""
    value = " ".join(value.split()).replace("|", "\\|")
    fence = "``" if "`" in value else "`"
    return f"{fence} {value} {fence}" if fence == "``" else f"`{value}`"


def table(header: Iterable[str], rows: Iterable[Iterable[str]]) -> list[str]:
    """A Markdown table and the empty line that ends it; cells must already be Markdown. The
    comment above it is the one ``tests/test_docs_tables.py`` asks of a table that is not a
    measurement."""
    header = list(header)
    lines = [
        "<!-- reference table -->",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return [*lines, ""]


_RST_CODE = re.compile(r"(?::[\w:]+:)?`~?([^`]+)`|``([^`]+)``")
"""A cross-reference role (``:class:`~a.B```) or literal (````x````) of reStructuredText."""


def rst_text(value: str) -> str:
    """A line of reStructuredText (a docstring's) as Markdown: its roles and literals as
    inline code (a role's ``~`` keeping the last name), the rest literal."""
    value = " ".join(value.split())
    out, end = [], 0
    for match in _RST_CODE.finditer(value):
        out.append(_escaped(value[end : match.start()]))
        role_target, literal = match.groups()
        if literal is None and match.group(0).startswith(":") and "~" in match.group(0)[:-1]:
            role_target = role_target.rsplit(".", 1)[-1]
        out.append(code(literal if literal is not None else role_target))
        end = match.end()
    out.append(_escaped(value[end:]))
    return "".join(out)


def first_paragraph(obj: Any) -> str:
    """The first paragraph of ``obj``'s docstring, on one line, as Markdown."""
    doc = inspect.getdoc(obj) or ""
    return rst_text(" ".join(doc.split("\n\n")[0].split()))


def generated_notice(source: str) -> list[str]:
    return [
        "",
        f"*Generated when the site is built, from {source}; "
        "do not edit (see docs/\\_ext/formation\\_reference.py).*",
        "",
    ]


def committed_notice(source: str, command: str) -> list[str]:
    return [
        "",
        f"*Generated from {source} by `{command}` (from the repository's root); do not edit: "
        "the tests and the site's build fail when it differs from the code.*",
        "",
    ]


# --- the command line ------------------------------------------------------------------------


def _usage(parser: argparse.ArgumentParser) -> str:
    """``parser.format_usage()`` wrapped at :data:`USAGE_WIDTH` columns, whatever the
    terminal."""
    formatter = parser.formatter_class(prog=parser.prog, width=USAGE_WIDTH)
    formatter.add_usage(parser.usage, parser._actions, parser._mutually_exclusive_groups)
    return formatter.format_help().strip()


def _subcommands(parser: argparse.ArgumentParser) -> Iterator[tuple[str, str, Any]]:
    """``(name, one-line help, parser)`` of each subcommand of ``parser``."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {choice.dest: choice.help or "" for choice in action._choices_actions}
            for name, sub in action.choices.items():
                yield name, helps.get(name, ""), sub


def _option_rows(parser: argparse.ArgumentParser) -> list[list[str]]:
    formatter = parser._get_formatter()
    rows = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) or action.help == argparse.SUPPRESS:
            continue
        if action.option_strings:
            metavar = (
                "" if action.nargs == 0 else formatter._format_args(action, action.dest.upper())
            )
            names = ", ".join(code(f"{flag} {metavar}".strip()) for flag in action.option_strings)
        else:
            names = code(formatter._format_args(action, action.dest))
        default = action.default
        shown = (
            ""
            if default in (None, argparse.SUPPRESS, False, [])
            or (action.nargs == 0 and not default)
            else code(" ".join(map(str, default)) if isinstance(default, list) else str(default))
        )
        help_text = formatter._expand_help(action) if action.help else ""
        if action.required:
            help_text = f"(required) {help_text}"
        rows.append([names, shown, text(help_text)])
    return rows


def _command_section(
    prog: str, parser: argparse.ArgumentParser, help_line: str, level: int
) -> list[str]:
    lines = [f"{'#' * level} `{prog}`", ""]
    if parser.description:  # the help line of the command list is its short form
        lines += [text(parser.description), ""]
    elif help_line:
        lines += [text(help_line[:1].upper() + help_line[1:]) + ".", ""]
    lines += ["```text", _usage(parser), "```", ""]
    rows = _option_rows(parser)
    if rows:
        lines += table(["option", "default", "meaning"], rows)
    for name, sub_help, sub in _subcommands(parser):
        lines += _command_section(f"{prog} {name}", sub, sub_help, level + 1)
    return lines


def cli_page() -> str:
    from formation_bench.cli.main import build_parser

    parser = build_parser()
    lines = [
        "# Command line",
        *committed_notice("the parser of formation\\_bench.cli.main", REGENERATE_CLI),
    ]
    lines += [text(parser.description or ""), ""]
    lines += ["Commands: " + ", ".join(f"`{name}`" for name, _, _ in _subcommands(parser)), ""]
    lines += ["```text", _usage(parser), "```", ""]
    lines += table(["option", "default", "meaning"], _option_rows(parser))
    if parser.epilog:
        lines += ["```text", parser.epilog.strip(), "```", ""]
    for name, help_line, sub in _subcommands(parser):
        lines += _command_section(f"formation-bench {name}", sub, help_line, 2)
    return "\n".join(lines)


# --- settings (optimisers, scenarios) ---------------------------------------------------------


def shown(value: Any) -> str:
    """A setting's value as ``formation-bench list --fields`` shows it, shortened if long."""
    from formation_bench.cli.main import shown_value

    shown_text = shown_value(value)
    if len(shown_text) > LONG_VALUE and isinstance(value, tuple | list):
        return f"({len(value)} items)"
    if len(shown_text) > LONG_VALUE:
        return shown_text[: LONG_VALUE - 3] + "..."
    return shown_text


def _is_group(value: Any) -> bool:
    return dataclasses.is_dataclass(value) and not isinstance(value, type)


def settings_rows(obj: Any, prefix: str = "", tunable: bool = False) -> list[list[str]]:
    """One row per setting of ``obj`` (a config class or instance), in the order and words of
    ``formation-bench list --fields``, with what a tuner searches when ``tunable`` (an
    optimiser's); a group of settings as a row naming it, then its settings."""
    from formation_bench.fields import describe_fields

    rows = []
    for info in describe_fields(obj):
        if _is_group(info.value):
            rows.append([f"**{text(prefix + info.name)}** (group)", "", "", text(info.doc)])
            rows += settings_rows(info.value, f"{prefix}{info.name}.", tunable)
            continue
        allowed = text(info.allowed)
        if tunable and info.search:
            allowed = f"{allowed}; tuning: {text(info.search)}" if allowed else text(info.search)
        rows.append(
            [code(prefix + info.name), f"{code(info.type)} = {code(shown(info.value))}", allowed,
             text(info.doc)]
        )  # fmt: skip
    return rows


# type and default share a cell, as do the allowed values and what a tuner searches: a column
# fewer lets the tables of the longest setting names fit the page's column
SETTINGS_HEADER = ("setting", "type = default", "allowed", "meaning")
OPTIMIZER_SETTINGS_HEADER = ("setting", "type = default", "allowed; tuning", "meaning")


def _equal(a: Any, b: Any) -> bool:
    try:
        return bool(a == b)
    except (ValueError, TypeError):  # arrays: compare their texts
        return repr(a) == repr(b)


def changed_settings(obj: Any, defaults: Any, prefix: str = "") -> list[tuple[str, Any]]:
    """``(name, value)`` of each setting of ``obj`` that differs from ``defaults`` (an
    instance or the class), groups entered (``timing.n_steps``)."""
    from formation_bench.fields import describe_fields

    default_values = {info.name: info.value for info in describe_fields(defaults)}
    changed = []
    for info in describe_fields(obj):
        default = default_values.get(info.name)
        if _is_group(info.value) and _is_group(default):
            changed += changed_settings(info.value, default, f"{prefix}{info.name}.")
        elif not _equal(info.value, default):
            changed.append((f"{prefix}{info.name}", info.value))
    return changed


def _changes_text(changes: list[tuple[str, Any]]) -> str:
    return ", ".join(code(f"{name}={shown(value)}") for name, value in changes) or "(defaults)"


def _class_path(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def optimizers_page() -> str:
    from formation_bench.optimizers import OPTIMIZERS

    by_class: dict[type, list[Any]] = {}
    for name in sorted(OPTIMIZERS):
        entry = OPTIMIZERS[name]
        by_class.setdefault(type(entry.optimizer), []).append(entry)
    lines = ["# Optimisers", *generated_notice("the optimiser registry")]
    lines += [
        f"{len(OPTIMIZERS)} registered configurations of {len(by_class)} classes. A "
        "configuration is a class with some settings changed; `formation-bench list --fields "
        "NAME` prints a configuration's settings and `--set optimizer.FIELD=VALUE` changes one "
        "for a run.",
        "",
    ]
    lines += table(
        ["configuration", "class", "description"],
        (
            [code(entry.name), f"[{cls.__name__}](#{cls.__name__.lower()})",
             text(entry.description)]
            for cls, entries in by_class.items()
            for entry in entries
        ),
    )  # fmt: skip
    missing = OPTIMIZERS.missing()
    if missing:
        lines += ["Not available where this page was built:", ""]
        lines += [f"- `{name}`: {text(reason)}" for name, reason in sorted(missing.items())]
        lines += [""]
    for cls in sorted(by_class, key=lambda c: c.__name__.lower()):
        lines += [f"## {cls.__name__}", "", f"`{_class_path(cls)}`: {first_paragraph(cls)}"]
        lines += ["", "Settings (the class's defaults):", ""]
        lines += table(OPTIMIZER_SETTINGS_HEADER, settings_rows(cls, tunable=True))
        lines += ["Registered configurations:", ""]
        lines += table(
            ["name", "description", "settings changed from the defaults"],
            (
                [code(e.name), text(e.description),
                 _changes_text(changed_settings(e.optimizer, cls))]
                for e in by_class[cls]
            ),
        )  # fmt: skip
    return "\n".join(lines)


def scenarios_page() -> str:
    from formation_bench.mpc.scenario import SCENARIOS, Scenario

    defaults = Scenario()
    lines = ["# Scenarios", *generated_notice("the scenario registry")]
    lines += [
        f"{len(SCENARIOS)} registered scenarios, each a `{_class_path(Scenario)}` with some "
        "settings changed. `formation-bench list --fields NAME` prints a scenario's settings "
        "and `--set scenario.FIELD=VALUE` changes one for a run; a setting of a group is set by "
        "its own name (`n_steps`) or with its group (`timing.n_steps`).",
        "",
        "## Registered scenarios",
        "",
    ]
    lines += table(
        ["name", "UAVs", "reference", "instants", "settings changed from the defaults"],
        (
            [code(name), str(s.n_uav), code(s.reference), str(s.timing.n_steps),
             _changes_text([c for c in changed_settings(s, defaults) if c[0] != "name"])]
            for name, s in sorted(SCENARIOS.items())
        ),
    )  # fmt: skip
    lines += ["## Settings", "", first_paragraph(Scenario), ""]
    lines += table(SETTINGS_HEADER, settings_rows(defaults))
    return "\n".join(lines)


# --- record and trace columns -----------------------------------------------------------------


def columns_page() -> str:
    from formation_bench.pipeline import record, trace_columns

    return "\n".join(
        [
            "# Record and trace columns",
            *generated_notice("the column declarations"),
            "## Record columns",
            "",
            "One row per run in the results store (`runs/*.parquet` of a sweep) and one object "
            "per run in a `metrics.json`. Declared in `formation_bench.pipeline.record` "
            "(description and provenance) and `formation_bench.mpc.metrics.Metrics` (the "
            "metrics). A *timing* column differs between two runs of the same thing.",
            "",
            record.columns_table(),
            "",
            "## Trace columns",
            "",
            "The trace table (`trace.parquet`): one row per instant and UAV. Declared in "
            "`formation_bench.pipeline.trace_columns.TRACE_COLUMNS`.",
            "",
            trace_columns.columns_table(),
            "",
        ]
    )


# --- suites ------------------------------------------------------------------------------------


def _budgets_text(budgets: Iterable[Any]) -> str:
    from formation_bench.pipeline.spec import budget_label

    return ", ".join(budget_label(budget) for budget in budgets)


def suites_page() -> str:
    from formation_bench.experiments import suite

    lines = ["# Suite files", *generated_notice("formation\\_bench.experiments.suite")]
    lines += [
        "A suite is a TOML file: `formation-bench sweep NAME_OR_PATH` runs every combination "
        "of its optimisers, scenarios, budgets, triggers and seeds. The format is explained in "
        "[Benchmarks](../../explanation/benchmarks.md#suites); the keys each table takes are "
        "the ones `formation_bench.experiments.suite` accepts:",
        "",
    ]
    lines += ["## Keys", ""]
    for heading, keys in (
        ("Top level", suite.TOP_LEVEL_KEYS),
        ("`[[optimizers]]` tables", suite.OPTIMIZER_KEYS),
        ("`[[scenarios]]` tables", suite.SCENARIO_KEYS),
        ("Budget tables", suite.BUDGET_KEYS),
    ):
        lines += [f"### {heading}", ""]
        lines += table(["key", "what it holds"], [[code(k), text(v)] for k, v in keys.items()])
    lines += [
        "## Shipped suites",
        "",
        "In `src/formation_bench/experiments/suites/`; the counts are those of the "
        "installation that built this page (an optional optimiser that is not installed is "
        "left out).",
        "",
    ]
    rows = []
    for name in suite.shipped_suites():
        loaded = suite.load_suite(name)
        rows.append(
            [code(name), text(loaded.description), str(len(loaded.optimizers)),
             str(len(loaded.scenarios)), text(_budgets_text(loaded.budgets)),
             str(len(loaded.triggers)), str(len(loaded.seeds)), str(len(loaded.runs()))]
        )  # fmt: skip
    lines += table(
        ["suite", "description", "optimisers", "scenarios", "budgets", "triggers", "seeds",
         "runs"],
        rows,
    )  # fmt: skip
    return "\n".join(lines)


# --- writing -----------------------------------------------------------------------------------


PAGES: dict[str, Callable[[], str]] = {
    "optimizers": optimizers_page,
    "scenarios": scenarios_page,
    "columns": columns_page,
    "suites": suites_page,
}
"""Each page generated at build time (its file name without ``.md``) and what writes it."""


def page_text(page: Callable[[], str]) -> str:
    """A page's text as it is written: one newline at its end."""
    return page().rstrip("\n") + "\n"


def write_pages(folder: Path) -> list[Path]:
    """Write every page of :data:`PAGES` into ``folder``; returns the pages whose text
    changed (the others are left untouched, so Sphinx does not read them again). A page of
    ``folder`` that is no longer generated there is removed: it would be in no toctree."""
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob("*.md"):
        if old.stem not in PAGES:
            old.unlink()
    changed = []
    for name, page in PAGES.items():
        path = folder / f"{name}.md"
        content = page_text(page)
        if not path.is_file() or path.read_text(encoding="utf-8") != content:
            path.write_text(content, encoding="utf-8")
            changed.append(path)
    return changed


def cli_page_is_current(path: Path) -> bool:
    """Whether the committed page at ``path`` says what the parser says."""
    return path.is_file() and path.read_text(encoding="utf-8") == page_text(cli_page)


def _on_builder_inited(app: Any) -> None:
    from sphinx.util import logging

    source = Path(app.srcdir)
    write_pages(source / GENERATED)
    if not cli_page_is_current(source / CLI_PAGE):
        logging.getLogger(__name__).warning(
            "%s differs from the command line's parser; rewrite it with: %s",
            CLI_PAGE.as_posix(), REGENERATE_CLI,
        )  # fmt: skip


def _is_generated(docname: str) -> bool:
    return docname == CLI_PAGE.with_suffix("").as_posix() or docname.startswith(
        GENERATED.as_posix() + "/"
    )


def setup(app: Any) -> dict[str, Any]:
    from sphinx.transforms import SphinxTransform

    class LiteralDashesAndQuotes(SphinxTransform):
        """Smart quotes off on the generated pages: marks the document as Sphinx's
        ``is_smartquotable`` reads it, before its smart-quotes transform runs (750)."""

        default_priority = 740

        def apply(self, **kwargs: Any) -> None:
            if _is_generated(self.env.docname):
                self.document["support_smartquotes"] = False

    app.connect("builder-inited", _on_builder_inited)
    app.add_transform(LiteralDashesAndQuotes)
    return {"parallel_read_safe": True, "parallel_write_safe": True}


def main() -> None:
    """Rewrite the committed command-line page from the installed code."""
    path = Path(__file__).resolve().parents[1] / CLI_PAGE
    path.write_text(page_text(cli_page), encoding="utf-8")
    print(f"wrote {path}", file=sys.stderr)


__all__ = ["CLI_PAGE", "PAGES", "cli_page", "cli_page_is_current", "setup", "write_pages"]


if __name__ == "__main__":
    main()
