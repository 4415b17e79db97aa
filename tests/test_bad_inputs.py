"""Bad input through the command line and the environment: exit 2, one line naming the
field, path or variable, no traceback, and nothing written that looks finished."""

from __future__ import annotations

import os
import re
import select
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from helpers import budget_settings

from formation_bench.cli.main import main
from formation_bench.environment import DECLARED
from formation_bench.optimizers import OPTIMIZERS
from formation_bench.pipeline.checks import MAX_LABEL_CHARS

RUN = ["run", "--optimizer", "pso", "--no-figures"]
TUNE = ["tune", "--optimizer", "pso"]
SHORT = ["--set", "n_steps=3", "--set", "settle_time_s=0"]

# (arguments with {out}, {file}, {dir}, {suite}, {bad_utf8}, {bad_toml} placeholders, needle)
CASES = [
    # names and options
    (["run", "--optimizer", "psoo", "--out", "{out}"], "--optimizer"),
    ([*RUN, "--scenario", "moon", "--out", "{out}"], "--scenario"),
    ([*RUN, "--seed", "-1", "--out", "{out}"], "--seed"),
    ([*RUN, "--seed", "x", "--out", "{out}"], "--seed"),
    ([*RUN, "--seed", str(2**128), "--out", "{out}"], "--seed"),
    ([*RUN, "--max-evaluations", "0", "--out", "{out}"], "--max-evaluations"),
    ([*RUN, "--max-iterations", "-2", "--out", "{out}"], "--max-iterations"),
    ([*RUN, "--max-evaluations", "ten", "--out", "{out}"], "--max-evaluations"),
    ([*RUN, "--frobnicate", "--out", "{out}"], "--frobnicate"),
    (["--plugin", "no_such_plugin_module", *RUN, "--out", "{out}"], "no_such_plugin_module"),
    (["--plugin", "{dir}/missing.py", *RUN, "--out", "{out}"], "missing.py"),
    (["list", "--fields", "nope"], "--fields"),
    # --set: form, names and values
    ([*RUN, "--set", "n_steps", "--out", "{out}"], "--set"),
    ([*RUN, "--set", "=3", "--out", "{out}"], "--set"),
    ([*RUN, "--set", "colour=3", "--out", "{out}"], "colour"),
    ([*RUN, "--set", "planet.n_steps=3", "--out", "{out}"], "planet.n_steps"),
    ([*RUN, "--set", "scenario.population_size=3", "--out", "{out}"], "population_size"),
    ([*RUN, "--set", "n_steps=2.5", "--out", "{out}"], "n_steps"),
    ([*RUN, "--set", "n_steps=abc", "--out", "{out}"], "n_steps"),
    ([*RUN, "--set", "n_steps=0", "--out", "{out}"], "n_steps"),
    ([*RUN, "--set", "period_s=0", "--out", "{out}"], "period_s"),
    ([*RUN, "--set", "w_trj=nan", "--out", "{out}"], "w_trj"),
    ([*RUN, "--set", "w_dst=-1", "--out", "{out}"], "w_dst"),
    ([*RUN, "--set", "eta=1.5", "--out", "{out}"], "eta"),
    ([*RUN, "--set", "accel_bounds=(1,)", "--out", "{out}"], "accel_bounds"),
    ([*RUN, "--set", "accel_bounds=(1,x)", "--out", "{out}"], "accel_bounds"),
    ([*RUN, "--set", "turn_rate_bounds=(1,-1)", "--out", "{out}"], "turn_rate_bounds"),
    ([*RUN, "--set", "initial_states=((1,2),)", "--out", "{out}"], "initial_states"),
    ([*RUN, "--set", "initial_states=((a,b),)", "--out", "{out}"], "initial_states"),
    ([*RUN, "--set", "formation_offsets=((1,1),(2,2),(3,3))", "--out", "{out}"],
     "formation_offsets"),
    ([*RUN, "--set", "reference=moon", "--out", "{out}"], "reference"),
    ([*RUN, "--set", "reference_start=(1,)", "--out", "{out}"], "reference_start"),
    ([*RUN, "--set", "name=(1,2)", "--out", "{out}"], "name"),
    ([*RUN, "--set", "n_blocks=50", "--out", "{out}"], "n_blocks"),
    ([*RUN, "--set", "trigger_lookahead_steps=-1", "--out", "{out}"], "trigger_lookahead_steps"),
    ([*RUN, "--set", "estimate_extension=guess", "--out", "{out}"], "estimate_extension"),
    ([*RUN, "--set", "population_size=1", "--out", "{out}"], "population_size"),
    ([*RUN, "--set", "bound_handling=bounce", "--out", "{out}"], "bound_handling"),
    (["run", "--optimizer", "modified-bso", "--no-figures", "--set", "n_clusters=99",
      "--out", "{out}"], "n_clusters"),
    # cross-field conditions and limits that would never finish or exhaust memory
    ([*RUN, "--set", "n_steps=10", "--out", "{out}"], "settle_time_s"),
    ([*RUN, "--set", "n_steps=1000000", "--out", "{out}"], "n_steps"),
    ([*RUN, "--set", "horizon_steps=5000", "--set", "n_blocks=1", "--out", "{out}"],
     "horizon_steps"),
    ([*RUN, "--set", "population_size=1000000", "--out", "{out}"], "population_size"),
    ([*RUN, "--max-evaluations", "100000000", "--out", "{out}"], "max_evaluations"),
    ([*RUN, "--set", "max_iterations=100000000", "--out", "{out}"], "max_iterations"),
    # output paths
    ([*RUN, *SHORT, "--out", "{file}"], "is a file"),
    ([*RUN, *SHORT, "--out", "{file}/sub"], "is a file"),
    ([*RUN, *SHORT, "--out", "{full}"], "--overwrite"),
    (["reproduce", "--no-figures", "--out", "{file}"], "is a file"),
    (["reproduce", "--no-figures", "--out", "{full}"], "--overwrite"),
    (["sweep", "paper", "--out", "{file}"], "is a file"),
    (["report", "{file}"], "no results"),
    (["report", "{dir}/nothing-here"], "no results"),
    # suites
    (["sweep", "{dir}", "--out", "{out}"], "is a folder"),
    (["sweep", "{dir}/missing.toml", "--out", "{out}"], "does not exist"),
    (["sweep", "{bad_utf8}", "--out", "{out}"], "UTF-8"),
    (["sweep", "{bad_toml}", "--out", "{out}"], "line"),
    (["sweep", "{big_suite}", "--out", "{out}"], "n_steps"),
    (["sweep", "nosuchsuite", "--out", "{out}"], "nosuchsuite"),
    (["sweep", "paper", "--out", "{out}", "--jobs", "0"], "--jobs"),
    (["sweep", "{huge_suite}", "--out", "{out}", "--dry-run"], "seeds"),
    (["sweep", "{big_seed_suite}", "--out", "{out}", "--dry-run"], "2**128 - 1"),
    # more values: wrong types, lengths and magnitudes
    ([*RUN, "--set", "rk4_substeps=100000", "--out", "{out}"], "rk4_substeps"),
    ([*RUN, "--set", "w_trj=1e999", "--out", "{out}"], "w_trj"),
    ([*RUN, "--set", "period_s='0.1'", "--out", "{out}"], "period_s"),
    ([*RUN, "--set", "n_steps=1e3", "--out", "{out}"], "n_steps"),
    ([*RUN, "--set", "accel_bounds=(1,2,3)", "--out", "{out}"], "accel_bounds"),
    ([*RUN, "--set", "optimizer.population_size=True", "--out", "{out}"],
     "optimizer.population_size"),
    (["reproduce", "--no-figures", "--seeds", str(2**128), "--out", "{out}"], "--seed"),
    (["reproduce", "--no-figures", "--seeds", *map(str, range(10_001)), "--out", "{out}"],
     "--seeds"),
    # more output paths and addresses
    (["sweep", "paper", "--out", "{file}/sub"], "is a file"),
    (["report", "{results}", "--out", "{file}"], "is a file"),
    (["report", "{results}", "--out", "{full}"], "--overwrite"),
    (["sweep", "paper", "--out", "{out}", "--scheduler", "not an address"], "--scheduler"),
    (["sweep", "paper", "--out", "{out}", "--scheduler", "http://host:8786"], "--scheduler"),
    (["sweep", "paper", "--out", "{out}", "--scheduler", "tcp://host:99999"], "--scheduler"),
    # tune: the data a tuning may not touch, then its own options
    ([*TUNE, "--split", "test", "--out", "{out}"], "--split"),
    ([*TUNE, "--seed", "0", "--out", "{out}"], "--seed"),
    ([*TUNE, "--objective", "loop", "--seeds", "1000", "12", "--out", "{out}"], "--seeds"),
    ([*TUNE, "--objective", "loop", "--seeds", "1000", "1000", "--out", "{out}"], "--seeds"),
    ([*TUNE, "--objective", "loop", "--suite", "nope", "--out", "{out}"], "--suite"),
    ([*TUNE, "--objective", "loop", "--metric", "colour", "--out", "{out}"], "--metric"),
    ([*TUNE, "--objective", "best", "--out", "{out}"], "--objective"),
    ([*TUNE, "--trials", "0", "--out", "{out}"], "--trials"),
    ([*TUNE, "--batch", "x", "--out", "{out}"], "--batch"),
    ([*TUNE, "--max-evaluations", "0", "--out", "{out}"], "--max-evaluations"),
    ([*TUNE, "--jobs", "0", "--out", "{out}"], "--jobs"),
    ([*TUNE, "--out", "{file}"], "is a file"),
    (["tune", "--optimizer", "psoo", "--out", "{out}"], "--optimizer"),
]  # fmt: skip

SCORE = ["score", "--optimizer", "pso"]
# the boundary of every command: output paths, worker counts, score's limits, suites without
# runs, values that leave nothing to optimise, plugin settings and names registered twice
BOUNDARY = [
    # an empty, folder-less or over-long --out, for every command that takes one
    ([*RUN, *SHORT, "--out", ""], "--out: empty path"),
    ([*RUN, *SHORT, "--out", "."], "names no folder of its own"),
    ([*RUN, *SHORT, "--out", "{long_name}"], "300 bytes"),
    ([*RUN, *SHORT, "--out", "{long_path}"], "per path"),
    (["reproduce", "--no-figures", "--out", ""], "--out: empty path"),
    (["reproduce", "--no-figures", "--out", "{long_name}"], "300 bytes"),
    (["sweep", "paper", "--out", ""], "--out: empty path"),
    (["sweep", "paper", "--out", "{long_name}"], "300 bytes"),
    (["sweep", "paper", "--out", "{long_path}"], "per path"),
    ([*SCORE, "--out", ""], "--out: empty path"),
    ([*SCORE, "--out", "{long_path}"], "per path"),
    (["report", "{results}", "--out", ""], "--out: empty path"),
    (["report", "{results}", "--out", "{long_name}"], "300 bytes"),
    (["report", "{long_path}"], "DIR: the path"),
    (["export-ioh", "{results}", "--out", "{long_name}"], "300 bytes"),
    (["export-ioh", "{results}", "--out", "{long_path}"], "per path"),
    # more local workers than the CPUs can run
    (["sweep", "paper", "--out", "{out}", "--jobs", "500"], "--jobs: 500 is more than"),
    ([*SCORE, "--out", "{out}", "--jobs", "500"], "--jobs: 500 is more than"),
    # score: the limits run and sweep enforce, and the optimiser's own fields
    ([*SCORE, "--budgets", "100000000", "--out", "{out}"], "max_evaluations=100000000"),
    ([*SCORE, "--seeds", *map(str, range(20_000)), "--out", "{out}"], "--seeds: 20,000"),
    ([*SCORE, "--deadline-ms", "1e9", "--out", "{out}"], "deadline_ms=1e+09"),
    ([*SCORE, "--set", "population_size=1000000", "--out", "{out}"], "population_size"),
    ([*SCORE, "--set", "max_iterations=100000000", "--out", "{out}"], "max_iterations"),
    (["score", "--optimizer", "ipopt", "--set", "population_size=5", "--out", "{out}"],
     "unknown field of optimizer 'ipopt'; its fields: acceptable_tol"),
    ([*SCORE, "--set", "scenario.n_steps=5", "--out", "{out}"], "has no scenario"),
    # a suite that matches no optimiser has no runs
    (["sweep", "{no_optimizer_suite}", "--out", "{out}"], "matches no registered optimizer"),
    (["sweep", "{optional_suite}", "--out", "{out}"], "'not-installed-search' is not registered"),
    # each value allowed, together nothing to optimise
    ([*RUN, "--set", "accel_bounds=(-1e300,1e300)", "--out", "{out}"], "accel_bounds"),
    ([*RUN, "--set", "turn_rate_bounds=(-100,100)", "--out", "{out}"], "turn_rate_bounds"),
    ([*RUN, "--set", "uav_accel_bounds=((-7,7),(-7,7),(-7,700))", "--out", "{out}"],
     "uav_accel_bounds"),
    ([*RUN, "--set", "w_dst=0", "--set", "w_trj=0", "--out", "{out}"], "both weights 0"),
    ([*RUN, "--set", "delay_steps=1000", "--out", "{out}"], "no plan would reach"),
    (["sweep", "{zero_weight_suite}", "--out", "{out}"], "both weights 0"),
    # plugin settings are declared, checked and listed like the shipped ones
    (["--plugin", "{tutorial_plugin}", "run", "--optimizer", "my-random-search",
      "--set", "population_size=0", "--out", "{out}"], "--set population_size: expected"),
    (["--plugin", "{plain_plugin}", "list"], "setting("),
    # a name registered twice is refused by every command
    (["--plugin", "{pso_plugin}", "list"], "'pso' is already registered"),
    (["--plugin", "{pso_plugin}", *RUN, *SHORT, "--out", "{out}"], "'pso' is already registered"),
    (["--plugin", "{pso_plugin}", "sweep", "paper", "--out", "{out}"],
     "'pso' is already registered"),
    (["--plugin", "{pso_plugin}", "report", "{results}"], "'pso' is already registered"),
]  # fmt: skip
CASES += BOUNDARY


ZERO_REFUSED = "--set max_iterations: expected an integer >= 1, got 0"
# budgets of zero: one rule for every option, suite key and optimiser setting of a budget, as
# --max-evaluations 0 above; every budget setting of every registered optimiser, for both
# commands that take --set
BUDGETS = [
    ([*RUN, "--max-iterations", "0", "--out", "{out}"],
     "--max-iterations: must be an integer >= 1"),
    (["run", "--optimizer", "ilqr", "--no-figures", "--max-iterations", "0", "--out", "{out}"],
     "--max-iterations: must be an integer >= 1"),
    ([*SCORE, "--budgets", "0", "--out", "{out}"], "--budgets: must be 'default' or a number"),
    (["sweep", "{zero_iterations_suite}", "--out", "{out}"],
     "budgets[0]: Budget.max_iterations must be an integer >= 1, got 0"),
    (["sweep", "{zero_evaluations_suite}", "--out", "{out}"],
     "budgets[0]: Budget.max_evaluations must be an integer >= 1, got 0"),
    (["sweep", "{own_zero_budget_suite}", "--out", "{out}", "--dry-run"],
     "optimizers[0].budgets[0]: Budget.max_iterations must be an integer >= 1, got 0"),
    # a plugin's budget setting: declared with budget_setting(), or held to its rule anyway
    (["--plugin", "{tutorial_plugin}", "run", "--optimizer", "my-random-search",
      "--set", "max_iterations=0", "--out", "{out}"], ZERO_REFUSED),
    (["--plugin", "{zero_plugin}", "run", "--optimizer", "zero-allowed-search",
      "--set", "max_iterations=0", "--out", "{out}"], ZERO_REFUSED),
    (["--plugin", "{zero_plugin}", "score", "--optimizer", "zero-allowed-search",
      "--set", "max_iterations=0", "--out", "{out}"], ZERO_REFUSED),
    (["sweep", "{zero_override_suite}", "--out", "{out}"],
     "optimizers[0].overrides.max_iter: IlqrOptimizer.max_iter must be an integer >= 1, got 0"),
    *[
        (args, f"--set {field}: expected an integer >= 1, got 0")
        for name in sorted(OPTIMIZERS)
        for field in budget_settings(OPTIMIZERS[name].optimizer)
        for args in (
            ["run", "--optimizer", name, "--no-figures", "--set", f"{field}=0", "--out", "{out}"],
            ["score", "--optimizer", name, "--set", f"{field}=0", "--out", "{out}"],
        )
    ],
]  # fmt: skip
# labels a report prints in every table row, legend and axis: bounded where a suite is read
LABELS = [
    (["sweep", "{long_label_suite}", "--out", "{out}"],
     "optimizers[0].label: 'xxxxxxxxxxxxxxxx...xxxxxxxxxxxxxxxx' is 5,000 characters, more than"),
    (["sweep", "{long_label_suite}", "--out", "{out}", "--dry-run"], "is 5,000 characters"),
    (["sweep", "{just_over_label_suite}", "--out", "{out}"],
     f"is {MAX_LABEL_CHARS + 1} characters, more than {MAX_LABEL_CHARS}"),
    (["sweep", "{long_scenario_label_suite}", "--out", "{out}"],
     "scenarios[0].label: 'ssssssssssssssss...ssssssssssssssss' is 300 characters"),
    (["sweep", "{long_derived_label_suite}", "--out", "{out}"],
     "optimizers[0].label: the name derived from the overrides: 'pso[population_s"),
    (["sweep", "{long_name_suite}", "--out", "{out}"],
     "name: 'nnnnnnnnnnnnnnnn...nnnnnnnnnnnnnnnn' is"),
    (["sweep", "{two_line_label_suite}", "--out", "{out}"],
     "optimizers[0].label: 'one\\ntwo' is not one line of printable characters"),
]  # fmt: skip
# what a command would otherwise merge without a word: a seed or budget given twice, a
# comparison of a factor the results hold one level of
MERGES = [
    (["reproduce", "--no-figures", "--seeds", "0", "0", "--out", "{out}"],
     "--seeds: 0 is given twice"),
    (["reproduce", "--no-figures", "--seeds", "3", "1", "3", "--out", "{out}"],
     "--seeds: 3 is given twice"),
    ([*SCORE, "--seeds", "0", "0", "--out", "{out}"], "--seeds: 0 is given twice"),
    ([*SCORE, "--budgets", "default", "default", "--out", "{out}"],
     "--budgets: default is given twice"),
    ([*SCORE, "--budgets", "1200", "1200", "--out", "{out}"], "--budgets: 1200 is given twice"),
    (["report", "{swept}", "--compare", "budget"],
     "--compare budget: these results hold one budget (default), so there is nothing to "
     "compare it with; compare optimizer (2 levels)"),
    (["report", "{swept}", "--compare", "trigger", "--no-figures"],
     "--compare trigger: these results hold one trigger (on)"),
    (["report", "{swept}", "--compare", "scenario", "--out", "{out}"],
     "--compare scenario: these results hold one scenario"),
]  # fmt: skip
CASES += BUDGETS + LABELS + MERGES
# report --page: every output checked before any is written; a file of the user's never
# overwritten; nothing inside the store or the report folder, which --overwrite replaces
PAGE = [
    (["report", "{results}", "--page", "{long_page}"], "--page: the name"),
    (["report", "{results}", "--page", "{notes}"], "is not a results page written by"),
    (["report", "{results}", "--page", "{notes}", "--overwrite"],
     "is not a results page written by"),
    (["report", "{results}", "--page", "{results_page}"], "add --overwrite to write it anew"),
    (["report", "{results}", "--page", "{results}/runs/page.md"], "/runs, which belongs to"),
    (["report", "{results}", "--page", "{results}/report/page.md"], "/report, which belongs to"),
    (["report", "{results}", "--out", "{out}", "--page", "{out}/page.md"],
     "/out, which belongs to"),
    (["report", "{results}", "--page", "{file}/page.md"], "is a file, not a folder"),
    (["report", "{results}", "--page", "{dir}/page.txt"], "give a Markdown file (.md)"),
]  # fmt: skip
CASES += PAGE

PLAIN_PLUGIN = """
from dataclasses import dataclass

from formation_bench.optimizers import Budget, Optimizer, register


@dataclass(frozen=True)
class Plain(Optimizer):
    population_size: int = 8

    @property
    def default_budget(self) -> Budget:
        return Budget(max_iterations=1)

    def minimize(self, objective, bounds, rng, budget=None, x0=None):
        raise AssertionError("the registry refuses this optimizer before any solve")


register("plain-search", Plain(), "a field without setting()")
"""
ZERO_PLUGIN = """
from dataclasses import dataclass

from formation_bench.fields import Validated, setting
from formation_bench.optimizers import Budget, Optimizer, register


@dataclass(frozen=True)
class ZeroAllowed(Validated, Optimizer):
    max_iterations: int = setting(40, low=0, doc="allows 0, which no budget does")

    @property
    def default_budget(self) -> Budget:
        return Budget(max_iterations=self.max_iterations)

    def minimize(self, objective, bounds, rng, budget=None, x0=None):
        raise AssertionError("a budget of zero iterations is refused before any solve")


register("zero-allowed-search", ZeroAllowed(), "declares its budget setting with low=0")
"""
PSO_AGAIN = """
from formation_bench.optimizers import get_optimizer, register

register("pso", get_optimizer("pso"), "the same name again")
"""


PSO_SUITE = 'seeds = 1\n[[optimizers]]\nname = "pso"\n'
SUITES = {
    "zero_iterations_suite": "budgets = [{ max_iterations = 0 }]\n" + PSO_SUITE,
    "zero_evaluations_suite": "budgets = [{ max_evaluations = 0 }]\n" + PSO_SUITE,
    "own_zero_budget_suite": PSO_SUITE + "budgets = [{ max_iterations = 0 }]\n",
    "zero_override_suite": (
        'seeds = 1\n[[optimizers]]\nname = "ilqr"\noverrides = { max_iter = 0 }\n'
    ),
    "long_label_suite": PSO_SUITE + f'label = "{"x" * 5000}"\n',
    "just_over_label_suite": PSO_SUITE + f'label = "{"x" * (MAX_LABEL_CHARS + 1)}"\n',
    "long_scenario_label_suite": PSO_SUITE
    + f'[[scenarios]]\nname = "paper"\nlabel = "{"s" * 300}"\n',
    "long_derived_label_suite": PSO_SUITE
    + "overrides = { population_size = 12, max_iterations = 100, inertia_start = 0.8 }\n",
    "long_name_suite": f'name = "{"n" * 300}"\n' + PSO_SUITE,
    "two_line_label_suite": PSO_SUITE + 'label = "one\\ntwo"\n',
}
"""Suites of the cases, each written to ``NAME.toml`` and named by its ``{NAME}`` placeholder."""
SWEPT_SUITE = """
name = "two-optimizers"
seeds = 2
[[optimizers]]
name = "pso"
[[optimizers]]
name = "random-search"
[[scenarios]]
name = "paper"
overrides = { n_steps = 3, settle_time_s = 0.0 }
"""
"""A sweep of one trigger setting, one budget and one scenario, for the cases of ``{swept}``."""


def tutorial_plugin_source() -> str:
    tutorial = Path(__file__).parents[1] / "docs" / "tutorials" / "add-optimizer.md"
    blocks = re.findall(r"```python\n(.*?)```", tutorial.read_text(), flags=re.S)
    return next(b for b in blocks if "register(" in b)


@pytest.fixture(autouse=True)
def cold_kernel_cache(monkeypatch):
    """As on a first run: the compile notice must not come before a refusal."""
    monkeypatch.setattr("formation_bench.pipeline.runner.kernels_cached", lambda: False)


@pytest.fixture(autouse=True)
def no_plugin_left_behind():
    """A plugin a case loads into this process is unloaded after it."""
    from formation_bench import plugins
    from formation_bench.optimizers import OPTIMIZERS

    names, sources = set(OPTIMIZERS), set(plugins._plugins)
    yield
    for name in set(OPTIMIZERS) - names:
        OPTIMIZERS.pop(name)
    for source in set(plugins._plugins) - sources:
        sys.modules.pop(plugins._plugins.pop(source).__name__, None)


@pytest.fixture
def places(tmp_path: Path) -> dict[str, str]:
    afile = tmp_path / "afile"
    afile.write_text("not a folder\n")
    full = tmp_path / "full"
    full.mkdir()
    (full / "keep.txt").write_text("mine\n")
    bad_utf8 = tmp_path / "latin1.toml"
    bad_utf8.write_bytes('name = "caf\xe9"\nseeds = 1\n'.encode("latin-1"))
    bad_toml = tmp_path / "broken.toml"
    bad_toml.write_text("seeds = [1, 2\n")
    big_suite = tmp_path / "big.toml"
    big_suite.write_text(
        'seeds = 1\n[[optimizers]]\nname = "pso"\n'
        '[[scenarios]]\nname = "paper"\noverrides = { n_steps = 9000000 }\n'
    )
    huge_suite = tmp_path / "huge.toml"
    huge_suite.write_text(
        'seeds = 1000000000\n[[optimizers]]\nname = "pso"\n[[scenarios]]\nname = "paper"\n'
    )
    big_seed_suite = tmp_path / "bigseed.toml"
    big_seed_suite.write_text(
        f'seeds = [{2**128}]\n[[optimizers]]\nname = "pso"\n[[scenarios]]\nname = "paper"\n'
    )
    results = tmp_path / "results"
    (results / "runs").mkdir(parents=True)
    (results / "score").mkdir()
    no_optimizer_suite = tmp_path / "none.toml"
    no_optimizer_suite.write_text('seeds = 1\n[[optimizers]]\nname = "*"\nexclude = ["*"]\n')
    optional_suite = tmp_path / "optional.toml"
    optional_suite.write_text(
        'seeds = 1\n[[optimizers]]\nname = "not-installed-search"\noptional = true\n'
    )
    zero_weight_suite = tmp_path / "zero.toml"
    zero_weight_suite.write_text(
        'seeds = 1\n[[optimizers]]\nname = "pso"\n'
        '[[scenarios]]\nname = "paper"\noverrides = { w_dst = 0.0, w_trj = 0.0 }\n'
    )
    for name, text in SUITES.items():
        (tmp_path / f"{name}.toml").write_text(text)
    notes = tmp_path / "notes.md"
    notes.write_text("# My notes\n\nNot a page formation-bench wrote.\n")
    results_page = tmp_path / "page.md"
    results_page.write_text(
        "# Results: suite x (2026-01-01)\n\nSuite `x`, made by `formation-bench sweep x --out "
        "r`; this page is written by `formation-bench report r --page page.md` (on "
        "2026-01-01).\n"
    )
    plugins = {}
    for name, source in (("tutorial", tutorial_plugin_source()), ("plain", PLAIN_PLUGIN),
                         ("pso", PSO_AGAIN), ("zero", ZERO_PLUGIN)):  # fmt: skip
        plugins[f"{name}_plugin"] = str(tmp_path / f"{name}_plugin.py")
        Path(plugins[f"{name}_plugin"]).write_text(source)
    return {
        **plugins,
        **{name: str(tmp_path / f"{name}.toml") for name in SUITES},
        "long_name": str(tmp_path / ("a" * 300)),
        "long_page": str(tmp_path / ("a" * 300 + ".md")),
        "notes": str(notes),
        "results_page": str(results_page),
        "long_path": str(tmp_path / "/".join(["abcdefghi"] * 500)),
        "no_optimizer_suite": str(no_optimizer_suite),
        "optional_suite": str(optional_suite),
        "zero_weight_suite": str(zero_weight_suite),
        "out": str(tmp_path / "out"),
        "file": str(afile),
        "full": str(full),
        "dir": str(tmp_path),
        "bad_utf8": str(bad_utf8),
        "bad_toml": str(bad_toml),
        "big_suite": str(big_suite),
        "huge_suite": str(huge_suite),
        "big_seed_suite": str(big_seed_suite),
        "results": str(results),
    }


def snapshot(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes() if p.is_file() else b"<dir>"
        for p in sorted(root.rglob("*"))
    }


def test_there_are_at_least_forty_distinct_cases():
    assert len({tuple(args) for args, _ in CASES}) == len(CASES) >= 40


def test_the_boundary_has_at_least_twenty_five_distinct_cases():
    assert len({tuple(args) for args, _ in BOUNDARY}) == len(BOUNDARY) >= 25


@pytest.mark.parametrize(("args", "needle"), CASES, ids=lambda v: " ".join(v)[:60] if
                         isinstance(v, list) else None)  # fmt: skip
def test_bad_input_is_one_line_exit_2_and_writes_nothing(
    args, needle, places, tmp_path, capsys, request
):
    if any("{swept}" in a for a in args):  # swept only for the cases that read it
        places["swept"] = str(tmp_path / "swept")
        shutil.copytree(request.getfixturevalue("swept"), places["swept"])
    assert_refused(args, needle, places, tmp_path, capsys)


def assert_refused(args: list[str], needle: str, places: dict[str, str], tmp_path, capsys):
    """The command refuses in one line naming ``needle``, exit 2, and writes nothing."""
    before = snapshot(tmp_path)
    argv = [a.format(**places) for a in args]
    try:
        code = main(argv)
    except SystemExit as exit_:  # argparse's own errors
        code = exit_.code
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err
    assert err.startswith("formation-bench"), err
    assert needle in err, err
    assert snapshot(tmp_path) == before  # nothing created, nothing overwritten


@pytest.fixture(scope="module")
def swept(tmp_path_factory) -> Path:
    from formation_bench.experiments.suite import parse_suite
    from formation_bench.experiments.sweep import run_sweep

    folder = tmp_path_factory.mktemp("swept") / "results"
    suite = parse_suite(SWEPT_SUITE, Path("two-optimizers.toml"))
    run_sweep(suite, folder, jobs=1, progress=False, log=lambda text: None)
    return folder


def test_a_factor_of_several_levels_is_compared(swept, tmp_path):
    # the refusals of --compare above are of a factor with one level, not of --compare
    results = tmp_path / "results"
    shutil.copytree(swept, results)
    assert main(["report", str(results), "--compare", "optimizer", "--no-figures"]) == 0
    assert (results / "report" / "wilcoxon.csv").is_file()


# every command, as it would start its work; an environment variable is checked before it
EVERY_COMMAND = [
    [*RUN, *SHORT, "--out", "{out}"],
    ["reproduce", "--no-figures", "--out", "{out}"],
    ["sweep", "paper", "--out", "{out}"],
    ["sweep", "paper", "--out", "{out}", "--dry-run"],
    [*SCORE, "--out", "{out}"],
    ["report", "{results}"],
    ["export-ioh", "{results}"],
    ["list"],
]
ENVIRONMENT = [
    (name, value, args)
    for name in sorted(DECLARED)
    for value in ("bogus", "", " ")
    for args in EVERY_COMMAND
]


@pytest.mark.parametrize(
    ("variable", "value", "args"), ENVIRONMENT,
    ids=lambda v: " ".join(v)[:40] if isinstance(v, list) else repr(v),
)  # fmt: skip
def test_an_environment_variable_is_checked_before_any_work(
    variable, value, args, places, tmp_path, capsys, monkeypatch
):
    monkeypatch.setenv(variable, value)
    declared = DECLARED[variable]
    needle = f"{variable} must be one of {declared.allowed} (unset: "
    assert_refused(args, f"{needle}{declared.unset.value}), got {value!r}", places, tmp_path,
                   capsys)  # fmt: skip


@pytest.mark.parametrize("args", EVERY_COMMAND[:5], ids=lambda v: " ".join(v)[:40])
def test_the_c_kernel_asked_for_where_it_was_not_built_is_refused_before_any_work(
    args, places, tmp_path, capsys, monkeypatch
):
    monkeypatch.setenv("FORMATION_BENCH_COST_KERNEL", "C")
    monkeypatch.setattr("formation_bench.mpc.native_cost.native_cost_address", lambda: None)
    assert_refused(args, "FORMATION_BENCH_COST_KERNEL=c: the C cost kernel was not built",
                   places, tmp_path, capsys)  # fmt: skip


def test_every_registered_optimizer_has_its_budget_settings_covered():
    # the cases above reach every optimiser through budget_settings(): it must find one for
    # each (the field its default budget reads), or a new optimiser would go unchecked
    for name in OPTIMIZERS:
        assert budget_settings(OPTIMIZERS[name].optimizer), name


def test_a_folder_that_is_not_writable_is_refused(tmp_path, monkeypatch, capsys):
    # the tests may run as root, for whom every folder is writable: the permission is faked
    locked = tmp_path / "locked"
    locked.mkdir()
    real_access = os.access
    monkeypatch.setattr(
        "formation_bench.pipeline.staging.os.access",
        lambda path, mode: Path(path) != locked and real_access(path, mode),
    )
    assert main([*RUN, *SHORT, "--out", str(locked / "run")]) == 2
    err = capsys.readouterr().err
    assert (
        err.strip()
        == f"formation-bench run: error: --out {locked / 'run'}: {locked} is not writable "
        "(read-only or immutable)"
    )
    assert list(locked.iterdir()) == []


LONG_RUN = ["run", "--optimizer", "modified-bso", "--no-trigger", "--set", "n_steps=100000"]
INTERRUPTED = [
    # a run far too long to end by itself, into a new folder
    (LONG_RUN, rb"[1-9][0-9]*/100000", False, 1),
    # the paper runs replacing an old folder: the old folder must survive the interruption
    (["reproduce", "--seeds", "0", "1", "2", "--overwrite"], rb"[1-9][0-9]*/240", True, 1),
    # Ctrl-C pressed twice: the second must not cut the first one's clean-up short
    (LONG_RUN, rb"[1-9][0-9]*/100000", False, 2),
]  # fmt: skip


@pytest.mark.parametrize(("args", "running", "existing", "presses"), INTERRUPTED,
                         ids=["run", "reproduce", "run-twice"])  # fmt: skip
@pytest.mark.slow
def test_ctrl_c_exits_130_in_one_line_and_leaves_nothing_finished(
    args, running, existing, presses, tmp_path
):
    out = tmp_path / "out"
    if existing:
        out.mkdir()
        (out / "keep.txt").write_text("mine\n")
    before = snapshot(tmp_path)
    process = subprocess.Popen(
        [sys.executable, "-m", "formation_bench.cli.main", *args, "--progress",
         "--no-figures", "--out", str(out)],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        # a test runner started in the background ignores SIGINT, and a child inherits that:
        # restore the default so that Python turns Ctrl-C into KeyboardInterrupt, as in a shell
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    # interrupt once the closed loop is running: its progress bar counts solved instants
    assert process.stderr is not None
    seen = b""
    while not re.search(running, seen):
        ready, _, _ = select.select([process.stderr], [], [], 300)
        chunk = os.read(process.stderr.fileno(), 65536) if ready else b""
        assert chunk, f"the run ended or stalled before it started: {seen[-500:]!r}"
        seen += chunk
    for _ in range(presses):
        process.send_signal(signal.SIGINT)
    _, rest = process.communicate(timeout=120)
    err = (seen + rest).decode(errors="replace")
    assert process.returncode == 130, err[-500:]
    last = err.strip().splitlines()[-1].strip()
    assert last.endswith(f"formation-bench {args[0]}: interrupted"), last
    assert "Traceback" not in err
    assert snapshot(tmp_path) == before  # no staging folder left, an old folder untouched


def test_ctrl_c_while_the_command_imports_its_modules_exits_130_in_one_line():
    # the interrupt arrives in the middle of the command line's imports, as a Ctrl-C pressed
    # during the first half second would
    script = textwrap.dedent("""
        import signal, sys
        sys.argv[0] = "formation-bench"

        class InterruptAnImport:
            def find_spec(self, name, path=None, target=None):
                if name == "formation_bench.pipeline.runner":
                    signal.raise_signal(signal.SIGINT)
                return None

        sys.meta_path.insert(0, InterruptAnImport())
        from formation_bench.cli.main import main
        sys.exit(main(["list"]))
    """)
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    assert done.returncode == 130, done.stderr
    assert done.stderr.strip() == "formation-bench: interrupted"


@pytest.fixture
def python_sigint():
    """Python's own Ctrl-C handler during the test, as in a shell: a test runner started in
    the background ignores SIGINT, and a command started so rightly keeps ignoring it."""
    original = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, original)


def test_ctrl_c_while_a_plugin_loads_and_again_while_it_is_reported(
    tmp_path, monkeypatch, capsys, python_sigint
):
    from formation_bench.cli import main as cli

    plugin = tmp_path / "slow_plugin.py"
    plugin.write_text("import signal\nsignal.raise_signal(signal.SIGINT)\n")
    real = cli.is_interrupt

    def pressed_again(error: BaseException) -> bool:
        signal.raise_signal(signal.SIGINT)  # the second Ctrl-C, while the first is handled
        return real(error)

    monkeypatch.setattr(cli, "is_interrupt", pressed_again)
    before = signal.getsignal(signal.SIGINT)
    out = tmp_path / "out"
    try:
        code = main(["--plugin", str(plugin), *RUN, *SHORT, "--out", str(out)])
    except KeyboardInterrupt:
        pytest.fail("the second Ctrl-C escaped the command's handler")
    assert code == 130
    assert capsys.readouterr().err.strip() == "formation-bench run: interrupted"
    assert not out.exists()
    assert signal.getsignal(signal.SIGINT) is before  # a caller in its own process gets it back


def test_ctrl_c_while_parsing_the_arguments_exits_130(monkeypatch, capsys):
    from formation_bench.cli import main as cli

    def interrupted() -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert main(["list"]) == 130
    assert capsys.readouterr().err.strip() == "formation-bench: interrupted"


def test_outputs_get_ordinary_permissions(tmp_path):
    out = tmp_path / "run"
    assert main([*RUN, *SHORT, "--no-trigger", "--out", str(out)]) == 0
    mask = os.umask(0)
    os.umask(mask)
    assert (out.stat().st_mode & 0o777) == 0o777 & ~mask
    for path in out.iterdir():
        assert (path.stat().st_mode & 0o777) == 0o666 & ~mask, path


def test_overwrite_replaces_the_folder_as_a_whole(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "stale_figure.png").write_text("old")
    assert main([*RUN, *SHORT, "--no-trigger", "--overwrite", "--out", str(out)]) == 0
    assert not (out / "stale_figure.png").exists()
    assert (out / "metrics.json").is_file()


def boxed() -> SystemError:
    """numba's dispatcher: a KeyboardInterrupt raised while boxing a kernel's result."""
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as inner:
            raise SystemError("returned a result with an exception set") from inner
    except SystemError as outer:
        return outer


def test_an_interrupt_reported_by_numba_as_a_system_error_is_an_interrupt():
    from formation_bench.pipeline.interrupts import is_interrupt

    assert is_interrupt(KeyboardInterrupt())
    assert is_interrupt(boxed())
    assert not is_interrupt(SystemError("a real failure"))
    looped = ValueError("a")
    looped.__context__ = ValueError("b")
    looped.__context__.__context__ = looped
    assert not is_interrupt(looped)


def test_a_sweep_run_raises_an_interrupt_and_returns_a_real_failure(monkeypatch):
    from formation_bench.experiments import executors
    from formation_bench.mpc.scenario import get_scenario
    from formation_bench.optimizers import get_optimizer
    from formation_bench.pipeline.spec import RunSpec

    scenario = get_scenario("paper")
    spec = RunSpec.of("pso", get_optimizer("pso"), "paper", scenario, trigger=True, seed=0)
    monkeypatch.setattr(executors, "execute", lambda _: (_ for _ in ()).throw(boxed()))
    with pytest.raises(SystemError):  # in-process sweeps stop on it instead of storing it
        executors.execute_run(spec)
    monkeypatch.setattr(
        executors, "execute", lambda _: (_ for _ in ()).throw(SystemError("a real failure"))
    )
    result = executors.execute_run(spec)
    assert result.row is None and "a real failure" in result.error
