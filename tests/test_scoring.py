"""The scoring statistics against values worked out by hand on small tables."""

import math

import numpy as np
import pandas as pd
import pytest

from formation_bench.benchmarks.analysis.scoring import (
    evaluations_to_target,
    expected_running_time,
    performance_profile,
    relative_gap,
    runtime_ecdf,
    shifted_geometric_mean,
    success_rate,
)


def test_relative_gap_and_evaluations_to_target():
    assert relative_gap(110.0, 100.0) == pytest.approx(0.1)
    assert relative_gap(99.0, 100.0) == pytest.approx(-0.01)
    nfev = np.array([10, 20, 30, 40])
    best = np.array([200.0, 120.0, 100.5, 100.05])  # gaps 1, 0.2, 0.005, 0.0005
    assert evaluations_to_target(nfev, best, 100.0, 0.25) == 20
    assert evaluations_to_target(nfev, best, 100.0, 1e-2) == 30
    assert evaluations_to_target(nfev, best, 100.0, 1e-3) == 40
    assert math.isnan(evaluations_to_target(nfev, best, 100.0, 1e-4))


def test_success_rate():
    gaps = np.array([0.0, 5e-3, 2e-2, 1e-4, 0.5])
    assert success_rate(gaps, 1e-2) == pytest.approx(3 / 5)
    assert success_rate(gaps, 1e-4) == pytest.approx(2 / 5)


def test_expected_running_time_counts_failures_at_their_full_cost():
    # two successes after 100 and 300 evaluations, one failure that used 1000:
    # (100 + 300 + 1000) / 2 = 700
    hits = np.array([100.0, math.nan, 300.0])
    used = np.array([500.0, 1000.0, 800.0])
    assert expected_running_time(hits, used) == pytest.approx(700.0)
    assert expected_running_time(np.array([math.nan]), np.array([10.0])) == math.inf


def test_runtime_ecdf_counts_trial_target_pairs():
    # 2 trials x 2 targets: reached at 10, 50, 30 evaluations and once never
    hits = np.array([[10.0, 50.0], [30.0, math.nan]])
    np.testing.assert_allclose(runtime_ecdf(hits, np.array([5, 10, 40, 100])), [0, 0.25, 0.5, 0.75])


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
