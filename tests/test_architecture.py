"""The package's shape: one installed namespace, dependencies pointing one way, lazy imports."""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "formation_bench"
HARNESS = (
    "formation_bench.mpc",
    "formation_bench.pipeline",
    "formation_bench.instances",
    "formation_bench.experiments",
    "formation_bench.analysis",
    "formation_bench.cli",
)


def imported_modules(path: Path, package: str) -> set[str]:
    """Every module a file imports, relative imports resolved against ``package``."""
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
                found.add(f"{base}.{node.module}" if node.module else base)
            elif node.module:
                found.add(node.module)
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "import_module":
            found.update(a.value for a in node.args if isinstance(a, ast.Constant))
    return found


OPTIMIZER_FILES = sorted((PACKAGE / "optimizers").rglob("*.py"))


@pytest.mark.parametrize("path", OPTIMIZER_FILES, ids=lambda p: p.name)
def test_optimizers_import_nothing_of_the_harness(path):
    imports = imported_modules(path, "formation_bench.optimizers")
    offending = sorted(m for m in imports if m.startswith(HARNESS) or m.split(".")[0] == "perf")
    assert not offending, f"{path.name} imports {offending}"


def test_the_import_check_sees_a_harness_import(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("from ..mpc import loop\nimport formation_bench.cli.main\n")
    imports = imported_modules(bad, "formation_bench.optimizers")
    assert {"formation_bench.mpc", "formation_bench.cli.main"} <= imports


def loaded_after(code: str) -> set[str]:
    """Top-level modules loaded in a fresh interpreter after running ``code``."""
    probe = code + "\nimport sys\nprint(' '.join(sorted({m.split('.')[0] for m in sys.modules})))"
    done = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=300, cwd=ROOT
    )
    assert done.returncode == 0, done.stderr
    return set(done.stdout.split())


def test_importing_the_harness_loads_no_solver_library():
    loaded = loaded_after(
        "import formation_bench.mpc.loop, formation_bench.mpc.metrics, formation_bench.mpc.problem"
        ", formation_bench.mpc.scenario, formation_bench.mpc.solvers\n"
        "from formation_bench.optimizers import get_optimizer\n"
        "get_optimizer('ipopt'); get_optimizer('ltv-osqp')"
    )
    assert "formation_bench" in loaded
    assert not loaded & {"casadi", "osqp", "cvxpy", "matplotlib", "seaborn"}


def test_listing_the_optimizers_loads_no_adapted_library():
    loaded = loaded_after(
        "from formation_bench.optimizers import get_optimizer, optimizer_names\n"
        "names = optimizer_names()\n"
        "[get_optimizer(n) for n in ('ng-ngopt', 'pycma', 'mealpy-bso') if n in names]"
    )
    assert "formation_bench" in loaded
    assert not loaded & {"nevergrad", "cma", "mealpy"}


def test_the_solver_libraries_are_loaded_when_a_solver_is_built():
    loaded = loaded_after(
        "import numpy as np\n"
        "from formation_bench.instances.instants import record_instants\n"
        "from formation_bench.mpc.scenario import get_scenario\n"
        "from formation_bench.optimizers import get_optimizer\n"
        "problem = record_instants(get_scenario('paper'), get_optimizer('pso'), [1])[0].problem\n"
        "get_optimizer('ltv-osqp').minimize(problem, problem.bounds, np.random.default_rng(0))"
    )
    assert {"casadi", "osqp"} <= loaded


def test_a_run_without_figures_loads_no_plotting_library(tmp_path):
    out = tmp_path / "run"
    loaded = loaded_after(
        "from formation_bench.cli.main import main\n"
        f"assert main(['run', '--optimizer', 'pso', '--no-trigger', '--no-figures', '--set', "
        f"'n_steps=3', '--set', 'settle_time_s=0', '--out', {str(out)!r}]) == 0"
    )
    assert (out / "metrics.json").is_file()
    assert not loaded & {"matplotlib", "seaborn"}


def test_the_wheel_installs_one_top_level_package_with_its_data(tmp_path):
    """Built without isolation from the installed build tools, so it works offline."""
    pytest.importorskip("setuptools_scm")
    # a copy, so that the build folder setuptools leaves behind is not in the checkout
    source = tmp_path / "source"
    skip = shutil.ignore_patterns(".git", ".venv*", "build", "results", "__pycache__", "*.egg-info")
    shutil.copytree(ROOT, source, ignore=skip)
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
         "--wheel-dir", str(tmp_path), str(source)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert built.returncode == 0, built.stderr[-2000:]
    (wheel,) = tmp_path.glob("formation_bench-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names if not n.split("/")[0].endswith(".dist-info")}
    assert top == {"formation_bench"}
    for shipped in ("ablation", "comparison", "deadline", "paper", "trigger"):
        assert f"formation_bench/experiments/suites/{shipped}.toml" in names
    for data in ("v1.npz", "v1.json"):
        assert f"formation_bench/instances/data/{data}" in names
    assert "formation_bench/py.typed" in names
    assert "formation_bench/mpc/solvers/ipopt_solver.py" in names
    assert "formation_bench/optimizers/adapters/nevergrad_adapter.py" in names
    meta = next(n for n in names if n.endswith(".dist-info/entry_points.txt"))
    entry_points = zipfile.ZipFile(wheel).read(meta).decode()
    assert "formation_bench.mpc.solvers" in entry_points
    license_files = [n for n in names if n.endswith("LICENSE")]
    assert license_files


BSO_MODULES = ("bso_ops", "bso_clusters", "modified_bso", "original_bso", "cls_bso", "clustering")


@pytest.mark.parametrize("name", ["base.py", "population.py", "registry.py", "bound_handling.py"])
def test_generic_population_code_imports_no_bso_operator(name):
    imports = imported_modules(PACKAGE / "optimizers" / name, "formation_bench.optimizers")
    offending = sorted(m for m in imports if m.rsplit(".", 1)[-1].startswith(BSO_MODULES))
    assert not offending, f"{name} imports {offending}"
