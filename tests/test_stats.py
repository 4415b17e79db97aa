"""Statistics against hand-computed values, and the report on a small fixed table."""

import math

import numpy as np
import pandas as pd
import pytest

from formation_bench.analysis import stats
from formation_bench.analysis.report import analyse, to_markdown


def test_describe_median_quartiles_and_ci():
    s = stats.describe(np.array([1.0, 2.0, 3.0, 4.0, 100.0]))
    assert (s.n, s.median, s.q1, s.q3, s.iqr) == (5, 3.0, 2.0, 4.0, 2.0)
    assert 1.0 <= s.ci_low <= 3.0 <= s.ci_high <= 100.0
    even = stats.describe(np.array([4.0, 1.0, 3.0, 2.0, np.nan]))
    assert (even.n, even.median, even.q1, even.q3) == (4, 2.5, 1.75, 3.25)
    constant = stats.describe(np.full(6, 7.0))
    assert constant.ci_low == constant.ci_high == constant.median == 7.0
    assert stats.describe(np.array([1.0, 5.0, 2.0, 8.0])) == stats.describe(
        np.array([1.0, 5.0, 2.0, 8.0])
    )  # the bootstrap is seeded: reports repeat


def test_holm_by_hand():
    # sorted 0.01, 0.03, 0.04 -> 3 * 0.01, max(0.03, 2 * 0.03), max(0.06, 1 * 0.04)
    assert stats.holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
    assert stats.holm([0.02, 0.5]) == pytest.approx([0.04, 0.5])
    adjusted = stats.holm([math.nan, 0.01, 0.02])
    assert math.isnan(adjusted[0]) and adjusted[1:] == pytest.approx([0.02, 0.02])
    assert stats.holm([0.3, 0.9]) == pytest.approx([0.6, 0.9])
    assert stats.holm([0.6, 0.7]) == pytest.approx([1.0, 1.0])  # capped at 1


def test_holm_agrees_with_statsmodels():
    multitest = pytest.importorskip("statsmodels.stats.multitest")
    p = np.random.default_rng(3).random(12) ** 3
    assert stats.holm(p) == pytest.approx(multitest.multipletests(p, method="holm")[1])


def test_a12_by_hand():
    # pairs x > y: (3, 2) twice; ties: (2, 2) twice -> (2 + 0.5 * 2) / 9
    assert stats.a12([1, 2, 3], [2, 2, 4]) == pytest.approx(1 / 3)
    assert stats.a12([5, 6], [1, 2]) == 1.0
    assert stats.a12([1, 2], [5, 6]) == 0.0
    assert stats.a12([3, 3], [3, 3]) == 0.5


def test_wilcoxon_by_hand():
    y = np.arange(10.0, 16.0)
    # differences 1..6 all positive: W- = 0, exact two-sided p = 2 / 2^6
    assert stats.wilcoxon_paired(y + np.arange(1, 7), y) == (0.0, pytest.approx(2 / 64))
    # differences 1, -2, 3, 4, 5, 6: W- = 2; P(W <= 2) = #{{}, {1}, {2}} / 64
    x = y + np.array([1, -2, 3, 4, 5, 6])
    assert stats.wilcoxon_paired(x, y) == (2.0, pytest.approx(2 * 3 / 64))
    assert stats.wilcoxon_paired(y, y) == (pytest.approx(math.nan, nan_ok=True), 1.0)


def test_friedman_by_hand():
    table = pd.DataFrame({"a": [1, 2, 3, 4], "b": [2, 3, 4, 5], "c": [3, 4, 5, 6]})
    result = stats.friedman(table)
    # ranks 1, 2, 3 in every block: chi2 = 12 / (4 * 3 * 4) * (4^2 + 8^2 + 12^2) - 3 * 4 * 4
    assert result.statistic == pytest.approx(8.0)
    assert result.pvalue == pytest.approx(math.exp(-4.0))
    assert result.average_ranks.tolist() == [1.0, 2.0, 3.0]
    assert result.nemenyi is not None and result.nemenyi.shape == (3, 3)
    two = stats.friedman(table[["a", "b"]])
    assert math.isnan(two.pvalue) and two.average_ranks.tolist() == [1.0, 2.0]


A = np.arange(1.0, 7.0)
TABLE = pd.DataFrame(
    {
        "optimizer": np.repeat(["base", "better", "mixed"], 6),
        "scenario": "paper",
        "trigger": True,
        "budget": "default",
        "seed": np.tile(np.arange(6), 3),
        "tracking_error_max_m": np.concatenate(
            [A, A + 0.1 * np.arange(1, 7), A + 0.5 * np.array([1, -2, 3, 4, 5, 6])]
        ),
        "nfev_total": 100,
        "steps": 240,
    }
)


def test_report_tables_on_a_fixed_table_match_hand_values():
    report = analyse(TABLE, baseline="base")
    assert report.factor == "optimizer" and report.baseline == "base"
    assert "steps" not in report.metrics and report.metrics[0] == "tracking_error_max_m"
    summary = report.summary[report.summary["metric"] == "tracking_error_max_m"].set_index(
        "optimizer"
    )
    assert summary["median"].to_dict() == pytest.approx(
        {"base": 3.5, "better": 3.85, "mixed": 5.25}
    )
    assert summary.loc["base", "q1"] == pytest.approx(2.25)
    assert summary.loc["base", "iqr"] == pytest.approx(2.5)
    tests = report.wilcoxon[report.wilcoxon["metric"] == "tracking_error_max_m"].set_index(
        "optimizer"
    )
    # raw exact p: 2/64 and 6/64; Holm: 2 * 2/64, then max(that, 1 * 6/64)
    assert tests["p"].to_dict() == pytest.approx({"better": 2 / 64, "mixed": 6 / 64})
    assert tests["p_holm"].to_dict() == pytest.approx({"better": 4 / 64, "mixed": 6 / 64})
    # A12 = P(level > base): better beats 1+2+...+6 = 21 of 36 pairs; mixed 23 of 36 (2 ties)
    assert tests["a12"].to_dict() == pytest.approx({"better": 21 / 36, "mixed": 23 / 36})
    assert tests["n_pairs"].tolist() == [6, 6]
    assert not tests["significant"].any()
    friedman = report.friedman.set_index("metric").loc["tracking_error_max_m"]
    assert friedman["statistic"] == pytest.approx(7.0)  # 12/72 * (7^2 + 13^2 + 16^2) - 72
    assert friedman["p"] == pytest.approx(math.exp(-3.5))
    ranks = report.ranks[report.ranks["metric"] == "tracking_error_max_m"]
    assert ranks.set_index("optimizer")["average_rank"].to_dict() == pytest.approx(
        {"base": 7 / 6, "better": 13 / 6, "mixed": 16 / 6}
    )
    # a constant metric: every difference zero, p = 1, A12 = 0.5
    constant = report.wilcoxon[report.wilcoxon["metric"] == "nfev_total"]
    assert constant["p_holm"].tolist() == [1.0, 1.0] and constant["a12"].tolist() == [0.5, 0.5]
    text = to_markdown(report, TABLE)
    # the block's tables: the median with its CI, the Friedman p = exp(-3.5) over 6 seeds
    assert "| better | 6 | 3.85 [" in text and "| Friedman p | 0.030 (6) |" in text


def test_missing_seeds_are_left_out_of_the_pairs():
    partial = TABLE[~((TABLE["optimizer"] == "better") & (TABLE["seed"] == 5))]
    report = analyse(partial, baseline="base")
    tests = report.wilcoxon[report.wilcoxon["metric"] == "tracking_error_max_m"]
    assert tests.set_index("optimizer")["n_pairs"].to_dict() == {"better": 5, "mixed": 6}
    # 5 positive differences: exact p = 2 / 32
    assert tests.set_index("optimizer").loc["better", "p"] == pytest.approx(2 / 32)
    assert report.friedman.set_index("metric").loc["tracking_error_max_m", "n_seeds"] == 5


def test_trigger_is_compared_when_there_is_one_optimizer():
    table = TABLE[TABLE["optimizer"] != "mixed"].copy()
    table["trigger"] = table["optimizer"] == "better"
    table["optimizer"] = "modified-bso"
    report = analyse(table)
    assert report.factor == "trigger" and report.baseline == "off"
    tests = report.wilcoxon[report.wilcoxon["metric"] == "tracking_error_max_m"]
    assert tests["trigger"].tolist() == ["on"] and tests["p_holm"].tolist() == [
        pytest.approx(2 / 64)
    ]
