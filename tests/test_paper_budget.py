"""The budget the paper needs, on hand-made runs whose outcome is known, and the shipped sweep."""

import math

import pandas as pd
import pytest

from formation_bench.analysis import paper_budget
from formation_bench.analysis.paper import PAPER_FIGURES, Reading


def run(optimizer, max_evaluations, seed, trigger, *, tracking=0.5, settled_tracking=0.2,
        solves=None):  # fmt: skip
    """One run's row: every figure holds unless a value is given that breaks it."""
    row = {
        "optimizer": optimizer,
        "optimizer_name": optimizer,
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
    """Ten seeds of 'a' at 100 and 200 evaluations, of the exact solver 'ipopt' at its default;
    ``outcome(optimizer, max_evaluations, seed)`` gives a run's changed values."""
    rows = []
    for optimizer, budgets in (("a", (100, 200)), ("ipopt", (None,))):
        for max_evaluations in budgets:
            for seed in range(10):
                for trigger in (True, False):
                    changes = outcome(optimizer, max_evaluations, seed, trigger)
                    rows.append(run(optimizer, max_evaluations, seed, trigger, **changes))
    return pd.DataFrame(rows)


def smallest(runs):
    table = paper_budget.smallest_budgets(paper_budget.budget_table(runs))
    return table.set_index(["optimizer", "reading", "target"])


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
    assert list(at["reaches_all"]) == [False, True]
    assert list(at["figures_held_median"]) == [11, 11]
    figures = paper_budget.figure_table(runs).set_index(["optimizer", "reading", "budget"])
    held = figures.loc[("a", str(Reading.SETTLE_TIME), "max_evaluations=100")]
    assert held["trigger tracking"] == 8 and held["no trigger tracking"] == 10
    assert held["trigger d31"] == 10 and held["seeds"] == 10
    found = smallest(runs)["smallest_budget"]
    assert found["a", str(Reading.SETTLE_TIME), paper_budget.ALL] == "200 evaluations"
    assert found["a", str(Reading.SETTLING), paper_budget.ALL] == "100 evaluations"
    assert found["ipopt", str(Reading.SETTLE_TIME), paper_budget.ALL] == "default"


def test_a_figure_the_exact_solver_misses_is_left_out_of_the_second_target():
    def outcome(optimizer, max_evaluations, seed, trigger):
        # the no-trigger tracking figure (1.25 m) fails for the exact solver on every seed and
        # for 'a' too; at 100 evaluations 'a' also misses the trigger tracking on seeds 0-1
        changes = {"tracking": 1.3} if not trigger else {}
        if trigger and max_evaluations == 100 and seed < 2:
            changes = {"tracking": 1.5}
        return changes

    runs = paper_budget.runs_table(sweep(outcome))
    reached = paper_budget.reference_figures(paper_budget.figure_table(runs))
    assert reached[str(Reading.SETTLE_TIME)] == [
        n for n in paper_budget.FIGURE_NAMES if n != "no trigger tracking"
    ]
    found = smallest(runs)
    settle = str(Reading.SETTLE_TIME)
    assert pd.isna(found.loc[("a", settle, paper_budget.ALL), "smallest_budget"])
    assert found.loc[("a", settle, paper_budget.ALL), "seeds_held"] == 0
    second = found.loc[("a", settle, paper_budget.REACHED)]
    assert second["smallest_budget"] == "200 evaluations" and second["figures"] == 10
    assert second["seeds_held"] == 10
    markdown = paper_budget.to_markdown(
        paper_budget.budget_table(runs),
        paper_budget.smallest_budgets(paper_budget.budget_table(runs)),
    )
    assert (
        "| a | settle-time | not reached (0/10 at 200 evaluations) | 10: 200 evaluations"
        in markdown
    )


def test_a_run_that_never_settles_misses_its_error_figures_in_the_settling_reading():
    def outcome(optimizer, max_evaluations, seed, trigger):
        # two seeds never settle without the trigger at every budget
        return {"settled_tracking": math.nan} if not trigger and seed < 2 else {}

    runs = paper_budget.runs_table(sweep(outcome))
    outcomes = paper_budget.seed_outcomes(runs)
    unsettled = outcomes[(outcomes["seed"] == 0) & (outcomes["reading"] == "settling")]
    # the four error figures of the run without the trigger fail, its solve counts have none
    figures = unsettled[list(paper_budget.FIGURE_NAMES)]
    assert set(figures.sum(axis=1)) == {len(PAPER_FIGURES) - 4}
    row = smallest(runs).loc[("a", str(Reading.SETTLING), paper_budget.ALL)]
    assert pd.isna(row["smallest_budget"]) and row["seeds_held"] == 8
    table = paper_budget.budget_table(runs)
    markdown = paper_budget.to_markdown(table, paper_budget.smallest_budgets(table))
    assert "not reached (8/10 at 200 evaluations)" in markdown


def test_too_many_solves_break_the_trigger_figures():
    def outcome(optimizer, max_evaluations, seed, trigger):
        return {"solves": 161} if trigger else {}

    outcomes = paper_budget.seed_outcomes(paper_budget.runs_table(sweep(outcome)))
    held = outcomes[list(paper_budget.FIGURE_NAMES)].sum(axis=1)
    assert set(held) == {len(PAPER_FIGURES) - 3}


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
        assert f"({optimizer}, figures together on 9 of 10 seeds" in line
    # the exact solvers ran at their own budgets, as references
    assert set(runs.loc[runs["optimizer_name"].isin(paper_budget.REFERENCES), "budget"]) == {
        "default"
    }


def test_the_report_writes_the_section_and_the_form_that_ships(tmp_path):
    from formation_bench.analysis.report import write_paper_budget

    frame = sweep(lambda optimizer, m, seed, trigger: {"tracking": 2.0} if m == 100 else {})
    assert paper_budget.applies(frame)
    section = write_paper_budget(frame, tmp_path)
    assert (tmp_path / "paper_budget.md").read_text() == section
    assert "| a | settle-time | 200 evaluations (10/10 seeds) |" in section
    runs = pd.read_csv(tmp_path / "paper_budget_runs.csv")
    assert len(runs) == 60
    line = paper_budget.shipped_line("a", tmp_path / "paper_budget_runs.csv")
    assert line.startswith("Budget the paper needs (a, figures together on 9 of 10 seeds")
    assert "all 11: 200 evaluations (errors from 10 s), 100 evaluations (from settling)" in line


def test_only_runs_of_the_unmodified_paper_scenario_count_for_the_section_and_its_tables():
    unmodified = sweep(lambda *_: {})
    changed = unmodified.assign(scenario_overrides='{"n_steps":12}')
    # the paper scenario changed, at both budgets with and without the trigger: the figures
    # are not of that problem, so there is nothing to tabulate and no section
    assert paper_budget.runs_table(changed).empty
    assert not paper_budget.applies(changed)
    # unmodified runs at one budget beside changed ones at two: one budget, no section
    one_budget = unmodified[unmodified["budget"] == "max_evaluations=200"]
    assert not paper_budget.applies(pd.concat([one_budget, changed]))
    both = pd.concat([unmodified, changed])
    assert paper_budget.applies(both)
    pd.testing.assert_frame_equal(
        paper_budget.runs_table(both), paper_budget.runs_table(unmodified)
    )


def test_runs_without_a_seed_holding_both_trigger_settings_get_no_section():
    frame = sweep(lambda *_: {})
    # the trigger on at one budget, off at the other: no seed is a pair of runs
    unpaired = frame[frame["trigger"] == (frame["budget"] == "max_evaluations=100")]
    assert unpaired["trigger"].nunique() == 2 and unpaired["budget"].nunique() == 3
    assert not paper_budget.applies(unpaired)
    assert paper_budget.smallest_budgets(paper_budget.budget_table(
        paper_budget.runs_table(unpaired))).empty  # fmt: skip
