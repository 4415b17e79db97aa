"""The numbers of every kind of results page, against a committed snapshot.

Each kind of page (tests/page_numbers.py builds its results: the paper scenario; the swarm,
robustness and obstacles sections; the leaderboard; the tuning report) is written with
``formation-bench report --page``, and the numbers of its tables and of the CSV files of its
report folder are compared with tests/data/page_numbers/KIND.json, as multisets
(perf/page_numbers.py: layout, headers and wording may change, the numbers may not; timing
and provenance are left out). A change of the report code that moves no number passes; one
that changes, adds or drops a number fails and lists it.

The snapshots are made by the code of their commit. To make them anew, after a change that is
meant to change the numbers (of the simulation, the optimisers, the statistics or the
library), or after a change of the environment that moves them (numpy, scipy, numba, optuna,
whose sampler makes the tunings):

    PAGE_NUMBERS_REWRITE=1 pytest tests/test_page_numbers.py -m "slow or not slow"

which writes every snapshot and skips the comparisons.
"""

from __future__ import annotations

import json
import os
from collections import Counter
from pathlib import Path

import pytest
from page_numbers import BUILDERS, render

from perf.page_numbers import (
    cell_numbers,
    csv_values,
    difference,
    markdown_tables,
    page_values,
)

SNAPSHOTS = Path(__file__).parent / "data" / "page_numbers"
REWRITE = "PAGE_NUMBERS_REWRITE"
"""Set (to anything but empty or 0) to write the snapshots instead of comparing."""
PARTS = ("page", "csv")
"""What a snapshot holds: the page's table numbers, the report folder's CSV numbers."""


def snapshot_path(kind: str) -> Path:
    return SNAPSHOTS / f"{kind}.json"


def read_snapshot(path: Path) -> dict[str, Counter[str]]:
    data = json.loads(path.read_text())
    return {part: Counter(data[part]) for part in PARTS}


def write_snapshot(path: Path, found: dict[str, Counter[str]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    data = {
        "about": "numbers of a results page's tables and its report's CSV files, each with its "
        "count; made by tests/test_page_numbers.py with PAGE_NUMBERS_REWRITE=1",
        **{part: dict(sorted(found[part].items())) for part in PARTS},
    }
    path.write_text(json.dumps(data, indent=0, ensure_ascii=False) + "\n")


def snapshot_problems(
    expected: dict[str, Counter[str]], found: dict[str, Counter[str]]
) -> list[str]:
    """What differs between a snapshot and the numbers found, as lines; empty if nothing."""
    problems = []
    for part in PARTS:
        changed = difference(expected[part], found[part])
        if changed:
            problems += [f"{part}: {line}" for line in changed.lines()]
    return problems


def rewriting() -> bool:
    return os.environ.get(REWRITE, "") not in ("", "0")


# --- the pages -----------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(BUILDERS))
def test_a_results_page_keeps_the_numbers_of_its_snapshot(kind, tmp_path):
    if kind == "tuning":
        pytest.importorskip("optuna")
    results = BUILDERS[kind](tmp_path)
    page, report = render(results, tmp_path)
    found = {"page": page_values(page.read_text()), "csv": csv_values(report)}
    # a page without numbers would pass against an empty snapshot: the builder went wrong
    assert sum(found["page"].values()) > 20 and sum(found["csv"].values()) > 20
    path = snapshot_path(kind)
    if rewriting():
        write_snapshot(path, found)
        pytest.skip(f"{REWRITE} is set: wrote {path}")
    problems = snapshot_problems(read_snapshot(path), found)
    assert not problems, (
        f"the numbers of the {kind} page differ from {path} (only before: in the snapshot, "
        f"not on the page; only now: the reverse):\n" + "\n".join(problems)
    )


def test_every_kind_of_page_has_a_snapshot():
    assert sorted(p.stem for p in SNAPSHOTS.glob("*.json")) == sorted(BUILDERS)


def test_a_changed_number_in_a_snapshot_fails_the_comparison():
    # the committed snapshot against a copy with one value changed, as a page with that
    # number changed would be
    expected = read_snapshot(snapshot_path("tuning"))
    changed = {part: Counter(values) for part, values in expected.items()}
    value = next(v for v in sorted(changed["page"]) if "." in v)
    changed["page"][value] -= 1
    changed["page"][value + "1"] += 1
    problems = snapshot_problems(expected, changed)
    assert problems == [f"page: only before: {value}", f"page: only now: {value}1"]
    assert snapshot_problems(expected, expected) == []


# --- the values of a page ------------------------------------------------------------------

WIDE = """\
## Block a

<!-- produced by: formation-bench report results/x --page p.md --overwrite; machine: M -->

| optimizer | runs | cost (m² s) | median solve time (ms) | settling time (s) |
|---|---:|---:|---:|---:|
| pso | 30 | 81.4 [65.9, 93.6] | 0.469 | 45.3 (n 24) |
| de | 30 | 1.07e-02 | 0.312 | – |
| Friedman p | – | 2.17e-05 (5) | 1.33e-05 (5) | 0.050 (5) |
"""

SPLIT = """\
## Block a: the costs

| configuration | cost, eq. (11) (m² s) | runs |
|:--|--:|--:|
| pso | 81.4 [65.9, 93.6] | 30 |
| de | 0.0107 | 30 |
| Friedman p | 2.17e-5 (5) | – |

Text between the tables, with numbers that are not in a table: 12.5, 3.

## Block a: the start-up

| configuration | runs | settling time, s |
|---|---|---|
| de | 30 | – |
| Friedman p | – | 0.05 (5) |
| pso | 30 | 45.3 (n 24) |
"""
"""WIDE split in two, both parts repeating the label and runs columns, its rows and columns
reordered, its headers reworded, its solve times left out, its numbers printed otherwise."""


def test_a_table_split_reordered_and_reworded_keeps_its_values():
    assert len(markdown_tables(WIDE)) == 1 and len(markdown_tables(SPLIT)) == 2
    assert page_values(WIDE) == page_values(SPLIT)
    assert page_values(WIDE)["30"] == 2  # the runs column, counted once
    # the solve times are left out, the settling times kept
    assert "0.469" not in page_values(WIDE) and "45.3" in page_values(WIDE)
    changed = difference(page_values(SPLIT), page_values(SPLIT.replace("65.9", "65.8")))
    assert (changed.missing, changed.extra) == (Counter(["65.9"]), Counter(["65.8"]))
    dropped = difference(page_values(SPLIT), page_values(SPLIT.replace("0.0107", "–")))
    assert dropped.missing == Counter(["0.0107"]) and not dropped.extra
    # one of the two runs columns changed: both count now, and the change shows
    moved = difference(
        page_values(SPLIT), page_values(SPLIT.replace("| pso | 30 | 45", "| pso | 31 | 45"))
    )
    assert moved.extra == Counter(["30", "31"]) and not moved.missing


def test_numbers_are_normalised_and_names_are_not_numbers():
    assert cell_numbers("0.438, A12 0.88") == ["0.438", "0.88"]
    assert cell_numbers("5.00 vs 5, 1e-02 *") == ["5", "5", "0.01"]
    assert cell_numbers("92% and 92 and +4 and -6") == ["92%", "92", "4", "-6"]
    assert cell_numbers("not reached (0/3 at 1200 evaluations)") == ["0", "3", "1200"]
    assert cell_numbers("population_size=13, c1=2.304") == ["13", "2.304"]
    assert cell_numbers("swarm-5 N5-ring d12 modified-bso –") == []


def test_timing_and_provenance_are_left_out_and_outcomes_kept():
    page = """\
| variant | date | seed | tuned value | wall time | time pairs spent within the safety radius (ms) |
|---|---|---:|---:|---:|---:|
| pso-tuned | 2026-11-28 | 100 | 0.1125 | 14.1 min | 600 |

| quantity | value |
|---|---:|
| sum of its solve times | 3.5 |
| sgm, failures charged (ms) | 436.0 |
| collisions per run | 2 |
"""
    assert page_values(page) == Counter(["100", "0.1125", "600", "2"])


def test_csv_values_leave_out_timing_columns_and_rows_and_round_floats(tmp_path):
    (tmp_path / "summary.csv").write_text(
        "optimizer,metric,n,median,solve_time_median_s,commit\n"
        "pso[max_iterations=2],tracking_error_max_m,3,10.217680305656266,0.0013,0a1b2c3\n"
        "pso[max_iterations=2],solve_time_median_s,3,0.00013,0.0013,0a1b2c3\n"
        "pso[max_iterations=2],steady_state_cost,3,nan,0.0013,0a1b2c3\n"
    )
    (tmp_path / "notes.csv").write_text("note\nnot applicable: needs 3 or more levels\n")
    assert csv_values(tmp_path) == Counter({"2": 2, "3": 3, "10.2177": 1})
