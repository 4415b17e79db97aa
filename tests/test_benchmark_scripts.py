"""Smoke tests of the scaling benchmark, the kernel comparison and the pytest-benchmark suite."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_cost_and_problem import random_problem

from formation_bench.instances.instants import RecordedInstant
from formation_bench.mpc.scenario import PAPER
from perf import deadline_overhead, kernel_speed, scaling

ROOT = Path(__file__).resolve().parent.parent


def test_scaling_script_reports_speedup_and_overhead(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(scaling, "WARM", scaling.WARM.replace("n_steps = 40", "n_steps = 5"))
    out = tmp_path / "scaling.json"
    assert scaling.main(["--runs", "2", "--steps", "10", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "speed-up, 2 workers over 1" in printed and "machinery overhead per run" in printed
    figures = json.loads(out.read_text())
    assert figures["speedup"] > 0
    assert figures["jobs1"]["workers_used"] == 1 and figures["jobs2"]["workers_used"] >= 1
    assert figures["jobs2"]["workers_started"] == 2
    assert 0 < figures["jobs1"]["simulate_total_s"] < 2 * figures["jobs1"]["sweep_wall_s"]


@pytest.mark.slow
def test_timing_suite_collects_every_optimizer_and_runs(tmp_path):
    listing = subprocess.run(
        [sys.executable, "-m", "pytest", "perf/timing", "--collect-only", "-q"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    assert listing.returncode == 0, listing.stdout + listing.stderr
    from formation_bench.optimizers import OPTIMIZERS

    for name in OPTIMIZERS:
        assert f"test_solve_time[{name}-default]" in listing.stdout
    saved = tmp_path / "timing.json"
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "perf/timing/test_solve_timing.py::test_solve_time[modified-bso-default]",
            "perf/timing/test_solve_timing.py::test_solve_time[pso-equal-1200]",
            f"--benchmark-json={saved}",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=600,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    data = json.loads(saved.read_text())
    names = {b["name"] for b in data["benchmarks"]}
    assert names == {"test_solve_time[modified-bso-default]", "test_solve_time[pso-equal-1200]"}
    assert data["machine_info"]["cpu_affinity"]
    assert all(b["stats"]["rounds"] == 27 for b in data["benchmarks"])


@pytest.mark.slow
def test_kernel_speed_times_every_kernel_and_the_floor():
    figures = kernel_speed.measure(repeats=2, calls=5)
    for population in kernel_speed.POPULATIONS:
        reference = figures[f"reference_per_eval_s_{population}"]
        assert 0 < figures[f"numba_per_eval_s_{population}"] < reference
        if figures["c_kernel_built"]:
            assert 0 < figures[f"c_per_eval_s_{population}"] < reference
    # the paper's problem: 5 blocks, 20 periods of one sub-step, 2 neighbours, 2 resets
    assert figures["operations_per_evaluation"] == 5 * 43 + 2 * 37 + 20 * (33 + 2 * 6 + 9) + 1
    table = kernel_speed.format_results(figures)
    assert "operations per evaluation (a fused multiply-add counts 2) | 1370" in table
    if figures["c_kernel_built"]:
        assert figures["fma_flops"] > 1e9 and "floor of an evaluation" in table


def test_operation_count_follows_the_problem_shape():
    count = kernel_speed.operations_per_evaluation
    # one more period adds a sub-step, its neighbours and the centre term
    assert count(21, 5, 1, 2) - count(20, 5, 1, 2) == 33 + 2 * 6 + 9
    # 16 sub-steps of the horizon between fresh headings
    assert count(16, 1, 1, 0) - count(15, 1, 1, 0) == 33 + 9
    assert count(17, 1, 1, 0) - count(16, 1, 1, 0) == 33 + 9 + 37


@pytest.mark.slow
def test_startup_script_measures_overhead_and_compile(tmp_path, monkeypatch):
    from perf import startup

    short = ["--set", "n_steps=8", "--set", "settle_time_s=0.5", "--set", "max_iterations=3"]
    monkeypatch.setattr(startup, "RUN", [*startup.RUN, *short])
    assert "pandas" not in startup.modules_loaded([*startup.RUN, "--out", str(tmp_path / "m")])
    warm = startup.warm_overhead(1, tmp_path)
    assert warm["ratio"]["median"] > 1  # a command takes longer than its solves
    assert 0 < warm["solve_sum_s"]["median"] < warm["wall_s"]["median"]
    cold = startup.cold_start(1, tmp_path)
    kernels = cold["kernels_cpu_s"]
    # the run solves through the compiled loop; the cost is the C kernel's, when it was
    # built, and the numba one is then never compiled
    from formation_bench.mpc.native_cost import native_cost_address

    assert "formation_bench.optimizers.modified_bso_kernels.modified_bso_iterate" in kernels
    numba_cost = "formation_bench.mpc.cost.packed_batch_cost" in kernels
    assert numba_cost is (native_cost_address() is None)
    assert cold["compile_cpu_s"] == pytest.approx(sum(kernels.values()))
    assert cold["wall_s"]["median"] > warm["wall_s"]["median"]


def test_run_split_parts_add_up_to_the_run(tmp_path, capsys):
    from perf import run_split

    out = tmp_path / "split.json"
    assert run_split.main(["--optimizers", "ltv-osqp", "--seeds", "1", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| ltv-osqp |" in printed and "all x 30 seeds, s" in printed
    row = json.loads(out.read_text())["runs"]["ltv-osqp"]
    assert 0 < row["solves"] < row["run"]
    assert row["loop bookkeeping"] > 0 and row["outside the loop"] > 0
    assert row["solves"] + row["loop bookkeeping"] + row["outside the loop"] == pytest.approx(
        row["run"], rel=1e-9
    )
    with pytest.raises(SystemExit, match="not in the comparison suite"):
        run_split.main(["--optimizers", "no-such-optimizer"])


def test_gradient_speed_orders_the_recorded_solves_both_ways() -> None:
    """Section B of perf.gradient_speed: each optimiser over every problem in turn, or every
    optimiser on a problem before the next one."""
    from perf.gradient_speed import ALTERNATING, BACK_TO_BACK, ORDERS, schedule

    assert schedule(("a", "b"), 2, BACK_TO_BACK) == [("a", 0), ("a", 1), ("b", 0), ("b", 1)]
    assert schedule(("a", "b"), 2, ALTERNATING) == [("a", 0), ("b", 0), ("a", 1), ("b", 1)]
    for order in ORDERS:
        assert sorted(schedule(("a", "b", "c"), 4, order)) == [
            (name, i) for name in "abc" for i in range(4)
        ]


def test_deadline_overhead_prints_a_row_per_optimiser(tmp_path, capsys, monkeypatch):
    problems = [random_problem(np.random.default_rng(k), PAPER) for k in range(2)]
    start = np.random.default_rng(1)
    instants = [RecordedInstant(0, 0, p, p.bounds.sample(start, 1)[0]) for p in problems]
    monkeypatch.setattr(deadline_overhead, "paper_instants", lambda: instants)
    out = tmp_path / "deadline.json"
    args = ["--rounds", "1", "--optimizers", "pso,cma-es", "--json", str(out)]
    assert deadline_overhead.main(args) == 0
    printed = capsys.readouterr().out
    assert "| iterations 1 ms allows |" in printed and "2 problems x 1 rounds" in printed
    rows = json.loads(out.read_text())["rows"]
    assert [r["optimizer"] for r in rows] == ["pso", "cma-es"]
    for row in rows:
        assert row["per_iteration_s"] > 0 and row["completed"] >= 1
        assert row["long_iterations"] > row["completed"] or not row["deadline_binds"]


def test_peer_pso_script_pairs_the_package_pso_with_mealpy_on_the_same_problems(capsys):
    from perf import peer_pso

    peer_pso.main(["--optimizers", "pso", "--problems", "3", "--budget", "300"])
    printed = capsys.readouterr().out
    assert "3 test problems, 300 evaluations, seed 0" in printed
    assert "pso vs mealpy OriginalPSO: lower on" in printed and " of 3," in printed


def test_cold_warm_script_states_each_target_met_or_missed():
    from perf.cold_warm import ColdWarm, format_results

    commands = [
        ColdWarm("reproduce", cold_s=9.0, warm_s=4.0, compile_cpu_s=5.0, compiles=80),
        ColdWarm("sweep comparison", cold_s=130.0, warm_s=100.0, compile_cpu_s=0.0, compiles=0),
        ColdWarm("sweep", cold_s=20.0, warm_s=3.0, compile_cpu_s=0.0, compiles=0),
        ColdWarm("score", cold_s=20.0, warm_s=5.0, compile_cpu_s=14.0, compiles=90),
    ]
    optimizers = [
        ColdWarm("pso", cold_s=5.5, warm_s=3.0, compile_cpu_s=2.0, compiles=10),
        ColdWarm("cma-es", cold_s=40.0, warm_s=3.0, compile_cpu_s=35.0, compiles=60),
    ]
    text = format_results(commands, optimizers)
    assert "| `reproduce` | 9.0 s | 4.0 s | 5.0 s | 2.2x | 5.0 s (80) | missed (<= 2x) |" in text
    assert (
        "| `sweep comparison` | 130.0 s | 100.0 s | 30.0 s | 1.3x | 0.0 s (0) | met (<= 1.3x) |"
        in text
    )
    assert "| `sweep` | 20.0 s | 3.0 s | 17.0 s | 6.7x | 0.0 s (0) |  |" in text  # no target
    assert (
        text.count("| `score` |") == 1
        and "| `score` | 20.0 s | 5.0 s | 15.0 s | 4.0x | 14.0 s (90) |  |" in text
    )
    assert "| pso | 5.5 s | 3.0 s | 2.5 s | 1.8x | 2.0 s (10) | met (<= 3 s) |" in text
    assert "| cma-es | 40.0 s | 3.0 s | 37.0 s | 13.3x | 35.0 s (60) | missed (<= 3 s) |" in text
    assert "within 3 s of the warm run: 1 of 2; compile CPU summed: 37 s" in text


def test_cold_warm_script_measures_one_optimizer_per_group_compiling_the_same_kernels():
    from formation_bench.optimizers import get_optimizer, optimizer_names
    from perf.cold_warm import default_optimizers

    names = default_optimizers()
    compiled = [get_optimizer(n).compiled_kernels() for n in names]
    compiled = [kernels for kernels in compiled if kernels]
    assert len(compiled) == len(set(compiled))  # no group twice
    every = {get_optimizer(n).compiled_kernels() for n in optimizer_names()} - {()}
    assert set(compiled) == every  # every group
    assert {"pso", "modified-bso", "cma-es", "ipopt", "pycma"} <= set(names)
    assert not any(name.startswith("ng-") for name in names)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--commands", "report"], "--commands: unknown report; allowed: run, reproduce"),
        (["--optimizers", "no-such"], "--optimizers: not registered: no-such"),
    ],
)
def test_cold_warm_script_refuses_what_it_cannot_measure(args, message, capsys):
    from perf import cold_warm

    with pytest.raises(SystemExit) as stop:
        cold_warm.main(args)
    assert stop.value.code == 2
    assert message in capsys.readouterr().err


def test_tuning_noise_is_the_spread_of_the_median_over_disjoint_seed_sets(capsys):
    from perf import tuning_noise

    # five sets of ten: medians 1, 2, 3, 4, 5
    costs = [float(k // 10 + 1) for k in range(50)]
    assert tuning_noise.noise(costs) == pytest.approx(np.std([1, 2, 3, 4, 5], ddof=1))
    with pytest.raises(SystemExit) as stop:
        tuning_noise.main(["--families", "random-search"])
    assert stop.value.code == 2
    assert "--families: no tuned-loop variant of random-search" in capsys.readouterr().err
