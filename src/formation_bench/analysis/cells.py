"""How the Markdown tables of the report, its sections and the variant pairs print numbers,
and how a metric's column is headed for a reader: its name and the unit it is shown in.

A metric's name, unit and label are declared once, on :class:`~formation_bench.mpc.metrics.
Metrics`; :data:`SHOWN_UNITS` is the one mapping from a declared unit to the unit a table
shows (counts as ``count``, fractions as ``%``), and :func:`metric_column` picks ms or s for
a time from the values it shows. :func:`share_cell` prints every share (success rates, the
share of runs or problems with a property, a fraction metric in %).
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
