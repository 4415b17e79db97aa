"""``formation-bench report`` on valid stored results that once made it fail: small sweeps and
score runs made with the command line, as tests/page_numbers.py makes its results."""

from pathlib import Path

import pandas as pd
from page_numbers import cli, sweep

from formation_bench.optimizers.tuned import tuned_data

OVERRIDDEN_PAPER = """\
name = "overridden-paper"
seeds = 2
triggers = [true, false]
budgets = [{ max_evaluations = 100 }, { max_evaluations = 200 }]
trace = false

[[optimizers]]
name = "pso"

[[scenarios]]
name = "paper"
overrides = { n_steps = 12, settle_time_s = 1.0 }
"""
"""The paper scenario shortened, at two budgets with and without the trigger: not the problem
the paper's figures are of."""

UNSETTLED_PAIR = """\
name = "unsettled-pair"
seeds = 3
triggers = [true]
budgets = [{ max_evaluations = 100 }]
trace = false

[[optimizers]]
name = "pso"

[[optimizers]]
name = "pso-warm"

[[scenarios]]
name = "paper"
overrides = { n_steps = 12, settle_time_s = 1.0 }
"""
"""A variant and its base in runs too short to settle: the settling time has no value in any
run of either."""


def report(results: Path, root: Path) -> Path:
    """``formation-bench report RESULTS``; returns the report folder."""
    out = root / f"{results.name}-report"
    cli("report", str(results), "--out", str(out), "--no-figures")
    return out


def test_a_shortened_paper_scenario_at_two_budgets_has_no_paper_budget_section(tmp_path):
    out = report(sweep(tmp_path, "overridden", OVERRIDDEN_PAPER), tmp_path)
    assert "The budget the paper needs" not in (out / "report.md").read_text()
    assert not (out / "paper_budget.csv").exists()


def test_a_metric_no_run_of_a_pair_has_shows_as_missing(tmp_path):
    out = report(sweep(tmp_path, "unsettled", UNSETTLED_PAIR), tmp_path)
    pairs = pd.read_csv(out / "variant_pairs.csv").set_index("metric")
    assert pairs.loc["settling_time_s", "n_pairs"] == 0
    assert pd.isna(pairs.loc["settling_time_s", "p"])
    # the pair's row in every table its metrics are split into
    rows = [
        line for line in (out / "variant_pairs.md").read_text().splitlines()
        if line.startswith("| pso-warm | pso | 3 |")
    ]  # fmt: skip
    assert len(rows) >= 1
    assert sum(row.count("– (n 0) vs – (n 0), –, A12 –") for row in rows) == 1


def test_a_tuned_pair_scored_only_off_its_tuning_budget_gets_a_line_not_a_rank_change(tmp_path):
    tuned_at = tuned_data("pso-tuned")["objective"]["budget"]
    scored_at = 300 if tuned_at != 300 else 200
    out = tmp_path / "score"
    for optimizer in ("pso", "pso-tuned"):
        cli("score", "--optimizer", optimizer, "--budgets", str(scored_at), "--out", str(out),
            "--jobs", "1")  # fmt: skip
    folder = report(out, tmp_path)
    markdown = (folder / "score.md").read_text()
    assert "## Rank change" not in markdown
    assert (
        f"Note: no rank change of pso with pso-tuned, tuned at max_evaluations={tuned_at}: "
        "pso-tuned and pso have no score runs at that budget (nor at default)"
    ) in markdown
    assert pd.read_csv(folder / "score_rank_change.csv").empty
    assert f"## budget max_evaluations={scored_at}" in markdown  # the leaderboard is there
