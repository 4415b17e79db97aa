"""The formation-bench command line, end to end on short runs."""

import json
import subprocess
import sys

import pandas as pd
import pytest

from formation_bench.benchmarks.cli import main, parse_value

METRIC_KEYS = {
    "optimizer",
    "scenario",
    "trigger",
    "seed",
    "steps",
    "settle_time_s",
    "tracking_error_max_m",
    "tracking_error_rms_m",
    "distance_error_max_m",
    "solves_per_uav",
    "closed_loop_cost",
    "solve_time_median_s",
    "solve_time_p95_s",
    "nfev_total",
    "wall_time_s",
}
SHORT = ["--set", "n_steps=25", "--set", "settle_time_s=1.0", "--set", "max_iterations=8"]


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "benchmarks.cli", *args], capture_output=True, text=True, timeout=300
    )


def test_short_run_writes_metrics_trace_and_figures(tmp_path):
    out = tmp_path / "run"
    result = cli(
        "run",
        "--optimizer",
        "modified-bso",
        "--no-trigger",
        "--seed",
        "3",
        *SHORT,
        "--out",
        str(out),
    )
    assert result.returncode == 0, result.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics) >= METRIC_KEYS
    assert metrics["trigger"] is False and metrics["seed"] == 3 and metrics["steps"] == 25
    assert metrics["solves_per_uav"] == [25, 25, 25]
    assert metrics["nfev_total"] > 0
    trace = pd.read_parquet(out / "trace.parquet")
    assert len(trace) == 26 * 3
    assert trace["solved"].sum() == 75
    for name in (
        "fig3_trajectory_no_trigger.png",
        "fig4_states_no_trigger.png",
        "fig7_solve_instants_no_trigger.png",
    ):
        assert (out / name).stat().st_size > 10_000


def test_run_is_repeatable_through_the_cli(tmp_path):
    runs = []
    for k in range(2):
        out = tmp_path / f"r{k}"
        assert main(["run", "--optimizer", "modified-bso", *SHORT, "--out", str(out)]) == 0
        runs.append(pd.read_parquet(out / "trace.parquet"))
    columns = ["x_m", "y_m", "heading_rad", "speed_m_s", "solved", "nfev", "solve_cost"]
    pd.testing.assert_frame_equal(runs[0][columns], runs[1][columns])


def test_set_reaches_scenario_and_optimizer(tmp_path):
    out = tmp_path / "set"
    assert (
        main(
            [
                "run",
                "--optimizer",
                "modified-bso",
                "--no-trigger",
                *SHORT,
                "--set",
                "optimizer.population_size=12",
                "--set",
                "scenario.reference=straight",
                "--set",
                "replacement_map=tent",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    trace = pd.read_parquet(out / "trace.parquet")
    solved = trace[trace["solved"]]
    assert (solved["nfev"] <= 12 * 9 + 10 * 8).all()
    assert trace["ref_heading_rad"].abs().max() == 0.0


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["run", "--optimizer", "nope", "--out", "x"], "modified-bso"),
        (["run", "--optimizer", "modified-bso", "--scenario", "mars", "--out", "x"], "paper"),
        (["run", "--optimizer", "modified-bso", "--set", "n_blocks=0", "--out", "x"], "n_blocks"),
        (
            ["run", "--optimizer", "modified-bso", "--set", "colour=red", "--out", "x"],
            "unknown field",
        ),
        (
            ["run", "--optimizer", "modified-bso", "--set", "population_size=1", "--out", "x"],
            "population_size",
        ),
        (
            [
                "run",
                "--optimizer",
                "modified-bso",
                "--set",
                "estimate_extension=freeze",
                "--out",
                "x",
            ],
            "coast, hold",
        ),
        (["run", "--optimizer", "modified-bso", "--set", "n_blocks", "--out", "x"], "FIELD=VALUE"),
        (["run", "--optimizer", "modified-bso", "--seed", "-1", "--out", "x"], "--seed"),
        (["run", "--optimizer", "modified-bso"], "--out"),
        (["frobnicate"], "invalid choice"),
    ],
)
def test_bad_input_is_one_line_exit_2(args, needle):
    result = cli(*args)
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    lines = [line for line in result.stderr.splitlines() if "error" in line]
    assert len(lines) == 1 and needle in lines[0], result.stderr


def test_list_names_optimizers_and_scenarios():
    result = cli("list")
    assert result.returncode == 0
    for name in ("modified-bso", "modified-bso-no-chaos-replacement", "paper", "paper-straight"):
        assert name in result.stdout


def test_parse_value():
    assert parse_value("3") == 3 and parse_value("0.5") == 0.5
    assert parse_value("true") is True and parse_value("False") is False
    assert parse_value("(-5, 5)") == (-5, 5)
    assert parse_value("tent") == "tent"
