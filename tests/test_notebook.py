"""The analysis notebook runs top to bottom on results the test makes, headless.

Miniature versions of the seven suites (tests/data/notebook/*.toml: 30 instants,
3 seeds, small budgets) are swept into a temporary folder, then the notebook
is executed with nbclient on the venv's ``python3`` kernel with MPLBACKEND=Agg.
"""

import base64
import dataclasses
import os
import warnings
from pathlib import Path

import nbformat
import pandas as pd
import pytest
from nbclient import NotebookClient

from formation_bench.analysis import notebook as analysis
from formation_bench.experiments.suite import load_suite
from formation_bench.experiments.sweep import run_sweep
from formation_bench.mpc.scenario import get_scenario
from formation_bench.pipeline.spec import canonical_json, config_of

ROOT = Path(__file__).parents[1]
SUITES = ("paper", "ablation", "comparison", "trigger", "swarm", "robustness", "obstacles")


@pytest.fixture(scope="module")
def results_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("notebook-results")
    for name in SUITES:
        suite = load_suite(str(ROOT / "tests" / "data" / "notebook" / f"{name}.toml"))
        run_sweep(suite, folder / name, jobs=1, progress=False, log=lambda text: None)
    return folder


def test_notebook_twin_is_in_sync():
    import jupytext

    paired = jupytext.read(ROOT / "notebooks" / "analysis.py")
    notebook = nbformat.read(ROOT / "notebooks" / "analysis.ipynb", as_version=4)
    sources = [c.source for c in notebook.cells]
    assert sources == [c.source for c in paired.cells], (
        "notebooks/analysis.ipynb and analysis.py differ: "
        "run `jupytext --sync notebooks/analysis.py`"
    )


@pytest.mark.slow
def test_notebook_executes_on_stored_results(results_dir, tmp_path, monkeypatch):
    monkeypatch.setenv("FORMATION_BENCH_RESULTS", str(results_dir))
    monkeypatch.setenv("FORMATION_BENCH_CONVERGENCE_SEEDS", "2")
    monkeypatch.setenv("MPLBACKEND", "Agg")
    notebook = nbformat.read(ROOT / "notebooks" / "analysis.ipynb", as_version=4)
    client = NotebookClient(
        notebook,
        timeout=600,
        kernel_name="python3",
        resources={"metadata": {"path": str(ROOT / "notebooks")}},
    )
    client.execute()
    outputs = [out for cell in notebook.cells for out in cell.get("outputs", [])]
    assert not [out for out in outputs if out.output_type == "error"]
    images = [out for out in outputs if "image/png" in out.get("data", {})]
    # Figs. 3-7 (5), four comparison distributions (steady state, two errors, transient),
    # ECDF, solves, ablation distribution, convergence, trigger trade-off; two metrics
    # against N, one against the disturbance level, the separation figure
    assert len(images) == 18
    assert all(len(base64.b64decode(out["data"]["image/png"])) > 5_000 for out in images)
    sentences = [
        out["data"]["text/markdown"] for out in outputs if "text/markdown" in out.get("data", {})
    ]
    # 6 paper + 9 ablation + 9 comparison + 6 trigger + 18 swarm + 18 robustness + 12 obstacles
    assert any(s.startswith("Loaded 78 runs") for s in sentences)
    for heading in ("## Swarm:", "## Robustness:", "## Obstacles:"):
        assert any(s.startswith(heading) for s in sentences)
    assert not any("skipped" in s for s in sentences)
    assert not any("nan" in s for s in sentences)


def test_analysis_helpers_on_the_stored_results(results_dir):
    results = analysis.load_all(results_dir)
    assert set(results["suite"]) == set(SUITES)
    paper = analysis.suite_runs(results, "paper")
    table = analysis.paper_figures_table(paper)
    assert len(table) == 11
    assert set(table["holds on"].str.split("/").str[1]) == {"3 seeds"}
    row, trace = analysis.representative_run(results_dir, paper, True)
    assert bool(row["trigger"]) and len(trace) == 31 * 3
    median = sorted(paper[paper["trigger"]]["tracking_error_max_m"])[1]
    assert row["tracking_error_max_m"] == median
    tradeoff = analysis.trigger_tradeoff(
        pd.concat([analysis.suite_runs(results, "trigger"), paper[~paper["trigger"]]])
    )
    assert sorted(tradeoff["threshold_m"].unique()) == [0.0, 1.0, 4.0]
    # the combined frame carries the 5-UAV swarm's per-UAV columns; every run here has 3 UAVs
    assert "solves_uav5" in tradeoff.columns
    no_trigger = tradeoff[tradeoff["threshold_m"] == 0.0]
    assert (no_trigger["solves_saved"] == 0.0).all()
    expected = 1.0 - tradeoff["solves_total"] / (tradeoff["steps"] * 3)
    assert tradeoff["solves_saved"].to_numpy() == pytest.approx(expected.to_numpy(), rel=1e-12)
    swarm = analysis.scenario_section(analysis.suite_runs(results, "swarm"), "swarm")
    assert set(swarm.table["n_uav"]) == {3, 5}
    # the sentence quotes the table's medians on the complete graph
    text = analysis.swarm_sentence(swarm)
    rows = swarm.table[
        (swarm.table["metric"] == "tracking_error_max_m") & (swarm.table["graph"] == "complete")
    ]
    assert all(f"{v:.3g}" in text for v in rows["median"])
    ring_only = dataclasses.replace(swarm, table=swarm.table[swarm.table["graph"] != "complete"])
    assert analysis.swarm_sentence(ring_only).startswith("At N = 5 the lowest median")
    assert analysis.scenario_section(paper, "swarm") is None
    robustness = analysis.scenario_section(analysis.suite_runs(results, "robustness"), "robustness")
    assert " of 4 (level, optimiser, trigger) cells" in analysis.robustness_sentence(robustness)
    obstacles = analysis.scenario_section(analysis.suite_runs(results, "obstacles"), "obstacles")
    with warnings.catch_warnings():
        warnings.simplefilter("error", pd.errors.PerformanceWarning)
        sentence = analysis.obstacles_sentence(obstacles)
    assert sentence.count("paper-obstacles with penalties") == 4


def test_trigger_tradeoff_counts_each_runs_own_uavs():
    def run(trigger: bool, n_uav: int, solves_total: int, eps: float | None) -> dict:
        scenario = get_scenario("paper") if eps is None else get_scenario("paper", eps_p=eps)
        return {
            "trigger": trigger,
            "steps": 100,
            "solves_total": solves_total,
            "scenario_config": canonical_json(config_of(scenario)),
            **{f"solves_uav{k}": solves_total / n_uav for k in range(1, n_uav + 1)},
        }

    runs = pd.DataFrame(
        [run(False, 3, 300, None), run(True, 3, 120, 2.0), run(True, 20, 1000, 2.0)]
    )
    assert list(analysis.uav_counts(runs)) == [3, 3, 20]
    tradeoff = analysis.trigger_tradeoff(runs)
    assert list(tradeoff["threshold_m"]) == [0.0, 2.0, 2.0]
    assert list(tradeoff["solves_saved"]) == pytest.approx([0.0, 0.6, 0.5])


def runs_on(config: str, count: int, suite: str) -> pd.DataFrame:
    return pd.DataFrame(
        {
            "suite": [suite] * count,
            "scenario_name": ["paper"] * count,
            "scenario_overrides": ["{}"] * count,
            "scenario_config": [config] * count,
        }
    )


def test_suites_of_different_scenarios_are_not_pooled():
    comparison, paper = runs_on("30 instants", 3, "comparison"), runs_on("60 instants", 2, "paper")
    pooled, sentence = analysis.on_one_scenario({"comparison": comparison, "paper": paper})
    assert list(pooled["suite"]) == ["comparison"] * 3
    assert "2 runs of the `paper` suite ran another scenario than `comparison`'s" in sentence
    same = runs_on("30 instants", 2, "paper")
    pooled, sentence = analysis.on_one_scenario({"comparison": comparison, "paper": same})
    assert len(pooled) == 5 and "left out" not in sentence
    assert sentence.startswith("Runs of the `comparison` and `paper` suites on one scenario")
    # records without a resolved scenario: its registered name and overrides
    older = same.assign(scenario_config=None, scenario_overrides='{"n_steps": 60}')
    pooled, sentence = analysis.on_one_scenario({"comparison": comparison, "paper": older})
    assert len(pooled) == 3 and "left out" in sentence
    pooled, _ = analysis.on_one_scenario({"comparison": comparison.iloc[:0], "paper": same})
    assert list(pooled["suite"]) == ["paper"] * 2


def test_paper_sentence_counts_holds():
    table = pd.DataFrame(
        [
            {
                "run": "a",
                "figure": "x",
                "paper": "<= 1 m",
                "median": 0.5,
                "worst": 0.9,
                "holds on": "5/5 seeds",
            },
            {
                "run": "b",
                "figure": "y",
                "paper": "<= 1 m",
                "median": 1.2,
                "worst": 1.5,
                "holds on": "1/5 seeds",
            },
        ]
    )
    text = analysis.paper_sentence(table)
    assert text.startswith("1 of 2 reported figures hold on every seed")
    assert "b y: median 1.2, worst 1.5" in text


def test_missing_results_folder_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="formation-bench sweep"):
        analysis.load_all(tmp_path)
    assert os.path.isdir(tmp_path)


@pytest.mark.parametrize("value", ["", "x", "0", "-3", "2.5"])
def test_a_bad_convergence_seed_count_names_its_variable(value: str) -> None:
    with pytest.raises(ValueError, match="FORMATION_BENCH_CONVERGENCE_SEEDS") as raised:
        analysis.convergence_seed_count(value)
    assert "\n" not in str(raised.value)


def test_a_convergence_seed_count_reads_text_and_numbers() -> None:
    assert analysis.convergence_seed_count(" 4 ") == analysis.convergence_seed_count(4) == 4
