"""The README's 'Adding an optimiser' example works as printed."""

import re
from pathlib import Path

import numpy as np

from formation_bench.mpc.loop import simulate
from formation_bench.mpc.scenario import get_scenario
from formation_bench.optimizers import OPTIMIZERS, Bounds, Budget, get_optimizer


def test_readme_optimizer_example_runs_in_the_closed_loop():
    readme = (Path(__file__).parents[1] / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", readme, flags=re.S)
    example = next(b for b in blocks if "register(" in b)
    try:
        exec(compile(example, "README.md", "exec"), {})
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
    finally:
        OPTIMIZERS.pop("my-random-search", None)
