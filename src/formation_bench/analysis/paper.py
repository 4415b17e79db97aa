"""The paper's reported figures (Section 3) and the table that sets a run beside them."""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any


class Reading(enum.StrEnum):
    """From when a run's largest errors are counted before they are set beside the paper's."""

    SETTLE_TIME = "settle-time"
    """From the scenario's fixed settle time (10 s in the paper scenario)."""
    SETTLING = "settling"
    """From the run's own settling time (``settling_time_s``); a run that does not settle
    misses every error figure."""


@dataclass(frozen=True)
class PaperFigure:
    """One reported figure: an upper bound on a metric of one of the two runs."""

    trigger: bool
    """Which run: with (True) or without (False) the event trigger."""
    label: str
    """What the paper reports, in words."""
    limit: float
    """The paper's bound (the metric must be <= it)."""
    unit: str
    """Unit of the bound and the value, for the table."""
    column: str
    """The record's column it bounds (:class:`~formation_bench.pipeline.record.RunRecord`)."""
    decimals: int = 3
    """Decimals the table shows of the measured value (0 for a count)."""

    @property
    def label_with_unit(self) -> str:
        """The label with the unit in its parentheses: ``tracking error max (m)``,
        ``UAV 1 solves (of 240; paper: 157)``."""
        what, opened, note = self.label.partition(" (")
        return f"{what} ({self.unit}; {note}" if opened else f"{what} ({self.unit})"

    def shown(self, value: float) -> str:
        """A measured value as the table prints it, e.g. ``0.395`` or ``97``."""
        return f"{value:.{self.decimals}f}"

    def column_for(self, reading: Reading) -> str:
        """The column holding this figure's value in ``reading`` (solve counts have one)."""
        if reading is Reading.SETTLING and "_error_max_m" in self.column:
            return self.column.replace("_error_max_m", "_error_max_settled_m")
        return self.column

    def measured(self, record: Mapping[str, Any], reading: Reading = Reading.SETTLE_TIME) -> float:
        """The value of a run's record (a ``metrics.json`` entry or a stored row)."""
        return float(record[self.column_for(reading)])

    def holds(self, record: Mapping[str, Any], reading: Reading = Reading.SETTLE_TIME) -> bool:
        """Whether the run meets the paper's bound (NaN, a run that never settles, does not)."""
        return bool(self.measured(record, reading) <= self.limit)


PAPER_FIGURES: tuple[PaperFigure, ...] = (
    PaperFigure(False, "tracking error max", 1.25, "m", "tracking_error_max_m"),
    PaperFigure(False, "d12 error max", 0.2, "m", "distance_error_max_m_d12"),
    PaperFigure(False, "d23 error max", 0.2, "m", "distance_error_max_m_d23"),
    PaperFigure(False, "d31 error max", 0.2, "m", "distance_error_max_m_d31"),
    PaperFigure(True, "tracking error max", 1.4, "m", "tracking_error_max_m"),
    PaperFigure(True, "d12 error max", 0.3, "m", "distance_error_max_m_d12"),
    PaperFigure(True, "d23 error max", 0.3, "m", "distance_error_max_m_d23"),
    PaperFigure(True, "d31 error max", 0.25, "m", "distance_error_max_m_d31"),
    # The paper reports 157/155/160 solves of 240 and claims at most two thirds.
    PaperFigure(True, "UAV 1 solves (paper: 157)", 160, "of 240", "solves_uav1", decimals=0),
    PaperFigure(True, "UAV 2 solves (paper: 155)", 160, "of 240", "solves_uav2", decimals=0),
    PaperFigure(True, "UAV 3 solves (paper: 160)", 160, "of 240", "solves_uav3", decimals=0),
)


def comparison_rows(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per paper figure for a seed's two run records: run, the paper's bound, the
    measured value, whether it holds."""
    by_trigger = {bool(r["trigger"]): r for r in runs}
    rows = []
    for figure in PAPER_FIGURES:
        record = by_trigger.get(figure.trigger)
        if record is None:
            continue
        value = figure.measured(record)
        rows.append(
            {
                "run": "with trigger" if figure.trigger else "without trigger",
                "figure": figure.label,
                "figure_with_unit": figure.label_with_unit,
                "paper": figure.limit,
                "unit": figure.unit,
                "measured": value,
                "shown": figure.shown(value),
                "holds": value <= figure.limit,
            }
        )
    return rows


def format_table(rows: list[dict[str, Any]]) -> str:
    """A plain-text table of :func:`comparison_rows`: each figure with its unit, the paper's
    bound, the measured value and whether the bound holds."""
    header = ("run", "figure", "paper", "measured", "holds")
    bounds = _on_point([f"{row['paper']:g}" for row in rows])
    cells = [header] + [
        (
            row["run"],
            row["figure_with_unit"],
            f"<= {bound}",
            row["shown"],
            "yes" if row["holds"] else "NO",
        )
        for row, bound in zip(rows, bounds, strict=True)
    ]
    widths = [max(len(line[k]) for line in cells) for k in range(len(header))]
    right = {"paper", "measured"}  # numbers: aligned on their last digit, bounds on the point
    lines = [
        "  ".join(
            f"{text:>{width}}" if name in right else f"{text:<{width}}"
            for name, text, width in zip(header, line, widths, strict=True)
        ).rstrip()
        for line in cells
    ]
    lines.insert(1, "-" * max(map(len, lines)))
    return "\n".join(lines)


def _on_point(numbers: list[str]) -> list[str]:
    """Numbers padded to one width with their decimal points (or ends) in one column."""
    parts = [number.partition(".") for number in numbers]
    whole = max(len(w) for w, _, _ in parts)
    fraction = max(len(dot + f) for _, dot, f in parts)
    return [f"{w:>{whole}}{dot + f:<{fraction}}" for w, dot, f in parts]


def format_seed_table(rows_by_seed: dict[int, list[dict[str, Any]]]) -> str:
    """A Markdown table: every paper figure, its value at each seed, and on how many it holds."""
    seeds = list(rows_by_seed)
    first = rows_by_seed[seeds[0]]
    header = ["run", "figure", "paper", *(f"seed {s}" for s in seeds), "holds on"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for k, row in enumerate(first):
        values = [rows_by_seed[s][k] for s in seeds]
        held = sum(v["holds"] for v in values)
        cells = [
            row["run"],
            row["figure"],
            f"<= {row['paper']:g} {row['unit']}",
            *(f"{v['measured']:.3g}" + ("" if v["holds"] else " ✗") for v in values),
            f"{held}/{len(seeds)}",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)
