"""The numbers of the results pages: regenerate each page and compare its table values.

Run ``python -m perf.page_numbers`` from a checkout. Each page under ``docs/results/`` that
``formation-bench report`` wrote names its command in the comment above every table
(``<!-- produced by: formation-bench report RESULTS ... --page docs/results/NAME.md ... -->``).
When RESULTS is here (``results/`` of the checkout), the page is copied into a temporary
folder and the recorded command is run on the copy (``--page COPY --overwrite``, which keeps
the page's findings, with ``--out`` a temporary report folder so that RESULTS is left as it is,
and ``--no-figures``: figures hold no table values). Then the values of the copy's tables are
compared with the committed page's, and one line per page is printed: its tables, its values,
and the values that differ (listed), or ``results not here``.

The values (:func:`page_values`) are what a change of layout or wording keeps: every number
printed in a table body cell, normalised (:func:`normalise`), pooled over the page as a
multiset, a column printed twice (the same cells beside the same row labels) counted once.
Headers and text are left out, so tables may be split (repeating their label and count
columns), merged, moved, their rows and columns reordered, their headings and headers
reworded; any number that changes, appears or disappears shows. Left out too, because they
differ between two runs of the same thing: the columns (and rows) of timing values
(:data:`TIMING`), and provenance columns (dates, commits, machines: :data:`PROVENANCE`).
tests/test_page_numbers.py uses the same functions on pages it makes, and :func:`csv_values`
on the CSV files a report writes beside its Markdown.
"""

from __future__ import annotations

import argparse
import csv
import math
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
from collections import Counter
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from decimal import Decimal
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
"""The checkout: the recorded commands name their results folders relative to it."""
PAGES = ROOT / "docs" / "results"

TIMING = re.compile(
    r"solve[ _]time|wall[ _]time|run[ _]time|\bsgm\b|deadline[ _]miss|\bseconds\b", re.IGNORECASE
)
"""Headers, row labels and CSV column names of machine-dependent values: solve and wall
times, their shifted geometric means, deadline misses. Deliberately narrower than "time":
settling time and the time spent within the safety radius are outcomes of the run, not of
the machine. A timing header reworded so that this no longer matches makes its values show
as differences (never hides a changed number)."""
PROVENANCE = re.compile(
    r"^(date|commit|version|machine|command|commands|tuner|platform|python)$", re.IGNORECASE
)
"""CSV columns and table headers that say where and when, not what was measured."""
NUMBER = re.compile(r"[-+\u2212]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][-+\u2212]?\d+)?%?")
"""A number as printed: sign, digits, decimals, exponent, percent sign."""
SEPARATORS = re.compile(r"[\s,;:()\[\]{}/=<>|\u2013\u2014]+")
"""What separates the numbers of a cell (``81.4 [65.9, 93.6]``, ``586/588``,
``population_size=13``); a token glued to letters (``A12``, ``d12``, ``swarm-5``) is a name,
not a number."""
TIMING_FILES = ("score_profile.csv",)
"""CSV files all of whose values come from timings though no column says so: the performance
profile of solve time (the share of problems each optimiser solves within a factor of the
fastest time)."""
CSV_DIGITS = 6
"""Significant digits a CSV float is compared at: the files hold full precision, whose last
digits a harmless change of summation order may move; six are far more than any page prints."""


@dataclass(frozen=True)
class Table:
    """A table of a page or a CSV file: its header cells and the cells of each body row."""

    header: list[str]
    rows: list[list[str]]


# --- extracting ---------------------------------------------------------------------------


def normalise(token: str) -> str:
    """A printed number in one canonical form: ``5.00`` and ``5``, ``+4`` and ``4``, ``1e-02``
    and ``0.01`` are the same value; ``92%`` stays apart from ``92``."""
    percent = token.endswith("%")
    body = token.rstrip("%").replace("\u2212", "-").lstrip("+")
    value = Decimal(body).normalize()
    if value.is_zero():
        text = "0"
    elif -12 <= value.adjusted() <= 15:
        text = format(value, "f")
    else:
        text = str(value)
    return text + ("%" if percent else "")


def cell_numbers(cell: str) -> list[str]:
    """The normalised numbers printed in a cell, in order (none in a name or a dash)."""
    found = []
    for token in SEPARATORS.split(cell):
        token = token.rstrip("*").rstrip(".")  # a significance mark, a full stop
        if token and NUMBER.fullmatch(token):
            found.append(normalise(token))
    return found


def _cells(line: str) -> list[str]:
    # a pipe escaped inside a cell does not end it
    return [c.strip() for c in re.split(r"(?<!\\)\|", line.strip().strip("|"))]


def _is_rule(line: str) -> bool:
    return all(re.fullmatch(r":?-+:?", c) for c in _cells(line))


def markdown_tables(text: str) -> list[Table]:
    """Every table of a Markdown text (outside code blocks), in order."""
    tables: list[Table] = []
    block: list[str] = []
    fenced = False
    for line in [*text.splitlines(), ""]:
        if line.lstrip().startswith("```"):
            fenced = not fenced
        if not fenced and line.lstrip().startswith("|"):
            block.append(line)
            continue
        if len(block) >= 2 and _is_rule(block[1]):
            tables.append(Table(_cells(block[0]), [_cells(b) for b in block[2:]]))
        block = []
    return tables


def _dropped_column(name: str) -> bool:
    return bool(TIMING.search(name) or PROVENANCE.match(name.strip()))


Column = tuple[tuple[str, tuple[str, ...]], ...]
"""A column as compared: for each row, its label (first cell) and the column's normalised
numbers in that row, sorted by label (the rows' order is layout)."""


def table_columns(
    table: Table,
    numbers: Callable[[str], list[str]] = cell_numbers,
    timing: Callable[[str], bool] = lambda text: bool(TIMING.search(text)),
) -> list[Column]:
    """The columns of a table (:data:`Column`) but its timing and provenance columns, without
    the rows labelled as timing (a table with metrics as rows); ``numbers`` reads a cell,
    ``timing`` tells a timing name."""
    rows = [
        row
        for row in table.rows
        if not any(timing(cell) for cell in row if cell and not numbers(cell))
    ]
    labels = [row[0] if row else "" for row in rows]
    columns = []
    for k, name in enumerate(table.header):
        if _dropped_column(name) or timing(name):
            continue
        cells = [numbers(row[k]) if k < len(row) else [] for row in rows]
        columns.append(tuple(sorted(zip(labels, map(tuple, cells), strict=True))))
    return columns


def column_values(columns: Iterable[Column]) -> Counter[str]:
    """The multiset of the numbers of ``columns``, a column printed more than once counted
    once: a table split in two that repeats its label and count columns in each part keeps
    the numbers of the table it was."""
    return Counter(v for column in set(columns) for _, cell in column for v in cell)


def page_values(text: str) -> Counter[str]:
    """The multiset of the numbers in the tables of a page (:func:`table_columns`,
    :func:`column_values`)."""
    return column_values(c for table in markdown_tables(text) for c in table_columns(table))


def _is_timing_name(name: str) -> bool:
    from formation_bench.pipeline.record import is_timing_column

    return is_timing_column(name) or bool(TIMING.search(name))


def csv_cell_numbers(cell: str) -> list[str]:
    """The numbers of a CSV cell: a float at :data:`CSV_DIGITS` significant digits, or those
    printed in a label or a settings string; none for an empty, NaN or infinite cell."""
    try:
        value = float(cell)
    except ValueError:
        return cell_numbers(cell)
    if not math.isfinite(value):
        return []
    return [normalise(f"{value:.{CSV_DIGITS}g}")]


def csv_table(path: Path) -> Table:
    """A CSV file as a table (its first line the header)."""
    with open(path, newline="") as handle:
        rows = list(csv.reader(handle))
    return Table(rows[0] if rows else [], rows[1:])


def csv_values(folder: Path) -> Counter[str]:
    """The multiset of the numbers of every CSV file in ``folder`` (a report folder) but the
    :data:`TIMING_FILES`, pooled as a page's tables are (:func:`table_columns`, with the
    column names of the timing metrics as timing names, :func:`column_values`)."""
    paths = [p for p in sorted(folder.glob("*.csv")) if p.name not in TIMING_FILES]
    return column_values(
        c
        for path in paths
        for c in table_columns(csv_table(path), csv_cell_numbers, _is_timing_name)
    )


# --- comparing ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Difference:
    """The values of two multisets that differ: ``missing`` in the new one (with the count
    missing), ``extra`` in it."""

    missing: Counter[str]
    extra: Counter[str]

    def __bool__(self) -> bool:
        return bool(self.missing or self.extra)

    def lines(self, limit: int = 20) -> list[str]:
        """The differences as lines, at most ``limit`` of each kind."""
        out = []
        for label, values in (("only before", self.missing), ("only now", self.extra)):
            shown = sorted(values.items(), key=_numeric_order)[:limit]
            if shown:
                more = len(values) - len(shown)
                listed = ", ".join(v if n == 1 else f"{v} (x{n})" for v, n in shown)
                out.append(f"{label}: {listed}" + (f", ... {more} more" if more > 0 else ""))
        return out


def _numeric_order(item: tuple[str, int]) -> tuple[float, str]:
    try:
        return float(item[0].rstrip("%")), item[0]
    except ValueError:
        return math.inf, item[0]


def difference(before: Counter[str], now: Counter[str]) -> Difference:
    """What differs between two multisets of values."""
    return Difference(before - now, now - before)


# --- the pages of the checkout -------------------------------------------------------------


PRODUCED_BY = re.compile(r"<!-- produced by: (.*?); machine:")
RUNS = re.compile(r"^(\d+) runs; compared", re.MULTILINE)
"""The count of runs a page's headline section starts with."""


def recorded_command(text: str) -> list[str] | None:
    """The ``formation-bench report`` command a page records above its tables, split into its
    words; None when the page records none (a page of other commands' tables)."""
    for match in PRODUCED_BY.finditer(text):
        words = shlex.split(match.group(1))
        if words[:2] == ["formation-bench", "report"]:
            return words
    return None


def regeneration_args(command: list[str], page: Path, report: Path) -> list[str]:
    """The arguments of ``formation-bench`` that write the page of ``command`` to ``page``,
    and its report folder to ``report``."""
    args = []
    words = iter(command[1:])
    for word in words:
        if word in ("--page", "--out"):
            next(words, None)
        elif word not in ("--overwrite", "--figures", "--no-figures"):
            args.append(word)
    return [*args, "--page", str(page), "--out", str(report), "--overwrite", "--no-figures"]


@dataclass(frozen=True)
class Outcome:
    """One page's comparison: its table and value counts and the difference, or why there is
    none (``reason``; with a difference, what may explain it)."""

    name: str
    tables: int = 0
    values: int = 0
    difference: Difference | None = None
    reason: str = ""


def compare_page(page: Path, work: Path) -> Outcome:
    """Regenerate ``page`` into ``work`` from its recorded command and compare its values."""
    text = page.read_text()
    command = recorded_command(text)
    if command is None or len(command) < 3:
        return Outcome(page.stem, reason="no 'formation-bench report' command recorded")
    results = ROOT / command[2]
    if not results.exists():
        return Outcome(page.stem, reason=f"results not here ({command[2]})")
    # a tuning page puts its figure in images/ beside the page's folder: keep it in work/
    copy = work / "results" / page.name
    copy.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(page, copy)
    args = regeneration_args(command, copy, work / f"{page.stem}-report")
    done = subprocess.run(
        [sys.executable, "-m", "formation_bench.cli.main", *args],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    if done.returncode != 0:
        tail = (done.stderr or done.stdout).strip().splitlines()[-3:]
        return Outcome(page.stem, reason=f"the command failed: {' / '.join(tail)}")
    regenerated = copy.read_text()
    before, now = page_values(text), page_values(regenerated)
    runs = [", ".join(RUNS.findall(t)) or "no" for t in (text, regenerated)]
    return Outcome(
        page.stem,
        tables=len(markdown_tables(text)),
        values=sum(before.values()),
        difference=difference(before, now),
        # a sweep still running (or resumed) differs in its numbers for that reason alone
        reason=f"the page counts {runs[0]} runs, the results {runs[1]}"
        if runs[0] != runs[1]
        else "",
    )


def outcome_lines(outcome: Outcome, limit: int) -> Iterator[str]:
    """The printed lines of one page's comparison."""
    if outcome.difference is None:
        yield f"{outcome.name}: {outcome.reason}"
        return
    changed = outcome.difference
    count = sum(changed.missing.values()) + sum(changed.extra.values())
    yield (
        f"{outcome.name}: {outcome.tables} tables, {outcome.values} values, {count} values differ"
    )
    if outcome.reason:
        yield f"  {outcome.reason}"
    for line in changed.lines(limit):
        yield f"  {line}"


def chosen_pages(names: Iterable[str] | None) -> list[Path]:
    """The pages under docs/results/, or those named (by stem)."""
    pages = sorted(PAGES.glob("*.md"))
    if names:
        wanted = set(names)
        pages = [p for p in pages if p.stem in wanted]
    return pages


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m perf.page_numbers", description=__doc__)
    parser.add_argument(
        "--pages", nargs="+", metavar="NAME", help="only these pages (docs/results/NAME.md)"
    )
    parser.add_argument(
        "--show", type=int, default=20, metavar="N", help="differing values listed per kind"
    )
    args = parser.parse_args(argv)
    differ = 0
    with tempfile.TemporaryDirectory(prefix="page-numbers-") as work:
        for page in chosen_pages(args.pages):
            outcome = compare_page(page, Path(work))
            differ += bool(outcome.difference)
            for line in outcome_lines(outcome, args.show):
                print(line, flush=True)
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
