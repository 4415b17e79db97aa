"""Optimisers and scenarios from outside the repository: entry points and ``--plugin``.

Nothing is installed: the entry point comes from a test distribution's metadata
(a ``*.dist-info`` folder with ``entry_points.txt``) on ``PYTHONPATH``, which is
all that ``importlib.metadata`` needs to find it.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from formation_bench import plugins
from formation_bench.experiments.store import load_results
from formation_bench.optimizers import OPTIMIZERS
from formation_bench.plugins import PluginError, Registry, load_plugin

PLUGIN_OPTIMIZER = '''
from dataclasses import dataclass

from formation_bench.fields import Validated, setting
from formation_bench.optimizers import Bounds, Budget, PopulationOptimizer, register


@dataclass(frozen=True)
class UniformSearch(Validated, PopulationOptimizer):
    """Uniform random search, as a user would write it outside the repository."""

    population_size: int = setting(8, low=1, doc="Points drawn per iteration")
    max_iterations: int = setting(3, low=0, doc="Iterations per solve")

    @property
    def default_budget(self) -> Budget:
        return Budget(max_iterations=self.max_iterations)

    def evaluations_per_step(self) -> int:
        return self.population_size

    def init(self, counter, bounds: Bounds, rng, x0, max_iterations):
        x = bounds.sample(rng, self.population_size)
        if x0 is not None:
            x[0] = x0
        return counter(x[: min(len(x), counter.remaining)])

    def step(self, state, counter, bounds, rng, iteration):
        return counter(bounds.sample(rng, min(self.population_size, counter.remaining)))


register("{name}", UniformSearch(), "uniform random search from a plugin")
'''

PLUGIN_SCENARIO = """
from formation_bench.mpc.scenario import get_scenario, register_scenario

register_scenario(get_scenario("paper", name="{name}", n_steps=6, settle_time_s=0.0))
"""

SUITE = """\
name = "plugin"
seeds = 2
triggers = [false]

[[optimizers]]
name = "{optimizer}"

[[optimizers]]
name = "pso"
overrides = {{ max_iterations = 2 }}

[[scenarios]]
name = "{scenario}"
"""

ROOT = Path(__file__).resolve().parents[1]


def cli(*args: str, env_path: Path | None = None, cwd: Path | None = None):
    env = dict(os.environ)
    if env_path is not None:
        env["PYTHONPATH"] = os.pathsep.join(
            p for p in (str(env_path), env.get("PYTHONPATH", "")) if p
        )
    return subprocess.run(
        [sys.executable, "-m", "formation_bench.cli.main", *args],
        capture_output=True,
        text=True,
        env=env,
        cwd=cwd,
        timeout=600,
    )


def make_distribution(root: Path, module: str, optimizer: str, scenario: str) -> Path:
    """A package plus the metadata of an installed distribution declaring both entry points."""
    package = root / module
    package.mkdir(parents=True)
    (package / "__init__.py").write_text(
        PLUGIN_OPTIMIZER.format(name=optimizer) + PLUGIN_SCENARIO.format(name=scenario)
    )
    info = root / f"{module}-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {module}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(
        f"[formation_bench.optimizers]\n{module} = {module}\n\n"
        f"[formation_bench.scenarios]\n{module} = {module}\n"
    )
    return root


@pytest.mark.slow
def test_entry_point_plugin_completes_a_two_worker_sweep(tmp_path):
    site = make_distribution(tmp_path / "site", "fb_entry_plugin", "ep-search", "ep-scenario")
    listing = cli("list", env_path=site)
    assert listing.returncode == 0, listing.stderr
    assert "ep-search" in listing.stdout and "ep-scenario" in listing.stdout
    suite = tmp_path / "plugin.toml"
    suite.write_text(SUITE.format(optimizer="ep-search", scenario="ep-scenario"))
    out = tmp_path / "results"
    done = cli("sweep", str(suite), "--out", str(out), "--jobs", "2", env_path=site)
    assert done.returncode == 0, done.stderr
    results = load_results(out)
    assert sorted(results["optimizer_name"].unique()) == ["ep-search", "pso"]
    assert len(results) == 4
    assert (results["solves_total"] > 0).all()


@pytest.mark.slow
def test_plugin_file_completes_a_two_worker_sweep_and_a_run(tmp_path):
    plugin = tmp_path / "my_plugin.py"
    plugin.write_text(
        PLUGIN_OPTIMIZER.format(name="file-search") + PLUGIN_SCENARIO.format(name="file-scenario")
    )
    suite = tmp_path / "plugin.toml"
    suite.write_text(SUITE.format(optimizer="file-search", scenario="file-scenario"))
    out = tmp_path / "results"
    # run from another folder: the plugin path is resolved before it reaches the workers
    done = cli(
        "--plugin", str(plugin), "sweep", str(suite), "--out", str(out), "--jobs", "2",
        cwd=tmp_path,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    results = load_results(out)
    assert sorted(results["optimizer_name"].unique()) == ["file-search", "pso"]
    assert len(results) == 4
    run = cli(
        "--plugin", str(plugin), "run", "--optimizer", "file-search", "--scenario",
        "file-scenario", "--no-trigger", "--no-figures", "--out", str(tmp_path / "run"),
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "run" / "metrics.json").is_file()


def test_without_the_plugin_the_name_is_unknown(tmp_path):
    suite = tmp_path / "plugin.toml"
    suite.write_text(SUITE.format(optimizer="file-search", scenario="paper"))
    done = cli("sweep", str(suite), "--out", str(tmp_path / "results"), "--jobs", "2")
    assert done.returncode == 2
    assert "file-search" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "results" / "runs").exists()


@pytest.fixture
def plugin_file(tmp_path):
    """A plugin loaded into this process, unregistered again afterwards."""
    path = tmp_path / "dask_plugin.py"
    path.write_text(PLUGIN_OPTIMIZER.format(name="dask-search"))
    yield path
    OPTIMIZERS.pop("dask-search", None)
    for source in list(plugins._plugins):
        module = plugins._plugins.pop(source)
        sys.modules.pop(module.__name__, None)


@pytest.mark.slow
def test_plugin_file_on_the_dask_path(tmp_path, plugin_file):
    distributed = pytest.importorskip("dask.distributed")
    from formation_bench.cli.main import main

    suite = tmp_path / "plugin.toml"
    suite.write_text(SUITE.format(optimizer="dask-search", scenario="paper").replace(
        'name = "paper"', 'name = "paper"\noverrides = { n_steps = 6, settle_time_s = 0.0 }'
    ))  # fmt: skip
    with distributed.LocalCluster(
        n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
        host="127.0.0.1",
    ) as cluster:  # fmt: skip
        code = main(["--plugin", str(plugin_file), "sweep", str(suite), "--out",
                     str(tmp_path / "dask"), "--scheduler", cluster.scheduler_address,
                     "--no-progress"])  # fmt: skip
    assert code == 0
    results = load_results(tmp_path / "dask")
    assert sorted(results["optimizer_name"].unique()) == ["dask-search", "pso"]


def test_load_plugin_errors_name_the_plugin(tmp_path):
    with pytest.raises(PluginError, match="no_such_module_xyz"):
        load_plugin("no_such_module_xyz")
    with pytest.raises(PluginError, match="no such file"):
        load_plugin(str(tmp_path / "missing.py"))
    broken = tmp_path / "broken_plugin.py"
    broken.write_text("raise RuntimeError('boom')\n")
    with pytest.raises(PluginError, match="RuntimeError: boom"):
        load_plugin(str(broken))
    assert str(broken) not in plugins._plugins


def test_a_broken_entry_point_is_named(tmp_path):
    site = tmp_path / "site"
    info = site / "fb_broken-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: fb_broken\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[formation_bench.optimizers]\nbad = fb_missing_mod\n")
    listing = cli("list", env_path=site)
    assert listing.returncode == 2
    assert "bad" in listing.stderr and "fb_missing_mod" in listing.stderr
    assert "Traceback" not in listing.stderr


def test_registry_refuses_duplicates_and_bad_names():
    registry: Registry[int] = Registry("thing", "formation_bench.no_such_group")
    registry.add("a-1", 1)
    with pytest.raises(ValueError, match="already registered"):
        registry.add("a-1", 2)
    with pytest.raises(ValueError, match="alphanumeric"):
        registry.add("bad name", 3)
    assert list(registry) == ["a-1"] and "a-1" in registry and len(registry) == 1
    assert "thing 'b'" in str(registry.unknown("b"))


def test_plugin_source_code_is_shown_in_the_tutorial():
    tutorial = (ROOT / "docs" / "tutorials" / "add-optimizer.md").read_text()
    assert "formation_bench.optimizers" in tutorial and "--plugin" in tutorial
    assert textwrap.dedent('[project.entry-points."formation_bench.optimizers"]') in tutorial


def one_line_refusal(done: subprocess.CompletedProcess, *needles: str) -> str:
    assert done.returncode == 2, done.stderr
    err = done.stderr.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in err, err
    return err


def test_plugin_settings_are_listed_and_a_bad_value_is_refused_before_the_run(tmp_path):
    plugin = tmp_path / "my_plugin.py"
    plugin.write_text(PLUGIN_OPTIMIZER.format(name="file-search"))
    listing = cli("--plugin", str(plugin), "list", "--fields", "file-search")
    assert listing.returncode == 0, listing.stderr
    assert "population_size = 8  (int; integer >= 1; not tuned)" in listing.stdout
    assert "Points drawn per iteration" in listing.stdout
    out = tmp_path / "run"
    done = cli(
        "--plugin", str(plugin), "run", "--optimizer", "file-search",
        "--set", "population_size=0", "--out", str(out),
    )  # fmt: skip
    err = one_line_refusal(done, "--set population_size", "integer >= 1")
    assert err.endswith("got 0"), err
    assert not out.exists()


@pytest.mark.slow
def test_a_name_from_an_entry_point_and_a_plugin_is_refused_by_every_command(tmp_path):
    site = make_distribution(tmp_path / "site", "fb_twice_plugin", "twice-search", "twice-scn")
    plugin = tmp_path / "twice.py"
    plugin.write_text(PLUGIN_OPTIMIZER.format(name="twice-search"))
    results = tmp_path / "results"
    (results / "runs").mkdir(parents=True)
    (results / "score").mkdir()
    commands = [
        ["list"],
        ["run", "--optimizer", "twice-search", "--no-figures", "--out", str(tmp_path / "r")],
        ["sweep", "paper", "--out", str(tmp_path / "s")],
        ["score", "--optimizer", "twice-search", "--out", str(tmp_path / "c")],
        ["report", str(results), "--out", str(tmp_path / "p")],
        ["export-ioh", str(results), "--out", str(tmp_path / "e")],
    ]
    for command in commands:
        done = cli("--plugin", str(plugin), *command, env_path=site)
        one_line_refusal(done, "'twice-search' is already registered by entry point", "twice.py")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results", "site", "twice.py"]
