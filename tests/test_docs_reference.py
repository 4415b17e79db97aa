"""The generated reference (docs/_ext/formation_reference.py) covers every declaration.

The pages are written into a temporary folder, as the Sphinx build writes them into
``docs/reference/_generated/``, and compared with the registries and declarations they are
generated from: every registered optimiser and scenario, every record and trace column,
every shipped suite and every command of the command line. The command line's page is
committed (``docs/reference/cli.md``) and must be the one the code generates.
"""

from __future__ import annotations

import argparse
import importlib.util
import re
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXTENSION = ROOT / "docs" / "_ext" / "formation_reference.py"


def load_extension() -> ModuleType:
    spec = importlib.util.spec_from_file_location("formation_reference", EXTENSION)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def pages(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    folder = tmp_path_factory.mktemp("generated")
    extension = load_extension()
    written = extension.write_pages(folder)
    assert {path.stem for path in written} == set(extension.PAGES)
    assert extension.write_pages(folder) == []  # unchanged text: nothing rewritten
    texts = {name: (folder / f"{name}.md").read_text(encoding="utf-8") for name in extension.PAGES}
    return {**texts, "cli": extension.page_text(extension.cli_page)}


def code_cells(page: str) -> set[str]:
    """The inline code at the start of each table row (the row's name)."""
    return set(re.findall(r"^\| `([^`]+)`", page, flags=re.MULTILINE))


def test_every_registered_optimizer_and_its_settings(pages: dict[str, str]) -> None:
    from formation_bench.fields import describe_fields
    from formation_bench.optimizers import OPTIMIZERS

    page = pages["optimizers"]
    names = code_cells(page)
    assert set(OPTIMIZERS) <= names
    for name in OPTIMIZERS:
        cls = type(OPTIMIZERS[name].optimizer)
        assert f"\n## {cls.__name__}\n" in page
        section = page.split(f"\n## {cls.__name__}\n")[1].split("\n## ")[0]
        assert {info.name for info in describe_fields(cls)} <= code_cells(section) | {
            re.sub(r"\\", "", group) for group in re.findall(r"\*\*(.+?)\*\* \(group\)", section)
        }


def test_a_configuration_lists_what_it_changes(pages: dict[str, str]) -> None:
    from formation_bench.optimizers import OPTIMIZERS

    extension = load_extension()
    for name in OPTIMIZERS:
        optimizer = OPTIMIZERS[name].optimizer
        changes = extension.changed_settings(optimizer, type(optimizer))
        rows = [
            line for line in pages["optimizers"].splitlines() if line.startswith(f"| `{name}` |")
        ]
        # the summary table's row, then the row of its class's configurations
        assert len(rows) == 2
        assert all(f"`{field}=" in rows[1] for field, _ in changes)
        assert bool(changes) != rows[1].endswith("| (defaults) |")


def test_every_registered_scenario_and_setting(pages: dict[str, str]) -> None:
    from formation_bench.fields import describe_fields
    from formation_bench.mpc.scenario import GROUPS, SCENARIOS, Scenario

    page = pages["scenarios"]
    names = code_cells(page)
    assert set(SCENARIOS) <= names
    for group, group_class in GROUPS.items():
        assert f"**{group}** (group)" in page
        assert {f"{group}.{info.name}" for info in describe_fields(group_class)} <= names
    top_level = {info.name for info in describe_fields(Scenario) if info.name not in GROUPS}
    assert top_level <= names


def test_every_record_and_trace_column(pages: dict[str, str]) -> None:
    from formation_bench.mpc.metrics import metric_infos
    from formation_bench.pipeline.record import record_columns
    from formation_bench.pipeline.trace_columns import TRACE_COLUMNS

    page = pages["columns"]
    record, trace = page.split("## Trace columns")
    for name, _, _ in record_columns():
        assert f"`{name}`" in record
    for info in metric_infos():
        assert f"`{info.name}" in record
    for column in TRACE_COLUMNS:
        assert f"`{column.name}`" in trace


def test_every_shipped_suite_and_suite_key(pages: dict[str, str]) -> None:
    from formation_bench.experiments import suite

    page = pages["suites"]
    for name in suite.shipped_suites():
        loaded = suite.load_suite(name)
        row = next(line for line in page.splitlines() if line.startswith(f"| `{name}` |"))
        assert row.rstrip(" |").endswith(str(len(loaded.runs())))
    keys = (
        suite.TOP_LEVEL_FIELDS + suite.TABLE_FIELDS + suite.OPTIMIZER_FIELDS
        + suite.SCENARIO_FIELDS + suite.BUDGET_FIELDS
    )  # fmt: skip
    for key in keys:
        assert f"`{key}`" in page


def test_every_command_and_option(pages: dict[str, str]) -> None:
    from formation_bench.cli.main import build_parser

    page = pages["cli"]

    def check(parser: argparse.ArgumentParser, prog: str) -> None:
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, sub in action.choices.items():
                    assert f"`{prog} {name}`" in page
                    check(sub, f"{prog} {name}")
            for flag in action.option_strings:
                assert f"`{flag}" in page

    check(build_parser(), "formation-bench")


def test_the_committed_cli_page_is_the_generated_one() -> None:
    extension = load_extension()
    committed = ROOT / "docs" / extension.CLI_PAGE
    assert extension.cli_page_is_current(committed), (
        f"{committed.relative_to(ROOT)} differs from the command line's parser; rewrite it "
        f"with: {extension.REGENERATE_CLI}"
    )


def test_the_cli_page_does_not_depend_on_the_terminal(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    extension = load_extension()
    pages = []
    for columns in ("60", "200"):
        monkeypatch.setenv("COLUMNS", columns)
        pages.append(extension.cli_page())
    assert pages[0] == pages[1]


def test_a_stale_or_missing_page_is_found(tmp_path: Path) -> None:
    extension = load_extension()
    page = tmp_path / "cli.md"
    page.write_text(
        extension.page_text(extension.cli_page).replace("`--out OUT`", "`--output OUT`"),
        encoding="utf-8",
    )
    assert not extension.cli_page_is_current(page)
    assert not extension.cli_page_is_current(tmp_path / "missing.md")


def test_the_budgets_default_reads_as_typed(pages: dict[str, str]) -> None:
    """``score --budgets`` defaults to the word a user types for the optimiser's own budget,
    never to Python's ``None``."""
    row = next(line for line in pages["cli"].splitlines() if line.startswith("| `--budgets"))
    assert row.split(" | ")[1] == "`default`"
    assert "None" not in pages["cli"]


def test_rst_in_docstrings_becomes_markdown() -> None:
    extension = load_extension()
    assert extension.rst_text("see :class:`~a.b.Config` and ``x | y``, a_b") == (
        r"see `Config` and `x \| y`, a\_b"
    )
