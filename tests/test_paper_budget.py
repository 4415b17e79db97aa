"""The budget the paper needs, on hand-made runs whose outcome is known, and the shipped sweep."""

import math

import pandas as pd
import pytest

from formation_bench.benchmarks.analysis import paper_budget
from formation_bench.benchmarks.analysis.paper import PAPER_FIGURES, Reading


def run(optimizer, max_evaluations, seed, trigger, *, tracking=0.5, settled_tracking=0.2,
        solves=None):  # fmt: skip
    """One run's row: every figure holds unless a value is given that breaks it."""
    row = {
        "optimizer": optimizer,
        "budget": "default" if max_evaluations is None else f"max_evaluations={max_evaluations}",
        "budget_max_evaluations": math.nan if max_evaluations is None else max_evaluations,
        "seed": seed,
        "trigger": trigger,
        "scenario_name": "paper",
        "scenario_overrides": "{}",
        "tracking_error_max_m": tracking,
        "tracking_error_max_settled_m": settled_tracking,
        "settling_time_s": math.nan if math.isnan(settled_tracking) else 12.0,
    }
    for pair in ("d12", "d23", "d31"):
        row[f"distance_error_max_m_{pair}"] = 0.1
        row[f"distance_error_max_settled_m_{pair}"] = 0.1 * settled_tracking / settled_tracking
    for k in (1, 2, 3):
        row[f"solves_uav{k}"] = (150 if trigger else 240) if solves is None else solves
    return row


def sweep(outcome) -> pd.DataFrame:
    """Ten seeds of 'a' at 100 and 200 evaluations, of the exact solver 'x' at its default;
    ``outcome(optimizer, max_evaluations, seed)`` gives a run's changed values."""
    rows = []
    for optimizer, budgets in (("a", (100, 200)), ("x", (None,))):
        for max_evaluations in budgets:
            for seed in range(10):
                for trigger in (True, False):
                    changes = outcome(optimizer, max_evaluations, seed, trigger)
                    rows.append(run(optimizer, max_evaluations, seed, trigger, **changes))
    return pd.DataFrame(rows)


def test_nine_of_ten_seeds_reach_the_paper_and_eight_do_not():
    def outcome(optimizer, max_evaluations, seed, trigger):
        # at 100 evaluations seeds 0 and 1 miss the tracking figure with the trigger (1.4 m);
        # at 200 only seed 0 does; the settled reading holds on every seed at both budgets
        misses = {100: (0, 1), 200: (0,)}.get(max_evaluations, ())
        return {"tracking": 1.5} if trigger and seed in misses else {}

    runs = paper_budget.runs_table(sweep(outcome))
    table = paper_budget.budget_table(runs).set_index(["optimizer", "reading", "budget"])
    at = table.loc["a", str(Reading.SETTLE_TIME)]
    assert list(at["seeds_all_held"]) == [8, 9]
    assert list(at["reaches_paper"]) == [False, True]
    assert list(at["figures_held_median"]) == [11, 11]
    figures = paper_budget.figure_table(runs).set_index(["optimizer", "reading", "budget"])
    held = figures.loc[("a", str(Reading.SETTLE_TIME), "100 evaluations")]
    assert held["trigger tracking"] == 8 and held["no trigger tracking"] == 10
    assert held["trigger d31"] == 10 and held["seeds"] == 10
    smallest = paper_budget.smallest_budgets(paper_budget.budget_table(runs))
    found = smallest.set_index(["optimizer", "reading"])["smallest_budget"]
    assert found["a", str(Reading.SETTLE_TIME)] == "200 evaluations"
    assert found["a", str(Reading.SETTLING)] == "100 evaluations"
    assert found["x", str(Reading.SETTLE_TIME)] == "default"


def test_a_run_that_never_settles_misses_its_error_figures_in_the_settling_reading():
    def outcome(optimizer, max_evaluations, seed, trigger):
        # two seeds never settle without the trigger at every budget
        return {"settled_tracking": math.nan} if not trigger and seed < 2 else {}

    runs = paper_budget.runs_table(sweep(outcome))
    outcomes = paper_budget.seed_outcomes(runs)
    unsettled = outcomes[(outcomes["seed"] == 0) & (outcomes["reading"] == "settling")]
    # the four error figures of the run without the trigger fail, its solve counts have none
    assert set(unsettled["figures_held"]) == {len(PAPER_FIGURES) - 4}
    smallest = paper_budget.smallest_budgets(paper_budget.budget_table(runs))
    settling = smallest[smallest["reading"] == "settling"].set_index("optimizer")
    assert pd.isna(settling.loc["a", "smallest_budget"])
    assert settling.loc["a", "seeds_all_held_at_largest"] == 8
    assert "not reached" in paper_budget.to_markdown(paper_budget.budget_table(runs), smallest)


def test_too_many_solves_break_the_trigger_figures():
    def outcome(optimizer, max_evaluations, seed, trigger):
        return {"solves": 161} if trigger else {}

    outcomes = paper_budget.seed_outcomes(paper_budget.runs_table(sweep(outcome)))
    assert set(outcomes["figures_held"]) == {len(PAPER_FIGURES) - 3}


def test_a_seed_without_both_runs_is_not_counted():
    frame = sweep(lambda *_: {})
    frame = frame[~((frame["seed"] == 3) & frame["trigger"])]
    table = paper_budget.budget_table(paper_budget.runs_table(frame))
    assert set(table.loc[table["optimizer"] == "a", "seeds"]) == {9}


def test_required_seeds():
    assert [paper_budget.required_seeds(n) for n in (10, 20, 5, 1)] == [9, 18, 5, 1]


def test_runs_table_refuses_results_without_the_figure_columns():
    frame = sweep(lambda *_: {}).drop(columns=["tracking_error_max_settled_m"])
    with pytest.raises(ValueError, match="tracking_error_max_settled_m"):
        paper_budget.runs_table(frame)
    assert not paper_budget.applies(frame)


def test_the_shipped_sweep_names_a_budget_for_every_optimiser_it_ran():
    runs = pd.read_csv(paper_budget.SHIPPED_RUNS)
    assert list(runs.columns) == [*paper_budget.KEYS, *paper_budget.figure_columns()]
    ran = set(runs["optimizer"])
    assert {"modified-bso", "pso", "cma-es", "de"} <= ran
    # ten seeds, both runs each, at every budget
    per_budget = runs.groupby(["optimizer", "budget"]).size()
    assert set(per_budget) == {20}
    for optimizer in ("modified-bso", "pso", "cma-es", "de"):
        line = paper_budget.shipped_line(optimizer)
        assert optimizer in line and "9 of 10 seeds" in line


def test_the_report_writes_the_section_and_the_form_that_ships(tmp_path):
    from formation_bench.benchmarks.analysis.report import write_paper_budget

    frame = sweep(lambda optimizer, m, seed, trigger: {"tracking": 2.0} if m == 100 else {})
    assert paper_budget.applies(frame)
    section = write_paper_budget(frame, tmp_path)
    assert (tmp_path / "paper_budget.md").read_text() == section
    assert "| a | settle-time | 200 evaluations | 10/10 | 200 evaluations |" in section
    runs = pd.read_csv(tmp_path / "paper_budget_runs.csv")
    assert len(runs) == 60
    line = paper_budget.shipped_line("a", tmp_path / "paper_budget_runs.csv")
    assert line.startswith("The paper's 11 figures on 9 of 10 seeds take a 200 evaluations")
