"""The "first sweep" tutorial's suite runs as printed and its report shows the tutorial's
numbers (all but the solve times, which depend on the machine)."""

import re
from pathlib import Path

import pytest

from formation_bench.cli.main import main

TUTORIAL = Path(__file__).parents[1] / "docs" / "tutorials" / "first-sweep.md"


def cells(line: str) -> list[str]:
    return [cell.strip() for cell in line.strip().strip("|").split("|")]


@pytest.mark.slow
def test_the_tutorial_suite_gives_the_tutorial_table(tmp_path, capsys, monkeypatch):
    text = TUTORIAL.read_text()
    suite = re.search(r"```toml\n(.*?)```", text, flags=re.S)[1]
    monkeypatch.chdir(tmp_path)
    Path("my-first.toml").write_text(suite)
    out = "results/my-first"
    assert main(["sweep", "my-first.toml", "--out", out, "--jobs", "1", "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["report", out, "--no-figures"]) == 0
    printed = capsys.readouterr().out
    table = text.split("<!-- produced by: formation-bench report results/my-first;", 1)[1]
    shown = [line for line in table.split("\n\n", 1)[0].splitlines() if line.startswith("|")]
    header, rows = cells(shown[0]), [cells(line) for line in shown[2:]]
    # the values tables (those with a runs column: the report splits the metrics into tables
    # of the same rows to fit a page), the first value of each optimizer and metric
    reported: dict[str, dict[str, str]] = {}
    report_header: list[str] = []
    for line in printed.splitlines():
        if line.startswith("| optimizer |"):
            report_header = cells(line) if cells(line)[1] == "runs" else []
        elif report_header and line.startswith("| ") and not line.startswith("|---"):
            values = dict(zip(report_header, cells(line), strict=True))
            for column, value in values.items():
                reported.setdefault(values["optimizer"], {}).setdefault(column, value)
        elif not line.startswith("|"):
            report_header = []
    assert len(rows) == 3
    for row in rows:
        for column, value in zip(header, row, strict=True):
            if "time" in column:  # the machine's, not the results'
                continue
            assert reported[row[0]][column] == value, (row[0], column)
