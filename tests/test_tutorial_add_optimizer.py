"""The "Add an optimiser" tutorial's example works as printed."""

import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from formation_bench.mpc.loop import simulate
from formation_bench.mpc.scenario import get_scenario
from formation_bench.optimizers import OPTIMIZERS, Bounds, Budget, get_optimizer

TUTORIAL = Path(__file__).parents[1] / "docs" / "tutorials" / "add-optimizer.md"


def tutorial_example() -> str:
    blocks = re.findall(r"```python\n(.*?)```", TUTORIAL.read_text(), flags=re.S)
    return next(b for b in blocks if "register(" in b)


def test_tutorial_optimizer_example_runs_in_the_closed_loop():
    try:
        exec(compile(tutorial_example(), "add-optimizer.md", "exec"), {})
        optimizer = get_optimizer("my-random-search")
        result = optimizer.minimize(
            lambda x: np.sum(x**2, axis=1),
            bounds=Bounds(-np.ones(3), np.ones(3)),
            rng=np.random.default_rng(0),
            budget=Budget(max_evaluations=95),
            x0=np.zeros(3),
        )
        assert result.nfev == 95 and result.fun == 0.0
        trace = simulate(get_scenario("paper", n_steps=5), optimizer, trigger=False, seed=0)
        assert trace.solved.all()
        with pytest.raises(ValueError, match=r"RandomSearch\.population_size must be an integer"):
            get_optimizer("my-random-search", population_size=0)
    finally:
        OPTIMIZERS.pop("my-random-search", None)


def test_tutorial_plugin_settings_are_listed_and_its_refusal_is_printed_as_shown(tmp_path):
    (tmp_path / "my_search.py").write_text(tutorial_example())
    shown = re.search(r"```console\n\$ (formation-bench --plugin my_search\.py .*)\n(.*)\n```",
                      TUTORIAL.read_text())  # fmt: skip
    assert shown is not None, "the tutorial shows a refused plugin setting"
    command, printed = shlex.split(shown[1]), shown[2]
    done = subprocess.run(
        [sys.executable, "-m", "formation_bench.cli.main", *command[1:]],
        capture_output=True, text=True, cwd=tmp_path, timeout=300,
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip() == printed
    assert not (tmp_path / "out").exists()
    listing = subprocess.run(
        [sys.executable, "-m", "formation_bench.cli.main", "--plugin", "my_search.py",
         "list", "--fields", "my-random-search"],
        capture_output=True, text=True, cwd=tmp_path, timeout=300,
    )  # fmt: skip
    assert listing.returncode == 0, listing.stderr
    assert "population_size = 30  (int; integer >= 1; not tuned)" in listing.stdout
