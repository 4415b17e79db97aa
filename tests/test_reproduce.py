"""``formation-bench reproduce`` end to end (both 240-instant runs, about 10 s)."""

import json

import pandas as pd
import pytest

from formation_bench.analysis.paper import PAPER_FIGURES, comparison_rows, format_table
from formation_bench.analysis.paper_budget import shipped_line
from formation_bench.cli.main import main


@pytest.mark.slow
def test_reproduce_writes_both_runs_and_the_table(tmp_path, capsys):
    out = tmp_path / "reproduce"
    assert main(["reproduce", "--out", str(out), "--seed", "4"]) == 0
    printed = capsys.readouterr().out
    metrics = json.loads((out / "metrics.json").read_text())
    assert [m["trigger"] for m in metrics] == [False, True]
    assert all(
        m["steps"] == 240 and m["seed"] == 4 and m["optimizer"] == "modified-bso" for m in metrics
    )
    solves = [[m[f"solves_uav{k}"] for k in (1, 2, 3)] for m in metrics]
    assert solves[0] == [240, 240, 240]
    assert all(n < 240 for n in solves[1])
    trace = pd.read_parquet(out / "trace.parquet")
    assert len(trace) == 2 * 241 * 3
    assert set(trace["trigger"]) == {False, True}
    for name in (
        "fig3_trajectory_no_trigger.png",
        "fig4_states_no_trigger.png",
        "fig5_trajectory_trigger.png",
        "fig6_states_trigger.png",
        "fig7_solve_instants.png",
    ):
        assert (out / name).stat().st_size > 10_000
    rows = comparison_rows(metrics)
    assert len(rows) == len(PAPER_FIGURES)
    assert format_table(rows) in printed
    # the budget the paper needs is read from the shipped sweep, not run again; it comes last
    assert printed.splitlines()[-1] == shipped_line("modified-bso")
    assert "97.000" not in printed and all(
        f"  {metrics[1][f'solves_uav{k}']}  " in printed for k in (1, 2, 3)
    )
    for row in rows:
        assert row["holds"] == (row["measured"] <= row["paper"])


def distance_errors(*values: float) -> dict[str, float]:
    return {
        f"distance_error_max_m_{p}": v for p, v in zip(("d12", "d23", "d31"), values, strict=True)
    }


def solves(*values: int) -> dict[str, int]:
    return {f"solves_uav{k}": v for k, v in enumerate(values, start=1)}


def test_comparison_rows_read_the_right_metrics():
    fake = [
        {
            "trigger": False,
            "tracking_error_max_m": 1.3,
            **distance_errors(0.1, 0.2, 0.3),
        },
        {
            "trigger": True,
            "tracking_error_max_m": 1.0,
            **distance_errors(0.31, 0.3, 0.2),
            **solves(161, 160, 10),
        },
    ]
    holds = {(r["run"], r["figure"]): (r["measured"], r["holds"]) for r in comparison_rows(fake)}
    assert holds[("without trigger", "tracking error max")] == (1.3, False)
    assert holds[("without trigger", "d23 error max")] == (0.2, True)
    assert holds[("without trigger", "d31 error max")] == (0.3, False)
    assert holds[("with trigger", "d12 error max")] == (0.31, False)
    assert holds[("with trigger", "UAV 1 solves (paper: 157)")] == (161, False)
    assert holds[("with trigger", "UAV 2 solves (paper: 155)")] == (160, True)


def test_seed_table_counts_holds_per_figure():
    from formation_bench.analysis.paper import format_seed_table

    def run(track, per_uav):
        return [
            {
                "trigger": False,
                "tracking_error_max_m": track,
                **distance_errors(0.1, 0.1, 0.1),
            },
            {
                "trigger": True,
                "tracking_error_max_m": 1.0,
                **distance_errors(0.1, 0.1, 0.1),
                **solves(*per_uav),
            },
        ]

    table = format_seed_table(
        {
            0: comparison_rows(run(1.0, [100, 100, 100])),
            7: comparison_rows(run(1.3, [100, 170, 100])),
        }
    )
    lines = table.splitlines()
    assert lines[0].startswith("| run | figure | paper | seed 0 | seed 7 | holds on |")
    tracking = next(line for line in lines if "without trigger | tracking" in line)
    assert "| 1 | 1.3 ✗ | 1/2 |" in tracking
    uav2 = next(line for line in lines if "UAV 2" in line)
    assert uav2.endswith("| 100 | 170 ✗ | 1/2 |")
    assert len(lines) == 2 + len(PAPER_FIGURES)


@pytest.mark.slow
def test_the_front_page_and_the_tutorial_show_what_reproduce_prints(tmp_path, capsys):
    """The README's table of seed 0 and the tutorial's table of seeds 0-4 are the printed ones."""
    from pathlib import Path

    root = Path(__file__).parents[1]
    assert main(["reproduce", "--out", str(tmp_path / "one"), "--no-figures"]) == 0
    printed = capsys.readouterr().out
    readme = (root / "README.md").read_text()
    shown = readme.split("```text\n", 1)[1].split("```", 1)[0]
    assert shown.strip() and shown in printed
    seeds = ["0", "1", "2", "3", "4"]
    five = ["reproduce", "--out", str(tmp_path / "five"), "--no-figures", "--seeds", *seeds]
    assert main(five) == 0
    printed = capsys.readouterr().out
    tutorial = (root / "docs" / "tutorials" / "reproduce.md").read_text()
    marker = "<!-- produced by: formation-bench reproduce --seeds 0 1 2 3 4 --no-figures -->\n"
    table = tutorial.split(marker, 1)[1].split("\n\n", 1)[0]
    assert table.count("\n") == 12 and table in printed
