"""Suite files: the shipped suites, validation errors with line numbers, run identities."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from formation_bench.cli.main import main
from formation_bench.experiments.executors import execute_run
from formation_bench.experiments.suite import (
    SUITES_DIR,
    SuiteError,
    load_suite,
    parse_suite,
    run_count,
    shipped_suites,
)
from formation_bench.mpc.loop import simulate
from formation_bench.mpc.metrics import compute_metrics
from formation_bench.optimizers import OPTIMIZERS, Budget
from formation_bench.pipeline.record import is_metric_column, is_timing_column
from formation_bench.pipeline.spec import canonical_json, config_of, sha256_hex

GOOD = """\
name = "t"
seeds = [3, 1]
triggers = [true, false]
budgets = ["default", { max_evaluations = 200 }]

[[optimizers]]
name = "modified-bso"
overrides = { max_iterations = 2 }

[[optimizers]]
name = "modified-bso-no-modifications"
label = "plain"

[[scenarios]]
name = "paper"
overrides = { n_steps = 8, settle_time_s = 0.4 }
"""


def parse(text: str):
    return parse_suite(text, Path("s.toml"))


def error_of(text: str) -> str:
    with pytest.raises(SuiteError) as info:
        parse(text)
    return str(info.value)


def test_shipped_suites_load_with_the_promised_contents():
    assert {"paper", "ablation", "comparison"} <= set(shipped_suites())
    paper = load_suite("paper")
    assert [e.name for e in paper.optimizers] == ["modified-bso"]
    assert paper.scenarios[0].name == "paper" and paper.scenarios[0].overrides == "{}"
    assert set(paper.triggers) == {True, False} and paper.seeds == tuple(range(30))
    assert len(paper.runs()) == 60
    ablation = load_suite("ablation")
    names = [e.name for e in ablation.optimizers]
    assert names[0] == "modified-bso" and len(names) >= 4
    assert all(n.startswith("modified-bso") for n in names) and len(ablation.seeds) == 30
    comparison = load_suite("comparison")
    adapters = {"pycma"} | {n for n in OPTIMIZERS if n.startswith(("ng-", "mealpy-"))}
    assert sorted(e.name for e in comparison.optimizers) == sorted(set(OPTIMIZERS) - adapters)
    paper_budget = load_suite("paper-budget")
    assert [e.name for e in paper_budget.optimizers[:4]] == ["modified-bso", "pso", "cma-es", "de"]
    assert len(paper_budget.runs()) == 4 * 5 * 2 * 10 + 2 * 2 * 10
    assert comparison.budgets == (Budget(max_evaluations=1200),) and len(comparison.seeds) == 30
    deadline = load_suite("deadline")
    # deadline_ms in the file, seconds in the Budget; the optimisers' own limits kept
    assert [b.deadline_s for b in deadline.budgets] == [0.0005, 0.001, 0.002, 0.005]
    assert all(b.keeps_own_limits for b in deadline.budgets)
    assert {r.budget_label for r in deadline.runs()} == {
        f"deadline_ms={ms}" for ms in ("0.5", "1", "2", "5")
    }


def test_expansion_order_labels_and_budgets():
    suite = parse(GOOD)
    runs = suite.runs()
    assert len(runs) == 2 * 2 * 2 * 2
    assert [r.optimizer_label for r in runs[:8]] == ["modified-bso[max_iterations=2]"] * 8
    assert {r.optimizer_label for r in runs} == {"modified-bso[max_iterations=2]", "plain"}
    assert {r.budget_label for r in runs} == {"default", "max_evaluations=200"}
    assert [r.seed for r in runs[:2]] == [3, 1]
    assert len({r.key for r in runs}) == len(runs)
    assert len({r.entropy for r in runs}) == len(runs)


def test_identity_ignores_labels_order_and_no_op_overrides():
    suite = parse(GOOD)
    renamed = parse(
        GOOD.replace('label = "plain"', 'label = "other"').replace(
            "max_iterations = 2 }", "max_iterations = 2, population_size = 30 }"
        )
    )
    assert {r.key for r in suite.runs()} == {r.key for r in renamed.runs()}
    assert {r.entropy for r in suite.runs()} == {r.entropy for r in renamed.runs()}
    # a real change of configuration is a different run
    changed = parse(GOOD.replace("max_iterations = 2 }", "max_iterations = 3 }"))
    assert {r.key for r in suite.runs()} != {r.key for r in changed.runs()}


def test_a_sweep_run_is_simulate_with_the_identity_entropy():
    run = parse(GOOD).runs()[0]
    result = execute_run(run)
    assert result.error is None
    scenario, optimizer = run.build()
    budget = run.budget_for(optimizer)
    trace = simulate(scenario, optimizer, trigger=run.trigger, seed=run.entropy, budget=budget)
    metrics = compute_metrics(trace).columns()
    assert result.row["seed"] == run.seed and result.row["seed_entropy"] == str(run.entropy)
    compared = [c for c in metrics if not is_timing_column(c)]
    assert len(compared) >= 15
    assert {c: result.row[c] for c in compared} == {c: metrics[c] for c in compared}
    assert result.row["solves_total"] == sum(result.row[f"solves_uav{k}"] for k in (1, 2, 3))
    assert len(result.row["solve_times_s"]) == result.row["solves_total"]


def test_the_recorded_command_repeats_a_sweep_run_exactly(tmp_path):
    import shlex

    suite = parse(GOOD)
    # a run with overrides on both sides and a budget: every part of the command is used
    run = next(r for r in suite.runs() if r.budget is not None and r.optimizer_overrides != "{}")
    row = execute_run(run).row
    argv = shlex.split(row["command"])
    assert argv[0] == "formation-bench" and argv[-2] == "--out"
    out = tmp_path / "again"
    assert main([*argv[1:-1], str(out), "--no-figures"]) == 0
    (record,) = json.loads((out / "metrics.json").read_text())
    compared = [c for c in row if is_metric_column(c) and not is_timing_column(c)]
    assert len(compared) >= 15
    # NaN (a run that never settled) must be NaN on both sides
    same = {
        c: record[c] == row[c] or (record[c] != record[c] and row[c] != row[c]) for c in compared
    }
    assert all(same.values()), [c for c, ok in same.items() if not ok]
    assert record["seed"] == run.entropy and record["config_hash"] == row["config_hash"]


@pytest.mark.parametrize(
    ("text", "where", "needles"),
    [
        (
            GOOD.replace('name = "modified-bso"\n', 'name = "psoo"\n'),
            "optimizers[0].name",
            ["unknown optimizer 'psoo'", "modified-bso-no-modifications"],
        ),
        (
            GOOD.replace("max_iterations = 2", "max_iteration = 2"),
            "optimizers[0].overrides.max_iteration",
            ["max_iteration", "population_size"],
        ),
        (
            GOOD.replace("max_iterations = 2", "population_size = 1"),
            "optimizers[0].overrides.population_size",
            ["population_size", ">= 2"],
        ),
        (GOOD.replace('name = "t"', 'nmae = "t"'), "nmae", ["unknown field", "seeds"]),
        (GOOD.replace("seeds = [3, 1]", "seeds = -2"), "seeds", ["seeds", ">= 1"]),
        (GOOD.replace("triggers = [true, false]", 'triggers = ["on"]'), "triggers", ["triggers"]),
        (
            GOOD.replace("max_evaluations = 200", "max_evals = 200"),
            "budgets[1].max_evals",
            ["max_evals", "max_evaluations, max_iterations"],
        ),
        (
            GOOD.replace("max_evaluations = 200", "max_evaluations = 0"),
            "budgets[1]",
            ["max_evaluations"],
        ),
        (
            GOOD.replace('label = "plain"', "colour = 1"),
            "optimizers[1].colour",
            ["unknown field", "label"],
        ),
        (
            GOOD.replace('name = "paper"', 'name = "moon"'),
            "scenarios[0].name",
            ["unknown scenario 'moon'", "paper-straight"],
        ),
        (
            GOOD.replace("n_steps = 8", "n_stepz = 8"),
            "scenarios[0].overrides.n_stepz",
            ["n_stepz", "horizon_steps"],
        ),
        (
            GOOD.replace("n_steps = 8", "n_steps = 0"),
            "scenarios[0].overrides.n_steps",
            ["n_steps", "[1,"],
        ),
        (
            GOOD.replace("settle_time_s = 0.4", "settle_time_s = 9.0"),
            "scenarios[0].overrides.settle_time_s",
            ["settle_time_s", "after the end"],
        ),
        (
            GOOD.replace('label = "plain"', 'label = "modified-bso[max_iterations=2]"'),
            "optimizers[1].label",
            ["used twice"],
        ),
        (
            GOOD.replace("seeds = [3, 1]", "seeds = [3, 1"),
            None,
            ["not valid TOML", "line 3, column"],
        ),
    ],
)
def test_validation_names_the_field_and_the_allowed_values(text, where, needles):
    message = error_of(text)
    assert message.startswith("s.toml")
    if where is not None:
        assert message.startswith(f"s.toml: {where}:")
    for needle in needles:
        assert needle in message
    assert "\n" not in message


def test_optional_optimizers_are_skipped_and_star_takes_every_registered_one():
    text = GOOD.replace(
        'name = "modified-bso-no-modifications"', 'name = "ipopt-x"\noptional = true'
    )
    suite = parse(text.replace('label = "plain"\n', ""))
    assert [e.name for e in suite.optimizers] == ["modified-bso"]
    assert "ipopt-x" in suite.notes[0]
    star = parse('seeds = 1\n[[optimizers]]\nname = "*"\nexclude = ["modified-bso-*"]\n')
    expected = sorted(n for n in OPTIMIZERS if not n.startswith("modified-bso-"))
    assert sorted(e.name for e in star.optimizers) == expected
    message = error_of('seeds = 1\n[[optimizers]]\nname = "*"\noverrides = { a = 1 }\n')
    assert "optimizers[0].overrides" in message and "not allowed" in message


def test_same_configuration_twice_is_refused():
    text = GOOD.replace(
        'name = "modified-bso-no-modifications"\nlabel = "plain"',
        'name = "modified-bso"\nlabel = "again"\noverrides = { max_iterations = 2 }',
    )
    assert "same configuration" in error_of(text)


def test_cli_reports_a_bad_suite_in_one_line_exit_2(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(GOOD.replace('name = "modified-bso"\n', 'name = "nope"\n'))
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "formation_bench.cli.main",
            "sweep",
            str(bad),
            "--out",
            str(tmp_path / "o"),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr
    assert lines[0].startswith("formation-bench sweep: error:")
    assert "optimizers[0].name" in lines[0] and "unknown optimizer 'nope'" in lines[0]


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["sweep", "no-such-suite", "--out", "x"], "unknown suite 'no-such-suite'; shipped:"),
        (["sweep", "paper", "--out", "x", "--jobs", "0"], "--jobs"),
        (["report", "{tmp}/nothing"], "holds no results"),
    ],
)
def test_bad_sweep_and_report_arguments_exit_2(args, needle, tmp_path, capsys):
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    with pytest.raises(SystemExit) if "--jobs" in args else _nullcontext():
        code = main(args)
        assert code == 2
    err = capsys.readouterr().err
    assert needle in err and len(err.strip().splitlines()) == 1


class _nullcontext:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def test_entropy_is_128_bits_and_key_is_stable():
    run = parse(GOOD).runs()[0]
    assert 0 <= run.entropy < 2**128
    assert run.key == parse(GOOD).runs()[0].key
    identity = run.identity()
    assert identity["seed"] == 3 and identity["optimizer_overrides"] == {"max_iterations": 2}
    assert json.loads(run.identity_json) == identity
    # the derived entropy is what the per-UAV streams are spawned from
    streams = np.random.SeedSequence(run.entropy).spawn(3)
    assert streams[0].entropy == run.entropy


def test_every_registered_configuration_hashes_the_same_in_any_process():
    code = (
        "from formation_bench.optimizers import OPTIMIZERS; "
        "from formation_bench.pipeline.spec import config_of, canonical_json;"
        "import hashlib; print({n: hashlib.sha256(canonical_json(config_of(r.optimizer)).encode())"
        ".hexdigest() for n, r in sorted(OPTIMIZERS.items())})"
    )
    here = {
        n: sha256_hex(canonical_json(config_of(r.optimizer))) for n, r in sorted(OPTIMIZERS.items())
    }
    there = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True
    ).stdout
    assert there.strip() == str(here)


def test_an_optimiser_entry_runs_at_its_own_budgets(tmp_path):
    text = GOOD.replace('label = "plain"', 'label = "plain"\nbudgets = ["default"]')
    suite = parse_suite(text, tmp_path / "t.toml")
    per_label = {}
    for run in suite.runs():
        per_label.setdefault(run.optimizer_label, set()).add(
            None if run.budget is None else run.budget.max_evaluations
        )
    assert per_label["plain"] == {None}
    assert per_label["modified-bso[max_iterations=2]"] == {None, 200}
    assert len(suite.runs()) == run_count(suite) == (2 + 1) * 2 * 2
    bad = GOOD.replace('label = "plain"', 'label = "plain"\nbudgets = [{ max_evals = 5 }]')
    with pytest.raises(SuiteError, match=r"optimizers\[1\]\.budgets\[0\]\.max_evals"):
        parse_suite(bad, tmp_path / "t.toml")


def _scenario_of(entry):
    from formation_bench.mpc.scenario import get_scenario
    from formation_bench.pipeline.spec import from_json_value

    return get_scenario(entry.name, **from_json_value(json.loads(entry.overrides)))


SCENARIO_SUITE_OPTIMIZERS = [
    "modified-bso", "pso", "ltv-osqp", "mppi", "predictive-sampling", "cem", "icem", "ilqr",
]  # fmt: skip
"""The optimisers of the swarm and robustness suites, in suite order."""


def test_swarm_suite_plans_every_size_on_every_graph_with_connected_range_graphs():
    from scipy.sparse.csgraph import connected_components

    from formation_bench.mpc.network import listening

    suite = load_suite("swarm")
    assert [e.name for e in suite.optimizers] == SCENARIO_SUITE_OPTIMIZERS
    assert suite.seeds == tuple(range(5)) and suite.triggers == (True,)
    planned = {}
    for entry in suite.scenarios:
        scenario = _scenario_of(entry)
        planned.setdefault(scenario.n_uav, set()).add(str(scenario.communication.graph))
        if scenario.communication.graph == "k-nearest":
            assert scenario.communication.graph_neighbours == 3
        if scenario.communication.graph == "range":
            start = scenario.initial_state_array()[:, :2]
            links = listening(scenario, start)
            assert connected_components(links, directed=True, connection="strong")[0] == 1
    # on 3 UAVs the ring and the 2-nearest graph are the complete graph
    assert planned == {
        3: {"complete", "range"},
        5: {"complete", "ring", "k-nearest", "range"},
        10: {"complete", "ring", "k-nearest", "range"},
        20: {"complete", "ring", "k-nearest", "range"},
    }
    runs = suite.runs()
    assert len(runs) == run_count(suite) == 14 * len(SCENARIO_SUITE_OPTIMIZERS) * 5
    assert len({r.key for r in runs}) == len(runs)


def test_the_range_of_the_swarm_suite_keeps_the_tightest_swarm_connected_in_flight():
    from scipy.sparse.csgraph import connected_components

    from formation_bench.mpc.network import listening

    suite = load_suite("swarm")
    ranges = {
        _scenario_of(e).communication.graph_range_m for e in suite.scenarios if "range" in e.label
    }
    (chosen,) = ranges

    def components(links):
        return connected_components(links, directed=True, connection="strong")[0]

    def at_start(name, range_m):
        scenario = _scenario_of(next(e for e in suite.scenarios if e.name == name))
        scenario = scenario.with_overrides(graph="range", graph_range_m=range_m)
        return components(listening(scenario, scenario.initial_state_array()[:, :2]))

    names = {e.name for e in suite.scenarios}
    assert {at_start(name, chosen) for name in names} == {1}
    assert at_start("swarm-5", chosen - 10) > 1  # not far above what swarm-5 needs
    # swarm-5 starts with its graph nearly split: it stays connected in the suite's run
    run = next(
        r
        for r in suite.runs()
        if r.scenario_label == "N5-range" and r.optimizer_name == "modified-bso"
    )
    scenario, optimizer = run.build()
    budget = run.budget_for(optimizer)
    trace = simulate(scenario, optimizer, trigger=run.trigger, seed=run.entropy, budget=budget)
    assert {components(links) for links in trace.neighbours} == {1}


def test_robustness_suite_varies_one_disturbance_family_at_a_time():
    from formation_bench.analysis.suite_sections import FAMILIES

    suite = load_suite("robustness")
    assert [e.name for e in suite.optimizers] == SCENARIO_SUITE_OPTIMIZERS
    assert set(suite.triggers) == {True, False} and len(suite.seeds) == 5
    levels = {}
    for entry in suite.scenarios:
        scenario = _scenario_of(entry)
        assert entry.name == "paper"
        active = [f.name for f in FAMILIES if f.active(scenario)]
        assert len(active) <= 1, entry.label
        levels.setdefault(active[0] if active else "nominal", []).append(scenario)
    assert len(levels["nominal"]) == 1
    assert sorted(s.disturbances.gust_std_m_s for s in levels["wind"]) == [0.0, 0.5, 1.0, 2.0]
    assert any(s.disturbances.wind_mean_m_s != (0.0, 0.0) for s in levels["wind"])
    assert sorted(s.disturbances.position_noise_std_m for s in levels["noise"]) == [0.1, 0.3]
    assert all(
        s.disturbances.heading_noise_std_rad > 0 and s.disturbances.speed_noise_std_m_s > 0
        for s in levels["noise"]
    )
    losses = sorted(
        (s.communication.packet_loss, s.communication.loss_correlation)
        for s in levels["packet loss"]
    )
    assert losses == [(0.1, 0.0), (0.3, 0.0), (0.3, 0.7), (0.5, 0.0)]
    assert sorted(s.communication.delay_steps for s in levels["delay"]) == [1, 2, 4]
    (mismatch,) = levels["mismatch"]
    assert (
        mismatch.disturbances.plant_accel_gain,
        mismatch.disturbances.plant_turn_rate_gain,
    ) == (0.8, 0.8)
    assert len(suite.runs()) == 15 * len(SCENARIO_SUITE_OPTIMIZERS) * 2 * 5


def test_obstacles_suite_turns_the_penalties_on_and_off():
    suite = load_suite("obstacles")
    assert [e.name for e in suite.optimizers] == ["modified-bso", "pso", "ltv-osqp"]
    settings = sorted(
        (e.name, s.safety.w_obstacle > 0 and bool(s.safety.obstacles), s.safety.w_collision > 0)
        for e in suite.scenarios
        for s in [_scenario_of(e)]
    )
    assert settings == [
        ("paper-obstacles", False, False),
        ("paper-obstacles", True, True),
        ("swarm-10", False, False),
        ("swarm-10", False, True),
    ]
    assert all(
        _scenario_of(e).safety.obstacles for e in suite.scenarios if e.name == "paper-obstacles"
    )
    assert len(suite.runs()) == 4 * 3 * 10


def test_a_shipped_name_is_the_shipped_suite_beside_a_folder_of_that_name(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "paper").mkdir()  # say, the results of an earlier 'sweep paper --out paper'
    assert load_suite("paper").path == SUITES_DIR / "paper.toml"
    with pytest.raises(SuiteError, match="is a folder"):
        load_suite("./paper")
