"""Each optimiser variant against the configuration it varies, paired by seed.

A registered variant named ``<base><suffix>`` (for example ``pso-warm``, which starts part
of its population around the warm start, or ``pso-tuned``, its settings tuned) is compared
with ``<base>`` (``pso``) wherever a block of the results (scenario, trigger, budget) holds
both, on every headline metric the runs carry: median of each, the median of the paired
differences, Wilcoxon signed-rank (two-sided) Holm-adjusted over the pairs of one kind
(:data:`VARIANT_KINDS`) in a block and metric, and the Vargha-Delaney A12 = P(variant > base)
(below 0.5: the variant's values are lower). A metric none of the runs of one of the two has
(a settling time where no run settled) has no pairs: no test, and that level's median shows
as missing with its count of runs with a value, ``– (n 0)``. The closed-loop counterpart of
the score report's paired table.
"""

from __future__ import annotations

from dataclasses import dataclass

import pandas as pd

from formation_bench.analysis import stats
from formation_bench.analysis.cells import Grid, MetricColumn, fitted, metric_column, p_cell
from formation_bench.analysis.comparison import prepare
from formation_bench.mpc.metrics import headline_metrics


@dataclass(frozen=True)
class VariantKind:
    """A kind of variant: its name ending and how the reports name its comparison."""

    suffix: str
    comparison: str
    """The kind of paired comparison, as the score report's paired table names it."""
    what: str
    """What the variant changes, for the text above a table of its pairs."""


VARIANT_KINDS = (
    VariantKind("-warm", "warm start against uniform start",
                "part of the population started around the warm start"),
    VariantKind("-tuned", "tuned against default", "settings tuned per solve"),
    VariantKind("-tuned-loop", "tuned for the loop against default",
                "settings tuned on a closed-loop metric"),
)  # fmt: skip
"""The variants compared with the configuration they vary, in the order the reports list
their kinds."""
VARIANT_SUFFIXES = tuple(kind.suffix for kind in VARIANT_KINDS)
"""Name endings of the variants compared with the configuration they vary."""
BLOCK = ["scenario", "trigger", "budget"]
MEDIANS = ("variant_median", "base_median")
NO_VALUE = "(n 0)"
"""After the median of a level none of whose runs has a value: the count of its runs with
one, written as the report's tables write it where some runs have none."""


def variant_kind(level: str, suffixes: tuple[str, ...] = VARIANT_SUFFIXES) -> str | None:
    """The suffix that makes ``level`` a variant: the longest of ``suffixes`` it ends with
    (``pso-warm-tuned`` is a tuned ``pso-warm``, whichever order the suffixes are in);
    None for a name that ends with none."""
    endings = [s for s in suffixes if level.endswith(s) and len(level) > len(s)]
    return max(endings, key=len) if endings else None


def variant_pairs(levels: list[str], suffixes: tuple[str, ...] = VARIANT_SUFFIXES) -> list:
    """``(variant, base)`` for every level whose base (its name without its suffix,
    :func:`variant_kind`) is a level too, in the order of ``levels``."""
    present = set(levels)
    pairs = []
    for level in levels:
        suffix = variant_kind(level, suffixes)
        if suffix is not None and level[: -len(suffix)] in present:
            pairs.append((level, level[: -len(suffix)]))
    return pairs


def kind_of(variant: str) -> VariantKind:
    """The :class:`VariantKind` of a level :func:`variant_pairs` paired."""
    suffix = variant_kind(variant)
    return next(kind for kind in VARIANT_KINDS if kind.suffix == suffix)


def pair_table(results: pd.DataFrame, metrics: tuple[str, ...] | None = None) -> pd.DataFrame:
    """One row per block, metric (``metrics``, by default the headline ones) and (variant,
    base) pair; empty when no pair applies."""
    frame = prepare(results)
    metrics = headline_metrics() if metrics is None else metrics
    metrics = tuple(m for m in metrics if m in frame)
    rows = []
    for block_values, block in frame.groupby(BLOCK, sort=False):
        levels = sorted(block["optimizer"].unique())
        pairs = variant_pairs(levels)
        for metric in metrics:
            # pivot_table drops a level none of whose runs has a value (a settling time where
            # no run settled): reindexed, such a level has its column, all missing
            table = block.pivot_table(
                index="seed", columns="optimizer", values=metric, aggfunc="first"
            ).reindex(columns=levels)
            found = []
            for variant, base in pairs:
                compared = _compared(table, variant, base)
                found.append(
                    {
                        **dict(zip(BLOCK, block_values, strict=True)),
                        "metric": metric,
                        "kind": kind_of(variant).comparison,
                        "variant": variant,
                        "base": base,
                        "n_pairs": compared.pop("pairs"),
                        "variant_median": compared.pop("x_median"),
                        "base_median": compared.pop("y_median"),
                        "variant_lower": compared.pop("x_lower"),
                        "variant_higher": compared.pop("x_higher"),
                        **compared,
                    }
                )
            for kind in dict.fromkeys(r["kind"] for r in found):
                stats.holm_family([r for r in found if r["kind"] == kind])
            rows.extend(found)
    return pd.DataFrame(rows)


def _compared(table: pd.DataFrame, variant: str, base: str) -> dict[str, float | int]:
    """:func:`~.stats.paired_comparison` of ``variant`` and ``base`` (columns of ``table``,
    seeds as rows) over the seeds where both have a value."""
    pair = table[[variant, base]].dropna()
    compared = stats.paired_comparison(pair[variant], pair[base])
    if not compared["pairs"]:
        # no median over pairs: each over its own runs says which of the two has no value
        # (missing only for a level none of whose runs has one)
        compared["x_median"], compared["y_median"] = (
            float(table[name].median()) for name in (variant, base)
        )
    return compared


def _no_value(row: pd.Series, median: float) -> bool:
    """Whether ``median`` (of a row of :func:`pair_table`) is missing because no run of its
    level has a value (with pairs, medians are over them and never missing)."""
    return not row["n_pairs"] and pd.isna(median)


def to_markdown(table: pd.DataFrame) -> str:
    """The pairs as Markdown, one table per block: the pairs as rows, the metrics as columns
    (name and unit in the header), each cell ``variant median vs base median, p (Holm),
    A12``; empty text when no pair applies."""
    if table.empty:
        return ""
    lines = ["## Variants against the configuration they vary", "", _intro(table), ""]
    for (scenario, trigger, budget), block in table.groupby(BLOCK, sort=False):
        metrics = list(dict.fromkeys(block["metric"]))
        columns = [
            metric_column(m, block.loc[block["metric"] == m, ["variant_median", "base_median"]]
                          .to_numpy().ravel())
            for m in metrics
        ]  # fmt: skip
        lines += [f"### scenario {scenario}, trigger {trigger}, {budget}", ""]
        rows = []
        for (variant, base), pair in block.groupby(["variant", "base"], sort=False):
            by_metric = pair.set_index("metric")
            cells = [
                _cell(column, by_metric.loc[m]) for m, column in zip(metrics, columns, strict=True)
            ]
            rows.append([variant, base, str(int(by_metric["n_pairs"].max())), *cells])
        grid = Grid(
            ["variant", "base", "pairs", *(c.header for c in columns)], rows, lead=3, left=2
        )
        for part in fitted(grid):  # the pairs in every part, the metrics split to fit the page
            lines += [*part.lines(), ""]
    return "\n".join(lines).rstrip() + "\n"


def _cell(column: MetricColumn, row: pd.Series) -> str:
    """``variant median vs base median, p (Holm), A12``; the median of a level none of whose
    runs has a value is ``– (n 0)``, and a test without pairs ``–``."""
    medians = [
        f"{column.value(median)} {NO_VALUE}" if _no_value(row, median) else column.value(median)
        for median in (row[m] for m in MEDIANS)
    ]
    mark = " *" if row["significant"] else ""
    a12 = "–" if pd.isna(row["a12"]) else f"{row['a12']:.2f}"
    return f"{medians[0]} vs {medians[1]}, {p_cell(row['p_holm'])}{mark}, A12 {a12}"


def _intro(table: pd.DataFrame) -> str:
    """The text above the tables: the kinds of variant they hold and how a cell reads."""
    kinds = [k for k in VARIANT_KINDS if k.comparison in set(table["kind"])]
    if len(kinds) == 1:
        held = f"Each `<name>{kinds[0].suffix}` variant against `<name>`"
        family = "the pairs of the block and metric"
    else:
        held = (
            "Each variant against `<name>`, the configuration it varies ("
            + "; ".join(f"`<name>{k.suffix}`: {k.what}" for k in kinds)
            + ")"
        )
        family = "the pairs of one kind of variant in the block and metric"
    # said only where a cell shows it, so the text above every other table is as it was
    shown = any(_no_value(r, r[m]) for _, r in table.iterrows() for m in MEDIANS)
    missing = f" – {NO_VALUE}: no run of the configuration has a value." if shown else ""
    return (
        f"{held}, paired by seed. A cell: the variant's median vs the base's, the Wilcoxon "
        f"signed-rank p (two-sided, Holm-adjusted over {family}; * below 0.05) and A12 = "
        f"P(variant > base) (< 0.5: lower values than the base).{missing}"
    )
