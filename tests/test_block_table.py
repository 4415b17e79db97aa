"""The report as a reader sees it: one table per block, metrics as columns with units, the
constant metrics on one line; and the dated results page with its produced-by comments."""

import datetime as dt

import numpy as np
import pandas as pd

from formation_bench.analysis.cells import metric_column
from formation_bench.analysis.comparison import analyse
from formation_bench.analysis.report import to_markdown
from formation_bench.analysis.results_page import mark_tables, page_text, suite_provenance
from formation_bench.experiments.manifest import MANIFEST_FORMAT, write_manifest
from formation_bench.experiments.store import ResultStore

OPTIMIZERS = ("modified-bso", "de", "pso")


def runs(seeds: int = 8) -> pd.DataFrame:
    rng = np.random.default_rng(5)
    rows = []
    for trigger in (True, False):
        for k, optimizer in enumerate(OPTIMIZERS):
            for seed in range(seeds):
                rows.append(
                    {
                        "optimizer": optimizer,
                        "trigger": trigger,
                        "budget": "default",
                        "scenario": "paper",
                        "seed": seed,
                        "tracking_error_max_m": 0.5 + k + rng.uniform(0, 0.1),
                        "solve_time_median_s": 0.002 * (k + 1) + rng.uniform(0, 1e-4),
                        "solves_total": 200 + 10 * k + seed,
                        "collisions": 0,
                        "plans_lost": 0,
                    }
                )
    return pd.DataFrame(rows)


def tables_of(section: str) -> list[list[str]]:
    """The Markdown tables of ``section``, each as its lines."""
    found, current = [], []
    for line in section.splitlines():
        if line.startswith("|"):
            current.append(line)
        elif current:
            found.append(current)
            current = []
    return found + ([current] if current else [])


def test_one_values_table_per_block_with_units_and_the_constant_metrics_on_a_line():
    results = runs()
    report = analyse(results)
    text = to_markdown(report, results)
    blocks = text.split("\n## ")[1:]
    assert [b.splitlines()[0] for b in blocks] == ["trigger on", "trigger off"]
    for block in blocks:
        tables = tables_of(block)
        values = [t for t in tables if "| runs |" in t[0]]
        assert len(values) == 1  # one table of values for the block
        header = values[0][0]
        assert "tracking error max after the settle time (m)" in header
        assert "median solve time (ms)" in header  # times below 1 s in ms
        assert "solves per run, all UAVs (count)" in header
        assert [row.split(" | ")[0].strip("| ") for row in values[0][2:]] == list(OPTIMIZERS)
        # collisions and plans lost never vary: no column, named with their value instead
        assert "collisions" not in "\n".join("\n".join(t) for t in tables)
        assert "collisions per run = 0" in block and "plans lost = 0" in block
        # the verdicts have the same rows and columns: ranks (3 levels) and the tests
        ranks = next(t for t in tables if t[-1].startswith("| Friedman p |"))
        tests = next(t for t in tables if "| baseline |" in t[2])
        assert ranks[0] == tests[0] == header.replace(" runs |", "", 1)
        de = next(row for row in tests if row.startswith("| de |"))
        assert "A12 1.00" in de and "*" in de  # de is above modified-bso in every seed


def test_the_shown_values_are_the_statistics_in_the_shown_unit():
    results = runs()
    report = analyse(results)
    text = to_markdown(report, results)
    summary = report.summary.set_index(["trigger", "optimizer", "metric"])
    median = summary.loc[("on", "de", "solve_time_median_s"), "median"]
    column = metric_column("solve_time_median_s", results["solve_time_median_s"])
    assert column.unit == "ms" and column.value(median) == f"{median * 1000:.2f}"
    row = next(line for line in text.splitlines() if line.startswith("| de | 8 |"))
    assert f"| {column.value(median)} [" in row


def test_the_page_names_its_commands_date_and_machine_and_marks_every_table(tmp_path):
    results = runs()
    write_manifest(
        ResultStore(tmp_path),
        {
            "format": MANIFEST_FORMAT,
            "created": "2026-03-01T10:00:00+00:00",
            "updated": "2026-03-02T09:00:00+00:00",
            "sessions": [
                {
                    "state": "done",
                    "command": "/venv/bin/formation-bench sweep paper --out res",
                    "started": "2026-03-01T10:00:00+00:00",
                    "finished": "2026-03-02T09:00:00+00:00",
                }
            ],
            "versions": {"formation-bench": "1.2.3"},
            "machine": {"cpu_model": "Test CPU", "cpu_count": 4},
            "suite": {"name": "paper", "sha256": "0" * 64},
        },
    )
    provenance = suite_provenance(tmp_path, results)
    assert provenance.commands == ("formation-bench sweep paper --out res",)
    assert provenance.dates == ("2026-03-01", "2026-03-02")
    body = to_markdown(analyse(results), results, title="Headline")
    command = "formation-bench report res --page docs/results/paper.md"
    page = page_text(provenance, body, command, today=dt.date(2026, 3, 3))
    lines = page.splitlines()
    assert lines[0] == "# Results: suite paper (2026-03-02)"
    first = lines[2]
    for said in (
        "`formation-bench sweep paper --out res`",
        f"`{command}`",
        "2026-03-01 to 2026-03-02",
    ):
        assert said in first
    assert "formation-bench 1.2.3" in first and "Test CPU, 4 CPUs" in first
    assert sum(line.startswith("# ") for line in lines) == 1  # the report's headings demoted
    starts = [
        k
        for k, line in enumerate(lines)
        if line.startswith("|") and not lines[k - 1].startswith("|")
    ]
    assert len(starts) == len(tables_of(body)) > 0
    for k in starts:
        above = [line for line in lines[k - 3 : k] if line.startswith("<!-- produced by: ")]
        assert above and above[-1].startswith(f"<!-- produced by: {command}")
        timing = "median solve time" in lines[k]
        assert ("machine: Test CPU, 4 CPUs; date: 2026-03-02 -->" in above[-1]) == timing


def test_marking_leaves_a_page_without_tables_alone():
    provenance = suite_provenance(
        __import__("pathlib").Path("/nonexistent"), runs().assign(suite="x")
    )
    assert mark_tables("text\n", "formation-bench report x", provenance) == "text\n"
    assert provenance.machine == "not recorded" and provenance.name == "x"
