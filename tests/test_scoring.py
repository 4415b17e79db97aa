"""The scoring statistics and the score report's tables against values worked out by hand
on small tables."""

import math

import numpy as np
import pandas as pd
import pytest

from formation_bench.analysis import score_report
from formation_bench.analysis.cells import TABLE_WIDTH, column_width, metric_column, share_cell
from formation_bench.analysis.scoring import (
    SUCCESS_TARGETS,
    TARGETS,
    evaluations_to_target,
    expected_running_time,
    normalised_gap,
    performance_profile,
    relative_gap,
    runtime_ecdf,
    shifted_geometric_mean,
    success_rate,
)
from formation_bench.experiments.score import SCORE_FORMAT, target_column
from perf.page_numbers import markdown_tables

# --- reading the Markdown tables of a report --------------------------------------------------


def table_widths(markdown: str) -> list[int]:
    """The narrowest each table of ``markdown`` can be, in the characters of
    :func:`~formation_bench.analysis.cells.column_width`."""
    return [
        sum(column_width(column) for column in zip(t.header, *t.rows, strict=True))
        for t in markdown_tables(markdown)
    ]


def joined_rows(markdown: str, lead: list[str]) -> dict[tuple[str, ...], list[str]]:
    """The rows of the tables of ``markdown`` whose first headers are ``lead`` (a table split
    into parts of the same rows), each row's cells after the lead joined over the parts in
    order, by the row's lead cells."""
    rows: dict[tuple[str, ...], list[str]] = {}
    for table in markdown_tables(markdown):
        if table.header[: len(lead)] == lead:
            for row in table.rows:
                rows.setdefault(tuple(row[: len(lead)]), []).extend(row[len(lead) :])
    return rows


# --- the gaps and the statistics of trials ----------------------------------------------------


def test_relative_and_normalised_gap_on_three_instances():
    # A: J* 100, warm start 200, f 150: half of the possible improvement left, half of J*
    # B: J* 2, warm start 3, f 2.5: the same half left, but a quarter of J*
    # C: J* 5, warm start 5 (already optimal), f 6: no normalised gap, relative 0.2
    j_star = np.array([100.0, 2.0, 5.0])
    warm = np.array([200.0, 3.0, 5.0])
    cost = np.array([150.0, 2.5, 6.0])
    np.testing.assert_allclose(relative_gap(cost, j_star), [0.5, 0.25, 0.2])
    gaps = normalised_gap(cost, j_star, warm)
    np.testing.assert_allclose(gaps[:2], [0.5, 0.5])
    assert math.isnan(gaps[2])
    # 1 at the warm start, 0 at J*, negative below it
    assert normalised_gap(200.0, 100.0, 200.0) == 1.0
    assert normalised_gap(100.0, 100.0, 200.0) == 0.0
    assert normalised_gap(90.0, 100.0, 200.0) == pytest.approx(-0.1)


def test_targets_are_declared_once_on_the_normalised_gap():
    assert TARGETS == (1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6)
    assert set(SUCCESS_TARGETS) <= set(TARGETS)
    assert target_column(1e-3) == "evals_to_norm_1e-03"
    assert score_report.success_column(1e-2) == "success_norm_1e-02"


def test_evaluations_to_a_target_of_the_normalised_gap():
    nfev = np.array([10, 20, 30, 40])
    best = np.array([200.0, 150.0, 110.0, 100.05])  # normalised gaps 1, 0.5, 0.1, 5e-4
    assert evaluations_to_target(nfev, best, 100.0, 200.0, 0.5) == 20
    assert evaluations_to_target(nfev, best, 100.0, 200.0, 1e-1) == 30
    assert evaluations_to_target(nfev, best, 100.0, 200.0, 1e-3) == 40
    assert math.isnan(evaluations_to_target(nfev, best, 100.0, 200.0, 1e-4))
    # a warm start that leaves nothing to gain has no normalised gap: never reached
    assert math.isnan(evaluations_to_target(nfev, best, 100.0, 100.0, 0.5))
    # J* 100, warm start 100.5: f 100.05 is within 1e-3 of J* (relative 5e-4), but leaves a
    # tenth of the possible improvement: not at the normalised target 1e-3, only at 1e-1
    near = np.array([100.05])
    assert relative_gap(100.05, 100.0) <= 1e-3
    assert math.isnan(evaluations_to_target(np.array([7]), near, 100.0, 100.5, 1e-3))
    assert evaluations_to_target(np.array([7]), near, 100.0, 100.5, 1e-1) == 7


def test_success_rate():
    gaps = np.array([0.0, 5e-3, 2e-2, 1e-4, 0.5])
    assert success_rate(gaps, 1e-2) == pytest.approx(3 / 5)
    assert success_rate(gaps, 1e-4) == pytest.approx(2 / 5)
    # weights 1/2 on the first two (one problem solved twice): (1/2 + 1/2 + 1) / 4
    weights = np.array([0.5, 0.5, 1.0, 1.0, 1.0])
    assert success_rate(gaps, 1e-4, weights) == pytest.approx(1.5 / 4)
    assert success_rate(np.array([np.nan, 0.0]), 1e-2) == 0.5  # no gap: no success


def test_expected_running_time_counts_failures_at_their_full_cost():
    # two successes after 100 and 300 evaluations, one failure that used 1000:
    # (100 + 300 + 1000) / 2 = 700
    hits = np.array([100.0, math.nan, 300.0])
    used = np.array([500.0, 1000.0, 800.0])
    assert expected_running_time(hits, used) == pytest.approx(700.0)
    assert expected_running_time(np.array([math.nan]), np.array([10.0])) == math.inf
    # weighted (the first and third: one problem, 1/2 each): (50 + 1000 + 150) / 1 = 1200
    weights = np.array([0.5, 1.0, 0.5])
    assert expected_running_time(hits, used, weights) == pytest.approx(1200.0)


def test_expected_running_time_to_a_normalised_target_from_histories():
    # J* 100, warm start 200; target 1e-3 of the normalised gap, i.e. a cost <= 100.1
    # trial 1: best 150 at 10, 100.05 at 50 (5e-4), 80 used: a success after 50
    # trial 2: best 190 at 10, 120 at 90 (0.2), 100 used: a failure, charged its 100
    hits = [
        evaluations_to_target(np.array([10, 50]), np.array([150.0, 100.05]), 100.0, 200.0, 1e-3),
        evaluations_to_target(np.array([10, 90]), np.array([190.0, 120.0]), 100.0, 200.0, 1e-3),
    ]
    assert hits[0] == 50 and math.isnan(hits[1])
    assert expected_running_time(np.array(hits), np.array([80.0, 100.0])) == pytest.approx(150.0)


def test_runtime_ecdf_counts_trial_target_pairs():
    # 2 trials x 2 targets: reached at 10, 50, 30 evaluations and once never
    hits = np.array([[10.0, 50.0], [30.0, math.nan]])
    np.testing.assert_allclose(runtime_ecdf(hits, np.array([5, 10, 40, 100])), [0, 0.25, 0.5, 0.75])
    # the second trial weighted 3 times the first: pairs 10, 50 weigh 1, pairs 30, never 3
    weighted = runtime_ecdf(hits, np.array([5, 10, 40, 100]), np.array([1.0, 3.0]))
    np.testing.assert_allclose(weighted, [0, 1 / 8, 4 / 8, 5 / 8])


def test_performance_profile_by_hand():
    # problem 1: A 1 s, B 2 s; problem 2: A fails, B 3 s; problem 3: A 4 s, B 4 s
    costs = pd.DataFrame({"A": [1.0, math.nan, 4.0], "B": [2.0, 3.0, 4.0]})
    profile = performance_profile(costs, np.array([1.0, 2.0, 10.0]))
    # ratios A: 1, inf, 1; B: 2, 1, 1
    assert profile["A"].tolist() == pytest.approx([2 / 3, 2 / 3, 2 / 3])
    assert profile["B"].tolist() == pytest.approx([2 / 3, 1.0, 1.0])


def test_shifted_geometric_mean_charges_failures():
    # shift 1: values 1 and 7 -> exp(mean(log 2, log 8)) - 1 = 4 - 1 = 3
    assert shifted_geometric_mean(np.array([1.0, 7.0]), shift=1.0) == pytest.approx(3.0)
    # the second fails and is charged 15: exp(mean(log 2, log 16)) - 1 = sqrt(32) - 1
    failed = np.array([False, True])
    value = shifted_geometric_mean(np.array([1.0, 7.0]), 1.0, failed, charge=15.0)
    assert value == pytest.approx(math.sqrt(32) - 1)
    # weights 3 and 1: exp((3 log 2 + log 8) / 4) - 1 = 2^(6/4) - 1
    weighted = shifted_geometric_mean(np.array([1.0, 7.0]), 1.0, weights=np.array([3.0, 1.0]))
    assert weighted == pytest.approx(2**1.5 - 1)


# --- the score report's tables ----------------------------------------------------------------


def trial(problem, j_star, warm, fun, *, optimizer="A", run="r1", seed=0, nfev=1000, **extra):
    """One score row as ``execute_score`` writes it, with the gaps computed from the costs."""
    degenerate = extra.pop("degenerate", False)
    gap = math.nan if degenerate else float(normalised_gap(fun, j_star, warm))
    row = {
        "run_key": run,
        "optimizer": optimizer,
        "budget": "default",
        "seed": seed,
        "library": "v2",
        "run_split": "test",
        "instance": int(problem[1:]),
        "content_hash": problem,
        "phase": "steady",
        "degenerate": degenerate,
        "j_star": j_star,
        "warm_cost": warm,
        "fun": fun,
        "gap": float(relative_gap(fun, j_star)),
        "normalised_gap": gap,
        "nfev": nfev,
        "seconds": 0.01,
        **{target_column(t): math.nan for t in TARGETS},
        "score_format": SCORE_FORMAT,
    }
    row.update(extra)
    return row


def toy_scores() -> pd.DataFrame:
    """One optimiser on three problems, the second solved twice (by a second run over an
    overlapping split), and two degenerate problems."""
    hit = target_column(1e-3)
    return pd.DataFrame(
        [
            # normalised gap 5e-3, relative 5e-3
            trial("h1", 100.0, 200.0, 100.5, phase="start-up"),
            # normalised and relative 5e-5, then 2e-4; reaches 1e-3 after 300 and 600
            trial("h2", 10.0, 20.0, 10.0005, phase="transient", **{hit: 300.0}),
            trial("h2", 10.0, 20.0, 10.002, run="r2", phase="transient", **{hit: 600.0}),
            # normalised and relative 0.5, 400 evaluations used
            trial("h3", 1.0, 2.0, 1.5, nfev=400),
            # degenerate: far off (|f - J*| about 0.5) and at its warm start (|f - J*| 1e-9)
            trial("h4", 1e-9, 1e-9, 0.5, degenerate=True),
            trial("h5", 2e-9, 3e-9, 3e-9, degenerate=True),
        ]
    )


def test_headline_counts_each_problem_once_and_leaves_out_the_degenerate():
    summary = score_report.summary_table(toy_scores())
    (row,) = summary.to_dict("records")
    assert (row["instances"], row["trials"], row["rank"]) == (3, 4, 1)
    # per problem: 5e-3, mean(5e-5, 2e-4) = 1.25e-4, 0.5 -> median 5e-3 (the four trials
    # without averaging would give (2e-4 + 5e-3) / 2; with h4, 0.5 and more)
    assert row["norm_gap_median"] == pytest.approx(5e-3)
    assert row["gap_median"] == pytest.approx(5e-3)
    # success, each problem weighted once (h2's two trials 1/2 each):
    # 1e-2: h1, h2 twice -> (1 + 1 + 0) / 3;  1e-3: h2 twice -> 1/3;  1e-4: h2 once -> 1/6
    assert row["success_norm_1e-02"] == pytest.approx(2 / 3)
    assert row["success_norm_1e-03"] == pytest.approx(1 / 3)
    assert row["success_norm_1e-04"] == pytest.approx(1 / 6)
    # median evaluations over problems: 1000, 1000, 400
    assert row["nfev_median"] == 1000


def test_ert_to_a_normalised_target_weights_each_problem_once():
    ert = score_report.ert_table(toy_scores())
    row = ert[ert["target_norm_gap"] == 1e-3].iloc[0]
    # h1 fails (1000 used, weight 1), h2 hits after 300 and 600 (weight 1/2 each), h3 fails
    # (400 used, weight 1): (1000 + 150 + 300 + 400) / (1/2 + 1/2) = 1850
    assert row["successes"] == 2 and row["trials"] == 4
    assert row["ert_evaluations"] == pytest.approx(1850.0)
    assert (ert.loc[ert["target_norm_gap"] != 1e-3, "ert_evaluations"] == math.inf).all()


def test_degenerate_stratum_by_hand():
    (row,) = score_report.degenerate_table(toy_scores()).to_dict("records")
    assert (row["instances"], row["trials"]) == (2, 2)
    # h4 ends above its warm start, h5 at it
    assert row["warm_or_better_share"] == pytest.approx(0.5)
    # |f - J*|: 0.5 - 1e-9 and 1e-9 -> median 0.25
    assert row["abs_error_median"] == pytest.approx(0.25)


def test_phase_medians_by_hand():
    phases = score_report.phase_table(toy_scores()).set_index("phase")
    assert phases.loc["start-up", "norm_gap_median"] == pytest.approx(5e-3)
    assert phases.loc["transient", "norm_gap_median"] == pytest.approx(1.25e-4)
    assert phases.loc["steady", "norm_gap_median"] == pytest.approx(0.5)
    assert phases["instances"].tolist() == [1, 1, 1]  # h3 only: h4, h5 are degenerate


def test_repeated_problems_are_counted_and_said():
    scores = toy_scores()
    assert score_report.repeated_problems(scores) == (0, 1)  # h2 of seed 0 in runs r1, r2
    again = pd.concat([scores, scores.iloc[[0]]], ignore_index=True)  # h1 twice in run r1
    assert score_report.repeated_problems(again) == (1, 1)
    markdown = score_report.to_markdown(
        score_report.summary_table(again),
        score_report.degenerate_table(again),
        score_report.phase_table(again),
        score_report.paired_table(again),
        library="v2 (split test)",
        notes=score_report._notes(again),
    )
    assert "1 score rows repeat the problem (content hash)" in markdown
    assert "1 (optimizer, budget, seed, problem) were solved by more than one run" in markdown
    assert "**Ranked by the median normalised gap**" in markdown


def paired_scores() -> pd.DataFrame:
    """12 problems: pso below modified-bso on every one, pso-warm between them, and a warm
    variant without its uniform-start counterpart."""
    rows = []
    for k in range(12):
        for optimizer, gap in (
            ("modified-bso", 0.5 + 0.01 * k),
            ("pso", 0.1 + 0.01 * k),
            ("pso-warm", 0.3 + 0.01 * k),
            ("de-warm", 0.5 + 0.01 * k),  # equal to modified-bso: no evidence either way
        ):
            rows.append(trial(f"h{k}", 1.0, 2.0, 1.0 + gap, optimizer=optimizer, run=optimizer))
    return pd.DataFrame(rows)


def test_paired_table_by_hand():
    paired = score_report.paired_table(paired_scores())
    kinds = list(dict.fromkeys(paired["comparison"]))
    # pso leaves the smallest median gap: the leader
    assert kinds == [
        "against modified-bso",
        "against the leader, pso",
        "warm start against uniform start",
    ]
    by_kind = {kind: rows.set_index(["x", "y"]) for kind, rows in paired.groupby("comparison")}
    table = by_kind["against modified-bso"]
    assert list(table.index) == [
        ("de-warm", "modified-bso"),
        ("pso", "modified-bso"),
        ("pso-warm", "modified-bso"),
    ]
    leader = by_kind["against the leader, pso"]
    assert list(leader.index) == [("de-warm", "pso"), ("modified-bso", "pso"), ("pso-warm", "pso")]
    warm = by_kind["warm start against uniform start"]
    assert list(warm.index) == [("pso-warm", "pso")]
    assert (paired["pairs"] == 12).all()
    # every difference of one sign: W = 0, exact two-sided p = 2 * 2^-12 = 2^-11
    for pair in [("pso", "modified-bso"), ("pso-warm", "modified-bso")]:
        assert table.loc[pair, "p"] == pytest.approx(2**-11)
    assert warm.loc[("pso-warm", "pso"), "p"] == pytest.approx(2**-11)
    # every pso value below every modified-bso value: A12 = 0; pso-warm above pso: A12 = 1
    assert table.loc[("pso", "modified-bso"), "a12"] == 0.0
    assert warm.loc[("pso-warm", "pso"), "a12"] == 1.0
    assert leader.loc[("modified-bso", "pso"), "a12"] == 1.0
    assert table.loc[("pso", "modified-bso"), "x_lower"] == 12
    assert table.loc[("pso", "modified-bso"), "reading"].startswith("favours pso:")
    assert warm.loc[("pso-warm", "pso"), "reading"].startswith("favours pso:")
    # de-warm equals modified-bso on every problem: p 1, A12 0.5, 12 ties
    equal = table.loc[("de-warm", "modified-bso")]
    assert (equal["p"], equal["a12"], equal["ties"]) == (1.0, 0.5, 12)
    assert equal["reading"].startswith("no difference")
    # Holm within each kind at the budget: three against modified-bso, p 2^-11, 2^-11, 1
    # -> 3 * 2^-11, max(2 * 2^-11, 3 * 2^-11) = 3 * 2^-11, 1; the warm pair alone keeps 2^-11;
    # against the leader all three p are 2^-11 -> 3 * 2^-11
    assert table.loc[("pso", "modified-bso"), "p_holm"] == pytest.approx(3 * 2**-11)
    assert table.loc[("pso-warm", "modified-bso"), "p_holm"] == pytest.approx(3 * 2**-11)
    assert table.loc[("de-warm", "modified-bso"), "p_holm"] == 1.0
    assert warm.loc[("pso-warm", "pso"), "p_holm"] == pytest.approx(2**-11)
    assert leader["p_holm"].tolist() == pytest.approx([3 * 2**-11] * 3)
    # without modified-bso: against the leader and the warm pairs
    alone = score_report.paired_table(paired_scores().query("optimizer != 'modified-bso'"))
    assert list(zip(alone["comparison"], alone["x"], alone["y"], strict=True)) == [
        ("against the leader, pso", "de-warm", "pso"),
        ("against the leader, pso", "pso-warm", "pso"),
        ("warm start against uniform start", "pso-warm", "pso"),
    ]


def test_the_experiments_import_nothing_from_the_analysis():
    """The analysis reads what the experiments produce: the gaps and targets a score run
    records are the experiments' own, and the analysis takes them from there."""
    import ast
    from pathlib import Path

    from formation_bench import experiments
    from formation_bench.analysis import scoring
    from formation_bench.experiments import gaps

    for path in Path(experiments.__file__).parent.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = (
                [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else []
            )
            assert not [n for n in names if n.startswith("formation_bench.analysis")], path.name
    assert scoring.normalised_gap is gaps.normalised_gap and scoring.TARGETS is gaps.TARGETS


def test_a_share_that_would_print_as_100_or_0_percent_prints_as_a_count():
    # 201 problems: all but one reach 1e-2 and 1e-3, one reaches 1e-4; one degenerate problem
    # of 201 is at its warm start (the rest of that stratum is left out: 1 of 1)
    rows = [trial(f"h{k}", 1.0, 2.0, 1.0 + (1e-5 if k == 0 else 5e-4)) for k in range(200)]
    rows.append(trial("h200", 1.0, 2.0, 1.5))
    rows.append(trial("h201", 1e-9, 1e-9, 1e-9, degenerate=True))
    scores = pd.DataFrame(rows)
    markdown = score_report.to_markdown(
        score_report.summary_table(scores),
        score_report.degenerate_table(scores),
        score_report.phase_table(scores),
        score_report.paired_table(scores),
        library="v2 (split test)",
    )
    # the leaderboard may be split into tables of the same rows: its row joined over them
    (line,) = [cells for lead, cells in joined_rows(markdown, ["rank", "optimizer"]).items()
               if lead == ("1", "A")]  # fmt: skip
    line = "| " + " | ".join(line) + " |"
    assert "| 200/201 | 200/201 | 1/201 |" in line
    assert "100%" not in line and "| 0%" not in line
    (line,) = [row for row in markdown.splitlines() if row.startswith("| A | 1 | 1 |")]
    assert "| 100% |" in line  # exactly every one: a percentage


def test_the_share_formatter_reads_100_or_0_only_when_it_is():
    assert share_cell(587 / 588, 588) == "587/588"
    assert share_cell(1 / 588, 588) == "1/588"
    assert share_cell(586.5 / 588, 588) == "586.5/588"  # a problem's two trials averaged
    assert share_cell(0.92, 588) == "92%"
    assert share_cell(1.0, 588) == "100%" and share_cell(0.0, 588) == "0%"
    # a share of no stated count, in a column headed in %: digits until it is not 100
    assert share_cell(0.9996) == "99.96" and share_cell(0.999996) == "99.9996"
    assert share_cell(0.5) == "50" and share_cell(1.0) == "100" and share_cell(0.0) == "0"
    assert share_cell(1e-5) == "0.00100"
    assert share_cell(math.nan, 5) == "–"
    # a fraction metric's column goes through it
    column = metric_column("solves_at_bound_share", [0.9996])
    assert column.unit == "%" and column.value(0.9996) == "99.96"
    assert column.with_unit(0.9996) == "99.96 %"


# --- the rank change of the families with a tuned variant -------------------------------------

AT_1200 = "max_evaluations=1200"


TUNED_GAPS = {
    # (optimizer, budget): the normalised gap of problem k is base + slope * k; the bases >= 0.15
    # apart and the slopes distinct, so that no two paired differences tie (Wilcoxon's exact p)
    ("pso-tuned-loop", AT_1200): (0.0, 0.0100),
    ("pso-tuned", AT_1200): (0.15, 0.0107),
    ("de", AT_1200): (0.3, 0.0114),
    ("pso", AT_1200): (0.45, 0.0121),
    ("pso-warm", AT_1200): (0.6, 0.0128),
    ("ilqr", "default"): (0.75, 0.0135),
    ("modified-bso", AT_1200): (0.9, 0.0142),
    ("modified-bso-tuned", AT_1200): (1.1, 0.0149),
    # at the default budget pso and de swap places: a ranking read there shows
    ("de", "default"): (1.2, 0.0156),
    ("pso", "default"): (0.0, 0.0163),
}


def tuned_scores() -> pd.DataFrame:
    """12 problems (:data:`TUNED_GAPS`): at 1200 evaluations pso-tuned below pso on every
    problem, modified-bso-tuned above modified-bso, pso-warm and pso-tuned-loop beside them;
    ilqr only at its own budget."""
    rows = [
        trial(f"h{k}", 1.0, 2.0, 1.0 + base + slope * k, optimizer=optimizer, run=optimizer,
              budget=budget)
        for (optimizer, budget), (base, slope) in TUNED_GAPS.items()
        for k in range(12)
    ]  # fmt: skip
    return pd.DataFrame(rows)


def test_rank_change_ranks_every_family_at_default_then_at_tuned_at_the_tuning_budget():
    scores = tuned_scores()
    summary = score_report.summary_table(scores)
    budgets = {"pso-tuned": 1200, "modified-bso-tuned": 1200}
    table = score_report.rank_change_table(scores, summary, budgets).set_index("family")
    assert list(table.index) == ["modified-bso", "pso"]
    assert set(table["budget"]) == {AT_1200}
    # default: de 1, pso 2, pso-warm 3, ilqr 4 (its own budget), modified-bso 5;
    # tuned: pso-tuned 1, de 2, pso-warm 3, ilqr 4, modified-bso-tuned 5
    assert (table.loc["pso", "default_rank"], table.loc["pso", "tuned_rank"]) == (2, 1)
    assert table.loc["pso", "rank_change"] == 1
    assert (table.loc["modified-bso", "default_rank"], table.loc["modified-bso", "tuned_rank"]) == (
        5,
        5,
    )
    assert (table["optimizers"] == 5).all()
    # the median of base + slope * k over k = 0 .. 11: base + 5.5 slope
    assert table.loc["pso", "default_median"] == pytest.approx(0.45 + 5.5 * 0.0121)
    assert table.loc["pso", "tuned_median"] == pytest.approx(0.15 + 5.5 * 0.0107)
    # paired by problem: every difference of one sign, exact p 2^-11, Holm over the 2 families
    assert (table["pairs"] == 12).all()
    assert table["p"].tolist() == pytest.approx([2**-11] * 2)
    assert table["p_holm"].tolist() == pytest.approx([2 * 2**-11] * 2)
    # A12 = P(tuned > default): every pso-tuned value below every pso value, every
    # modified-bso-tuned value above every modified-bso value
    assert (table.loc["pso", "a12"], table.loc["modified-bso", "a12"]) == (0.0, 1.0)
    # a tuned variant whose tuning budget is unknown has no row; one tuned at 300 evaluations
    # is ranked at that budget, where it has no score runs (nor at its own budget): no row
    alone = score_report.rank_change_table(scores, summary, {"pso-tuned": 1200})
    assert list(alone["family"]) == ["pso"]
    assert score_report.rank_change_table(scores, summary, {"pso-tuned": 300}).empty
    markdown = score_report.to_markdown(
        summary,
        score_report.degenerate_table(scores),
        score_report.phase_table(scores),
        score_report.paired_table(scores),
        library="v2 (split test)",
        rank_change=score_report.rank_change_table(scores, summary, budgets),
    )
    section = markdown.split("## Rank change with the tuned variants, budget max_evaluations=1200")
    assert len(section) == 2 and "ranked by its median normalised gap" in section[1]
    assert f"| pso | 2 | 1 | +1 | {0.45 + 5.5 * 0.0121:.3g} [" in section[1]
    assert section[1].index("| family |") < section[1].index("## budget")


# --- the tables fit the documentation's content column ----------------------------------------


def test_a_wide_table_is_split_into_tables_of_the_same_rows_each_within_the_room():
    names = score_report.Column("name", ["a-long-optimizer-name", "b"], text=True)
    pair = [score_report.Column("low", ["1", "2"]), score_report.Column("high", ["3", "4"])]
    wide = score_report.Column("a header with a long word: incomprehensibilities", ["5", "6"])
    room = names.width + 16
    lines = score_report.fitted_table([names], [pair, [wide]], room=room)
    markdown = "\n".join(lines)
    # the pair fits beside the name, the wide column does not (it is a table of its own,
    # wider than the room, rather than cut)
    assert [t.header for t in markdown_tables(markdown)] == [
        ["name", "low", "high"],
        ["name", "a header with a long word: incomprehensibilities"],
    ]
    assert table_widths(markdown)[0] <= room < table_widths(markdown)[1]
    assert joined_rows(markdown, ["name"]) == {
        ("a-long-optimizer-name",): ["1", "3", "5"],
        ("b",): ["2", "4", "6"],
    }
    assert "|---|---:|---:|" in lines  # the names left-aligned, the numbers right-aligned
    # a section wider than the room beside the lead is split column by column
    split = score_report.fitted_table([names], [[*pair, wide]], room=room)
    assert [t.header[1:] for t in markdown_tables("\n".join(split))] == [
        ["low", "high"],
        ["a header with a long word: incomprehensibilities"],
    ]
    # everything in one table when it fits
    one = score_report.fitted_table([names], [pair, [wide]], room=TABLE_WIDTH)
    assert len(markdown_tables("\n".join(one))) == 1 and one[-1] == ""


def test_every_table_of_the_leaderboard_fits_the_page_and_keeps_every_cell_of_its_rows():
    scores = tuned_scores()
    summary = score_report.summary_table(scores)
    at = summary[summary["budget"] == AT_1200]
    paired = score_report.paired_table(scores)
    markdown = score_report.to_markdown(
        at,
        score_report.degenerate_table(scores),
        score_report.phase_table(scores),
        paired[paired["budget"] == AT_1200],
        library="v2 (split test)",
        rank_change=score_report.rank_change_table(
            scores, summary, {"pso-tuned": 1200, "modified-bso-tuned": 1200}
        ),
    )
    widths = table_widths(markdown)
    assert len(widths) > 5 and max(widths) <= TABLE_WIDTH
    # the leaderboard: split, rank and name in every part, every cell of a row once
    leaderboard = [t for t in markdown_tables(markdown) if t.header[:2] == ["rank", "optimizer"]]
    assert len(leaderboard) == 2
    assert leaderboard[0].rows[0][:2] == leaderboard[1].rows[0][:2]
    rows = joined_rows(markdown, ["rank", "optimizer"])
    assert len(rows) == len(at) and {len(cells) for cells in rows.values()} == {10}
    r = at.set_index("optimizer").loc["pso"]
    g = score_report._g
    assert rows[(f"{r['rank']}", "pso")] == [
        f"{r['instances']}",
        f"{r['trials']}",
        f"{g(r['norm_gap_median'])} [{g(r['norm_gap_ci_low'])}, {g(r['norm_gap_ci_high'])}]",
        f"{g(r['gap_median'])} [{g(r['gap_ci_low'])}, {g(r['gap_ci_high'])}]",
        g(r["nfev_median"], ".0f"),
        *(score_report._share(r[score_report.success_column(t)], 12) for t in SUCCESS_TARGETS),
        g(1e3 * r["solve_time_median_s"], ".2f"),
        g(1e3 * r["solve_time_sgm_s"], ".1f"),
    ]
    # the paired comparisons: every comparison's cells once, named by its kind, x and y
    compared = joined_rows(markdown, ["comparison", "x", "y"])
    assert len(compared) == len(paired[paired["budget"] == AT_1200])
    assert {len(cells) for cells in compared.values()} == {8}
    assert compared[("against modified-bso", "pso", "modified-bso")][-1].startswith("favours pso")


def test_tuned_pairs_join_the_paired_table_as_their_own_kind():
    paired = score_report.paired_table(tuned_scores())
    at = paired[paired["budget"] == AT_1200]
    kinds = {
        kind: set(zip(rows["x"], rows["y"], strict=True)) for kind, rows in at.groupby("comparison")
    }
    assert kinds["tuned against default"] == {("modified-bso-tuned", "modified-bso"),
                                              ("pso-tuned", "pso")}  # fmt: skip
    assert kinds["tuned for the loop against default"] == {("pso-tuned-loop", "pso")}
    assert kinds["warm start against uniform start"] == {("pso-warm", "pso")}
    # the ablation question at the best settings: each per-solve tuned variant against the
    # tuned modified BSO (not the loop-tuned one, which is not tuned for solves)
    assert kinds["tuned, against modified-bso-tuned"] == {("pso-tuned", "modified-bso-tuned")}
    # Holm within each kind: the two tuned pairs share a family, the warm pair has its own
    tuned = at[at["comparison"] == "tuned against default"]
    assert tuned["p_holm"].tolist() == pytest.approx([2 * 2**-11] * 2)
    warm = at[at["comparison"] == "warm start against uniform start"]
    assert warm["p_holm"].tolist() == pytest.approx([2**-11])


def test_a_score_report_without_tuned_variants_has_no_rank_change(tmp_path):
    scores = paired_scores().assign(split="test")
    markdown = score_report.write_score_report(scores, tmp_path, figures=False)
    assert "Rank change" not in markdown
    assert pd.read_csv(tmp_path / "score_rank_change.csv").empty


def test_the_tuning_budgets_come_from_the_registered_tuned_variants_else_a_note_says_so(
    tmp_path, monkeypatch
):
    from formation_bench.optimizers import tuned

    scores = tuned_scores().assign(split="test")
    # whatever the package ships: here only pso-tuned is a registered tuned variant
    monkeypatch.setattr(tuned, "_TUNED", {"pso-tuned": {"objective": {"budget": 1200}}})
    markdown = score_report.write_score_report(scores, tmp_path / "a", figures=False)
    assert "## Rank change with the tuned variants, budget max_evaluations=1200" in markdown
    assert "modified-bso-tuned: not registered here as a tuned variant" in markdown
    written = pd.read_csv(tmp_path / "a" / "score_rank_change.csv")
    assert written[["family", "default_rank", "tuned_rank"]].values.tolist() == [["pso", 2, 1]]
    monkeypatch.setattr(tuned, "_TUNED", {})
    none = score_report.write_score_report(scores, tmp_path / "b", figures=False)
    assert "Rank change" not in none
    assert "modified-bso-tuned, pso-tuned: not registered here as a tuned variant" in none


def test_a_tuned_pair_scored_only_off_its_tuning_budget_has_no_rank_change_and_a_line_says_so(
    tmp_path,
):
    # pso and pso-tuned scored at 300 evaluations only, tuned at 1200, and no optimiser at its
    # own budget: at 1200 there is nothing to rank
    at_300 = tuned_scores()
    at_300 = at_300[at_300["optimizer"].isin(["pso", "pso-tuned"]) & (at_300["budget"] == AT_1200)]
    at_300 = at_300.assign(budget="max_evaluations=300")
    summary = score_report.summary_table(at_300)
    budgets = {"pso-tuned": 1200}
    assert score_report.rank_change_table(at_300, summary, budgets).empty
    line = (
        "no rank change of pso with pso-tuned, tuned at max_evaluations=1200: pso-tuned and pso "
        "have no score runs at that budget (nor at default), so there is nothing to compare."
    )
    assert score_report.rank_change_notes(summary, budgets) == [line]
    markdown = score_report.write_score_report(
        at_300.assign(split="test"), tmp_path, figures=False, tuning_budgets=budgets
    )
    assert f"Note: {line}" in markdown and "Rank change" not in markdown
    assert pd.read_csv(tmp_path / "score_rank_change.csv").empty
    # one of the two at the tuning budget: the other is named
    scores = tuned_scores()
    summary = score_report.summary_table(scores)
    assert score_report.rank_change_notes(summary, {"pso-tuned": 300}) == [
        "no rank change of pso with pso-tuned, tuned at max_evaluations=300: pso-tuned has no "
        "score runs at that budget (nor at default), so there is nothing to compare."
    ]
    # every family ranked: no line
    assert score_report.rank_change_notes(summary, {"pso-tuned": 1200}) == []
