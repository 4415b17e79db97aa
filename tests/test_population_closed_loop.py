"""Every registered population optimiser drives the paper's closed loop, with and without trigger.

Short runs (a few instants) keep this fast; the full 240-instant runs of
``formation-bench run --optimizer NAME`` are listed in ``docs/explanation/optimizers.md``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import configured_names

from formation_bench.cli.main import main
from formation_bench.mpc.loop import simulate
from formation_bench.mpc.scenario import get_scenario
from formation_bench.optimizers import PopulationOptimizer, get_optimizer
from formation_bench.optimizers.adapters import ADAPTERS

SHORT = get_scenario("paper", n_steps=6, settle_time_s=0.0)
SHORTER = get_scenario("paper", n_steps=2, settle_time_s=0.0)
"""For the adapters, whose solves take up to a second (docs/how-to/adapters.md)."""
POPULATION = [n for n in configured_names() if isinstance(get_optimizer(n), PopulationOptimizer)]


# the adapters' libraries make a solve 30-650 times slower (docs/how-to/adapters.md)
@pytest.mark.parametrize(
    "name", [pytest.param(n, marks=pytest.mark.slow) if n in ADAPTERS else n for n in POPULATION]
)
@pytest.mark.parametrize("trigger", [False, True])
def test_short_closed_loop(name: str, trigger: bool) -> None:
    scenario = SHORTER if name in ADAPTERS else SHORT
    trace = simulate(scenario, get_optimizer(name), trigger=trigger, seed=0, optimizer_name=name)
    assert trace.solved[0].all()
    assert np.isfinite(trace.states).all()
    lower, upper = scenario.control_lower, scenario.control_upper
    assert (trace.controls >= lower).all() and (trace.controls <= upper).all()
    assert (trace.nfev[trace.solved] > 0).all()


@pytest.mark.parametrize("name", ["original-bso", "pso", "cls-bso"])
def test_cli_run_writes_metrics(name: str, tmp_path) -> None:
    out = tmp_path / name
    args = ["run", "--optimizer", name, "--no-trigger", "--set", "n_steps=5"]
    assert main([*args, "--set", "settle_time_s=0.0", "--out", str(out)]) == 0
    (record,) = json.loads((out / "metrics.json").read_text())
    assert record["optimizer"] == name
    assert [record[f"solves_uav{k}"] for k in (1, 2, 3)] == [5, 5, 5]


def test_population_optimisers_listed() -> None:
    expected = {
        "original-bso",
        "modified-bso",
        "modified-bso-no-chaos-replacement",
        "modified-bso-no-all-centre",
        "modified-bso-no-modifications",
        "modified-bso-raw-weights",
        "pso",
        "pso-constriction",
        "chaotic-pso",
        "cls-bso",
        "modified-bso-tent",
        "modified-bso-sine",
    }
    assert expected <= set(POPULATION)
