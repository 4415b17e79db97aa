"""The formation-bench command line, end to end on short runs."""

import json
import subprocess
import sys

import pandas as pd
import pytest

from formation_bench.cli.main import main, parse_value
from formation_bench.mpc.metrics import metric_infos, metric_of
from formation_bench.pipeline.record import is_metric_column, record_columns

SHORT = ["--set", "n_steps=25", "--set", "settle_time_s=1.0", "--set", "max_iterations=8"]


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "formation_bench.cli", *args],
        capture_output=True,
        text=True,
        timeout=300,
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
    (record,) = json.loads((out / "metrics.json").read_text())
    # every column is declared, and every declared metric and record column is there
    described = [name for name, _, _ in record_columns()]
    assert all(c in described or is_metric_column(c) for c in record)
    assert set(described) <= set(record)
    assert {metric_of(c).name for c in record if is_metric_column(c)} == {
        info.name for info in metric_infos()
    }
    assert record["trigger"] is False and record["seed"] == 3 and record["steps"] == 25
    assert [record[f"solves_uav{k}"] for k in (1, 2, 3)] == [25, 25, 25]
    assert record["nfev_total"] > 0
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


def test_a_sweep_run_is_repeated_exactly_by_run_with_its_entropy_and_budget(tmp_path):
    """The command docs/explanation/benchmarks.md gives for repeating a sweep run: seeds of 128
    bits."""
    from formation_bench.experiments.store import load_results
    from formation_bench.experiments.suite import parse_suite
    from formation_bench.experiments.sweep import run_sweep

    text = (
        'name = "repeat"\nseeds = 1\ntriggers = [true]\nbudgets = [{ max_evaluations = 150 }]\n'
        '[[optimizers]]\nname = "modified-bso"\noverrides = { population_size = 12 }\n'
        '[[scenarios]]\nname = "paper"\noverrides = { n_steps = 12, settle_time_s = 1.0 }\n'
    )
    suite = parse_suite(text, tmp_path / "repeat.toml")
    run_sweep(suite, tmp_path / "store", jobs=1, progress=False, log=lambda _: None)
    row = load_results(tmp_path / "store").iloc[0]
    entropy = int(row["seed_entropy"])
    assert entropy >= 2**63  # the case that once broke writing the trace
    code = main(
        ["run", "--optimizer", "modified-bso", "--set", "optimizer.population_size=12",
         "--set", "scenario.n_steps=12", "--set", "scenario.settle_time_s=1.0",
         "--seed", str(entropy), "--max-evaluations", "150", "--no-figures",
         "--out", str(tmp_path / "run")]
    )  # fmt: skip
    assert code == 0
    (metrics,) = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["scenario"] == "paper[n_steps=12,settle_time_s=1.0]"
    assert metrics["scenario_overrides"] == {"n_steps": 12, "settle_time_s": 1.0}
    assert metrics["optimizer"] == "modified-bso[population_size=12]"
    assert metrics["budget_max_evaluations"] == 150
    assert metrics["tracking_error_max_m"] == row["tracking_error_max_m"]
    assert metrics["closed_loop_cost"] == row["closed_loop_cost"]
    assert metrics["nfev_total"] == row["nfev_total"]
    for name in ("d12", "d23", "d31"):
        assert metrics[f"distance_error_max_m_{name}"] == row[f"distance_error_max_m_{name}"]
    assert (tmp_path / "run" / "trace.parquet").is_file()
    assert not list((tmp_path / "run").glob("*.png"))


def test_list_fields_shows_values_ranges_and_docs(capsys):
    assert main(["list", "--fields", "modified-bso-tent"]) == 0
    out = capsys.readouterr().out
    assert "weight_map = tent" in out and "n_clusters = 5" in out
    assert "integer in [1, population_size]" in out and "m, k-means clusters" in out
    # what a tuner searches: ranges (field-dependent ones in words), choices, or nothing
    assert "population_size = 30  (int; integer >= 2; searched: [4, 100] log)" in out
    assert "searched: [2, min(population_size, 12)])" in out
    assert "bound_handling = clip  (BoundHandling; one of clip, reflect, resample; " in out
    assert "searched: clip, reflect, resample)" in out
    assert (
        "not tuned)\n      f_hmap" in out
        and "max_iterations = 40  (int; integer >= 1; not tuned)" in out
    )
    assert main(["list", "--fields", "paper"]) == 0
    out = capsys.readouterr().out
    assert "settle_time_s = 10.0" in out and "tuned" not in out and "searched" not in out
    assert main(["list", "--fields", "nope"]) == 2
    assert "unknown optimizer or scenario 'nope'" in capsys.readouterr().err


def test_version_and_help(capsys):
    import formation_bench

    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    assert capsys.readouterr().out.strip() == f"formation-bench {formation_bench.__version__}"
    with pytest.raises(SystemExit):
        main(["--help"])
    text = capsys.readouterr().out
    assert "examples:" in text and "--plugin" in text and "``" not in text


def test_first_run_notice_and_progress_bar_go_to_stderr(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr("formation_bench.pipeline.runner.kernels_cached", lambda: False)
    args = ["run", "--optimizer", "pso", "--no-trigger", "--no-figures", "--progress",
            "--set", "n_steps=4", "--set", "settle_time_s=0"]  # fmt: skip
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert "compiling numba kernels" in err and "/4 [" in err and "instant" in err
    monkeypatch.setattr("formation_bench.pipeline.runner.kernels_cached", lambda: True)
    monkeypatch.setattr("formation_bench.pipeline.runner.optimizer_kernels_cached", lambda _: True)
    assert main([*args, "--no-progress", "--out", str(tmp_path / "b")]) == 0
    assert capsys.readouterr().err == ""


def test_the_kernel_cache_is_found_after_a_run():
    from formation_bench.mpc.scenario import get_scenario
    from formation_bench.optimizers import get_optimizer
    from formation_bench.pipeline.runner import execute, kernels_cached, optimizer_kernels_cached
    from formation_bench.pipeline.spec import RunSpec

    scenario = get_scenario("paper", n_steps=3, settle_time_s=0.2)
    optimizer = get_optimizer("modified-bso", max_iterations=2)
    execute(RunSpec.of("modified-bso", optimizer, "paper", scenario, trigger=True, seed=0))
    assert kernels_cached() and optimizer_kernels_cached(optimizer)


def test_the_trace_columns_are_written_as_declared(tmp_path):
    from formation_bench.pipeline.trace_columns import TRACE_COLUMN_NAMES

    out = tmp_path / "run"
    args = ["run", "--optimizer", "pso", "--no-figures", "--set", "n_steps=3"]
    assert main([*args, "--set", "settle_time_s=0", "--out", str(out)]) == 0
    assert list(pd.read_parquet(out / "trace.parquet").columns) == list(TRACE_COLUMN_NAMES)


def test_help_texts_carry_no_markup(capsys):
    for command in ([], ["run"], ["reproduce"], ["list"], ["sweep"], ["score"], ["report"]):
        with pytest.raises(SystemExit):
            main([*command, "--help"])
        text = capsys.readouterr().out
        assert "usage: formation-bench" in text
        for markup in ("``", ":func:", ":class:", ":mod:", ":meth:"):
            assert markup not in text, (command, markup)


def test_a_malformed_set_value_names_the_field_and_the_form(tmp_path, capsys):
    argv = ["run", "--optimizer", "pso", "--set", "accel_bounds=(1,)", "--out", str(tmp_path)]
    assert main(argv) == 2
    assert capsys.readouterr().err == (
        "formation-bench run: error: --set accel_bounds: expected a pair (lower, upper) of "
        "numbers, got (1,)\n"
    )


def test_the_command_line_modules_import_one_way():
    import ast
    from pathlib import Path

    import formation_bench.cli as cli

    def imported(name: str) -> set[str]:
        tree = ast.parse((Path(cli.__file__).parent / f"{name}.py").read_text())
        found = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module:
                found.add(node.module)
            elif isinstance(node, ast.Import):
                found.update(alias.name for alias in node.names)
        return {m.rsplit(".", 1)[-1] for m in found if m.startswith("formation_bench.cli")}

    assert imported("common") == set()
    assert imported("sweep_commands") == {"common"}
    assert imported("tune_command") == {"common"}
    # cli: command_start
    assert imported("main") == {"cli", "common", "sweep_commands", "tune_command"}
    # command_start is the first import of the entry point's module, before anything heavy
    source = (Path(cli.__file__).parent / "main.py").read_text()
    first = next(line for line in source.splitlines() if line.startswith(("from ", "import ")))
    later = source.split("\n# first:", 1)[1].splitlines()[1]
    assert first == "from __future__ import annotations"
    assert later == "from formation_bench.cli import command_start  # isort: skip"
