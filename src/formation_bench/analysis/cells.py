"""How the Markdown tables of the report, its sections and the variant pairs print numbers."""

from __future__ import annotations

import math


def number_cell(value: float | None) -> str:
    """A statistic: whole numbers and values of 1000 or more without decimals, else four
    significant digits; ``–`` for a missing or infinite value."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if abs(value) >= 1000 or float(value).is_integer():
        return f"{value:.0f}"
    return f"{value:.4g}"


def p_cell(value: float | None) -> str:
    """A p-value: scientific below 0.001, else three decimals; ``–`` when there is none."""
    if value is None or not math.isfinite(value):
        return "–"
    return f"{value:.2e}" if value < 1e-3 else f"{value:.3f}"
