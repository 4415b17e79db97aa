"""How the Markdown tables of the report, its sections and the variant pairs print numbers,
and how a metric's column is headed for a reader: its name and the unit it is shown in.

A metric's name, unit and label are declared once, on :class:`~formation_bench.mpc.metrics.
Metrics`; :data:`SHOWN_UNITS` is the one mapping from a declared unit to the unit a table
shows (counts as ``count``, fractions as ``%``), and :func:`metric_column` picks ms or s for
a time from the values it shows. :func:`share_cell` prints every share (success rates, the
share of runs or problems with a property, a fraction metric in %). :class:`Grid` holds a table
before it is printed, and :func:`fit_columns` splits its metric columns into tables of the same
rows that each fit the documentation's content column (:data:`TABLE_WIDTH`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from formation_bench.mpc.metrics import metric_of

COUNT = "count"
SHOWN_UNITS: dict[str, tuple[str, float]] = {
    "solves": (COUNT, 1.0),
    "events": (COUNT, 1.0),
    "plans": (COUNT, 1.0),
    "evaluations": (COUNT, 1.0),
    "fraction": ("%", 100.0),
    "cost": ("m² s", 1.0),
}
"""Declared unit -> (unit shown, factor from the declared to the shown value); a unit not
here (m, s) is shown as declared, a time below one second in ms (:func:`metric_column`)."""

_UNIT_SUFFIX = re.compile(r"(_(m|s))+$")
_TRAILING_BRACKETS = re.compile(r"\s*\([^()]*\)$")


def p_cell(value: float | None) -> str:
    """A p-value: scientific below 0.001, else three decimals; ``–`` when there is none."""
    if value is None or not math.isfinite(value):
        return "–"
    return f"{value:.2e}" if value < 1e-3 else f"{value:.3f}"


def reader_number(value: float | None) -> str:
    """A value for a reader: three significant digits without an exponent, whole numbers
    and values of 100 or more without decimals; ``–`` for a missing or infinite value."""
    if value is None or not math.isfinite(float(value)):
        return "–"
    value = float(value)
    size = abs(value)
    if size >= 100 or value.is_integer():
        return f"{value:.0f}"
    if size >= 10:
        return f"{value:.1f}"
    if size >= 1:
        return f"{value:.2f}"
    decimals = 2 - math.floor(math.log10(size))
    return f"{value:.{decimals}f}"


def share_cell(share: float, total: float | None = None) -> str:
    """A share (0 to 1) as a percentage that reads 100 or 0 only when the share is exactly 1
    or 0; ``–`` when there is none.

    With ``total``, the number of things the share is of (problems, runs), a whole percentage
    with its sign (``92%``) or, where that would round to ``100%`` or ``0%``, the count
    ``k/total`` (``587/588``; ``586.5/588`` when a problem's trials are averaged). Without it,
    the number of percent for a column headed in %: three significant digits
    (:func:`reader_number`), with more decimals where those would read 100 (``99.96``).
    """
    if share is None or not math.isfinite(float(share)):
        return "–"
    share = float(share)
    if total is not None:
        text = f"{share:.0%}"
        if text in ("0%", "100%") and share not in (0.0, 1.0):
            return f"{round(share * total, 2):g}/{total:g}"
        return text
    text = reader_number(100 * share)
    decimals = 1
    while share < 1.0 and float(text) >= 100 and decimals < 15:
        text = f"{100 * share:.{decimals}f}"
        decimals += 1
    return text


@dataclass(frozen=True)
class MetricColumn:
    """A metric's column as a table shows it: its reader's name, its unit, and the factor
    from the stored value to the shown one."""

    column: str
    name: str
    unit: str
    scale: float

    @property
    def header(self) -> str:
        """``name (unit)``."""
        return f"{self.name} ({self.unit})" if self.unit else self.name

    def value(self, stored: float | None) -> str:
        """A stored value in the shown unit."""
        if stored is None or not math.isfinite(float(stored)):
            return "–"
        if self.unit == "%":
            return share_cell(float(stored) * self.scale / 100)
        return reader_number(float(stored) * self.scale)

    def with_unit(self, stored: float | None) -> str:
        """A stored value in the shown unit, the unit after it unless it is a count."""
        text = self.value(stored)
        if text == "–" or self.unit in ("", COUNT):
            return text
        return f"{text} %" if self.unit == "%" else f"{text} {self.unit}"


def metric_name(column: str) -> str:
    """A metric column's name for a reader: its declared label without the unit in brackets,
    else its name in words without the unit suffix (``solve time p95``, ``solves uav1``)."""
    info = metric_of(column)
    if info is None:
        return column
    if column == info.name and info.label is not None:
        return _TRAILING_BRACKETS.sub("", info.label)
    stem = _UNIT_SUFFIX.sub("", info.name)
    item = column.removeprefix(info.name).lstrip("_")
    return " ".join(part for part in (stem.replace("_", " "), item) if part)


def metric_column(column: str, values: Iterable[float] = ()) -> MetricColumn:
    """The column of ``column`` for a table showing ``values`` (stored values): a time in ms
    when every finite value is below one second (and one is not 0), else as declared
    (:data:`SHOWN_UNITS`)."""
    info = metric_of(column)
    unit = "" if info is None else info.unit
    shown, scale = SHOWN_UNITS.get(unit, (unit, 1.0))
    if unit == "s":
        finite = np.asarray([v for v in values if v is not None], dtype=float)
        finite = finite[np.isfinite(finite)]
        if finite.size and 0 < np.abs(finite).max() < 1.0:
            shown, scale = "ms", 1000.0
    return MetricColumn(column, metric_name(column), shown, scale)


# --- fitting a table into the documentation's content column ---------------------------------

TABLE_WIDTH = 96
"""The widest table the report writes, in characters of :func:`column_width`: the results
pages are read in the documentation site's content column, 833 px at a 1280 px window
(docs/_static/site.css), where a table cannot shrink below the sum of its columns' longest
unbreakable words. Measured there, one character of this estimate takes at most 8.1 px
(wide glyphs, bold headers, the cells' padding and borders), so 96 leaves a margin of about
7 %. A table of more metrics continues in further tables of the same rows."""
COLUMN_PADDING = 2
"""What a column takes beside its longest word, in characters: the cell's padding and
borders."""

# a browser breaks a line at a space, or after a hyphen between letters (``steady-state``,
# ``modified-bso``), never inside a number (``1.2e-05``)
_WORD_BREAK = re.compile(r"\s+|(?<=[^\W\d_]-)(?=[^\W\d_])")


def column_width(texts: Iterable[str]) -> int:
    """The narrowest a column holding ``texts`` (its header and cells) can be, in
    characters: its longest unbreakable word and its padding."""
    words = (word for text in texts for word in _WORD_BREAK.split(text))
    return max((len(word) for word in words), default=0) + COLUMN_PADDING


def split_columns(widths: list[int], room: int) -> list[list[int]]:
    """The indices of columns of ``widths`` in consecutive groups, each within ``room``
    characters where it can be (a column wider than that is a group of its own): as few
    groups as a greedy fill needs, the widest of them as narrow as can be, so that a split
    table is not a full table and a stub."""
    if not widths:
        return []
    fewest = len(_pack(widths, room))
    smallest = max(-(-sum(widths) // fewest), min(max(widths), room))
    for capacity in range(smallest, room + 1):
        groups = _pack(widths, capacity)
        if len(groups) <= fewest:
            return groups
    return _pack(widths, room)


def _pack(widths: list[int], capacity: int) -> list[list[int]]:
    """Columns in order, a new group whenever the next one would pass ``capacity``."""
    groups: list[list[int]] = []
    used = capacity + 1  # the first column opens a group
    for index, width in enumerate(widths):
        if used + width > capacity:
            groups.append([])
            used = 0
        groups[-1].append(index)
        used += width
    return groups


@dataclass(frozen=True)
class Grid:
    """A Markdown table before it is printed: ``lead`` columns that name the row (repeated in
    every part of a split table), then the value columns; the first ``left`` columns are
    left-aligned, the others (numbers) right-aligned."""

    head: list[str]
    rows: list[list[str]]
    lead: int = 1
    left: int = 1

    def widths(self) -> list[int]:
        """:func:`column_width` of each value column."""
        columns = zip(self.head, *self.rows, strict=True)
        return [column_width(texts) for texts in list(columns)[self.lead :]]

    def lead_width(self) -> int:
        """:func:`column_width` of the lead columns together."""
        columns = list(zip(self.head, *self.rows, strict=True))[: self.lead]
        return sum(column_width(texts) for texts in columns)

    def select(self, indices: list[int]) -> Grid:
        """The lead columns and the value columns at ``indices``."""
        keep = [*range(self.lead), *(self.lead + k for k in indices)]
        return Grid(
            [self.head[k] for k in keep],
            [[row[k] for k in keep] for row in self.rows],
            self.lead,
            self.left,
        )

    def lines(self) -> list[str]:
        """The table in Markdown."""
        rule = "|" + "---|" * self.left + "---:|" * (len(self.head) - self.left)
        return [_markdown_row(self.head), rule, *(_markdown_row(row) for row in self.rows)]


def _markdown_row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def fit_columns(grids: Iterable[Grid]) -> list[list[int]]:
    """The value columns that ``grids`` share (same count, same metrics) in groups whose
    tables each fit :data:`TABLE_WIDTH` (:func:`split_columns`): a column as wide as the
    widest of its cells in any of them, beside the widest lead."""
    grids = list(grids)
    if not grids:
        return []
    widths = [max(column) for column in zip(*(g.widths() for g in grids), strict=True)]
    return split_columns(widths, TABLE_WIDTH - max(g.lead_width() for g in grids))


def fitted(grid: Grid) -> list[Grid]:
    """``grid`` split into tables that fit :data:`TABLE_WIDTH`, the lead in each."""
    return [grid.select(group) for group in fit_columns([grid])]
