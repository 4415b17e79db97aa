"""Smoke test of the swarm speed benchmark, and its checks of linear growth and bad input."""

import json

import numpy as np
import pytest

from formation_bench.pipeline.runner import WARM_UP_PERIODS
from perf import swarm_speed


def test_tiny_run_times_every_configuration_and_profiles(tmp_path, capsys):
    out = tmp_path / "swarm.json"
    assert swarm_speed.main(["--tiny", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "Time against J" in printed and "Whole runs (modified-bso, trigger on" in printed
    figures = json.loads(out.read_text())
    solves = figures["solves"]
    seen = {(row["n_uav"], row["graph"], row["what"]): row for row in solves["rows"]}
    for n_uav in (3, 5):
        assert seen[(n_uav, "complete", "modified-bso")]["neighbours"] == n_uav - 1
        assert seen[(n_uav, "ring", "modified-bso")]["neighbours"] == 2
        assert (n_uav, "complete", "ltv-osqp") in seen
        assert seen[(n_uav, "ring", "ltv-osqp")]["neighbours"] == 2
    for row in solves["rows"]:
        assert row["problems"] == 2 and len(row["repeat_medians_s"]) == 2
        assert 0 < row["median_s"]
        if row["what"] == "ltv-osqp":  # its evaluations are linearisations and line searches
            assert row["per_evaluation_s"] is None
        else:
            expected = row["median_s"] / row["nfev_median"]  # nfev varies by a few per problem
            assert row["per_evaluation_s"] == pytest.approx(expected, rel=0.02)
    for what in ("objective", "modified-bso", "pso", "ltv-osqp"):
        assert solves["fits"][what]["neighbour_ratio"] == 2.0
    runs = {(row["n_uav"], row["graph"]): row for row in figures["runs"]["rows"]}
    assert set(runs) == {(3, "complete"), (3, "ring"), (5, "complete"), (5, "ring")}
    for (n_uav, _), row in runs.items():
        assert row["instants"] == 6
        assert n_uav <= row["solves"] <= 6 * n_uav  # every UAV solves at the first instant
        assert 0 < row["solves_s"] < row["loop_s"] <= row["run_s"]
        assert row["loop_rest_share"] == pytest.approx(1 - row["solve_share_of_loop"])
    profiles = figures["profiles"]  # --tiny profiles both runs of the largest N
    assert [p["scenario"].startswith("swarm-5") for p in profiles] == [True, True]
    for profile, graph in zip(profiles, ("complete", "ring"), strict=True):
        assert profile["steps"]["closed loop (simulate)"]["calls"] == 1
        # a run profiled whole: its untimed warm-up instants (every UAV solves at each) and its
        # loop
        warm_up_solves = 5 * WARM_UP_PERIODS
        solves = runs[(5, graph)]["solves"] + warm_up_solves
        assert profile["steps"]["minimize (the optimiser)"]["calls"] == solves
        assert profile["own_time"]
    assert "| function | calls |" in printed


def test_linear_growth_is_told_from_faster_growth():
    neighbours = np.array([2, 2, 4, 9, 19, 24])
    line = 3e-4 + 2e-5 * neighbours
    fit = swarm_speed._fit(neighbours, line)
    assert fit["neighbours"] == [2, 4, 9, 19, 24]  # equal J pooled
    assert fit["at_most_linear"] and fit["r_squared"] == pytest.approx(1.0)
    assert fit["slope_s_per_neighbour"] == pytest.approx(2e-5)
    assert fit["intercept_s"] == pytest.approx(3e-4)
    assert fit["quadratic_share"] == pytest.approx(0.0, abs=1e-9)
    assert fit["time_ratio"] < fit["neighbour_ratio"] == 12.0
    # growing faster than J: below J max / J min in ratio, but far from any line
    curved = 3e-4 + 2e-6 * neighbours**2
    fit = swarm_speed._fit(neighbours, curved)
    assert fit["time_ratio"] < fit["neighbour_ratio"]
    assert fit["max_relative_residual"] > swarm_speed.RESIDUAL_TOLERANCE
    assert fit["quadratic_share"] > 0.5 and not fit["at_most_linear"]
    # proportional to J squared: the ratio alone fails it
    fit = swarm_speed._fit(neighbours, 1e-6 * neighbours**2)
    assert fit["time_ratio"] > fit["neighbour_ratio"] and not fit["at_most_linear"]
    # a noisy line (one repeat's spread on a shared machine) still counts as linear
    noisy = line * (1 + 0.03 * np.random.default_rng(0).standard_normal(line.size))
    assert swarm_speed._fit(neighbours, noisy)["at_most_linear"]


def test_bad_settings_name_the_field_and_what_is_allowed(capsys):
    with pytest.raises(ValueError, match=r"SwarmSpeedSettings.sizes must hold UAV counts among"):
        swarm_speed.SwarmSpeedSettings(sizes=(4,))
    with pytest.raises(ValueError, match=r"SwarmSpeedSettings.repeats must be an integer >= 1"):
        swarm_speed.SwarmSpeedSettings(repeats=0)
    with pytest.raises(SystemExit):
        swarm_speed.main(["--sizes", "7"])
    assert "SwarmSpeedSettings.sizes" in capsys.readouterr().err
