"""The package's shape: one installed namespace, dependencies pointing one way, lazy imports."""

from __future__ import annotations

import ast
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from formation_bench.mpc.native_cost import native_cost_address

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "formation_bench"
HARNESS = (
    "formation_bench.mpc",
    "formation_bench.pipeline",
    "formation_bench.instances",
    "formation_bench.experiments",
    "formation_bench.tuning",
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


# --- the module graph ----------------------------------------------------------------------

LAYERS = ("optimizers", "mpc", "pipeline", "instances", "experiments", "tuning", "analysis", "cli")
"""The subpackages, each importing only from itself and those before it."""
SHARED = ("fields", "plugins", "environment", "kernel_cache", "_version")
"""Modules beside the subpackages that every layer may import (as the package root)."""


def module_name(path: Path, package: Path = PACKAGE) -> str:
    """``formation_bench.mpc.loop`` for ``src/formation_bench/mpc/loop.py``; a package is
    named by its folder."""
    parts = list(path.relative_to(package.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    """Every module of the package and the package's modules it imports: at the top, in a
    function or under ``TYPE_CHECKING`` alike. ``from a.b import c`` imports the module
    ``a.b.c`` if there is one, else ``a.b``."""
    paths = {module_name(path, package): path for path in sorted(package.rglob("*.py"))}
    graph = {}
    for name, path in paths.items():
        own = name if path.name == "__init__.py" else name.rpartition(".")[0]
        candidates = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                candidates.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    parent = own.rsplit(".", node.level - 1)[0] if node.level > 1 else own
                    base = f"{parent}.{base}" if base else parent
                for alias in node.names:
                    module = f"{base}.{alias.name}"
                    candidates.add(module if module in paths else base)
            elif isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "import_module":
                candidates.update(a.value for a in node.args if isinstance(a, ast.Constant))
        graph[name] = {c for c in candidates if c in paths and c != name}
    return graph


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle (``[a, b, ..., a]``) through every group of modules that import each other,
    directly or through others (Tarjan's strongly connected components)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    groups: list[set[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for target in sorted(graph[node]):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            group = set()
            while True:
                member = stack.pop()
                group.add(member)
                if member == node:
                    break
            if len(group) > 1:
                groups.append(group)

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return [_cycle_within(graph, group) for group in groups]


def _cycle_within(graph: dict[str, set[str]], group: set[str]) -> list[str]:
    """The shortest cycle from the group's first module back to it, inside the group."""
    start = min(group)
    paths = {start: [start]}
    frontier = [start]
    while frontier:
        following = []
        for node in frontier:
            for target in sorted(graph[node] & group):
                if target == start:
                    return [*paths[node], start]
                if target not in paths:
                    paths[target] = [*paths[node], target]
                    following.append(target)
        frontier = following
    raise AssertionError(f"no cycle through {start} in {sorted(group)}")


def layer_of(module: str) -> int | None:
    """The place of a module's subpackage in :data:`LAYERS`; None for the shared modules."""
    parts = module.split(".")
    return LAYERS.index(parts[1]) if len(parts) > 1 and parts[1] in LAYERS else None


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    """Every import of a module from a later subpackage than its own, as ``a -> b``."""
    found = []
    for module, targets in sorted(graph.items()):
        for target in sorted(targets):
            own, other = layer_of(module), layer_of(target)
            if own is not None and other is not None and other > own:
                found.append(f"{module} -> {target} ({LAYERS[own]} imports {LAYERS[other]})")
    return found


def test_no_modules_import_each_other_in_a_cycle():
    cycles = find_cycles(import_graph())
    assert not cycles, "import cycles:\n" + "\n".join(" -> ".join(c) for c in cycles)


def test_the_subpackages_import_only_downwards():
    offending = upward_imports(import_graph())
    order = " < ".join(LAYERS)
    assert not offending, f"imports against the order {order}:\n" + "\n".join(offending)


def test_every_module_is_in_a_layer_or_shared():
    shared = {PACKAGE.name, *(f"{PACKAGE.name}.{name}" for name in SHARED)}
    loose = [m for m in import_graph() if layer_of(m) is None and m not in shared]
    assert not loose, f"modules in no subpackage of {LAYERS} and not shared: {loose}"


def test_the_graph_checks_find_a_cycle_and_an_upward_import(tmp_path):
    package = tmp_path / "formation_bench"
    for folder in ("mpc", "analysis"):
        (package / folder).mkdir(parents=True)
        (package / folder / "__init__.py").write_text("")
    (package / "__init__.py").write_text("")
    (package / "mpc" / "a.py").write_text("def f():\n    from . import b\n")
    (package / "mpc" / "b.py").write_text("from formation_bench.mpc.c import thing\n")
    (package / "mpc" / "c.py").write_text("import formation_bench.mpc.a\n")
    (package / "mpc" / "d.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n"
        "    from formation_bench.analysis import report\n"
    )
    (package / "analysis" / "report.py").write_text("from formation_bench.mpc import d\n")
    graph = import_graph(package)
    assert graph["formation_bench.mpc.a"] == {"formation_bench.mpc.b"}
    cycles = sorted(find_cycles(graph))
    assert cycles == [
        ["formation_bench.analysis.report", "formation_bench.mpc.d",
         "formation_bench.analysis.report"],
        ["formation_bench.mpc.a", "formation_bench.mpc.b", "formation_bench.mpc.c",
         "formation_bench.mpc.a"],
    ]  # fmt: skip
    assert upward_imports(graph) == [
        "formation_bench.mpc.d -> formation_bench.analysis.report (mpc imports analysis)"
    ]


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


@pytest.mark.slow
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
    skip = shutil.ignore_patterns(
        ".git", ".venv*", "build", "results", "__pycache__", "*.egg-info", "*.so"
    )
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
    # the C cost kernel is compiled into the wheel wherever a compiler works (as here)
    if native_cost_address() is not None:
        assert any(n.startswith("formation_bench/mpc/_cost_kernel") for n in names)
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


def test_the_environment_is_read_only_through_declared_variables():
    # every command checks the declared variables before it starts: a variable read anywhere
    # else would be an input no command checks
    readers = [
        str(path.relative_to(PACKAGE))
        for path in sorted(PACKAGE.rglob("*.py"))
        if path.name != "environment.py"
        and any(word in path.read_text() for word in ("os.environ", "getenv", "environ["))
    ]
    assert readers == []


def test_the_layout_page_lists_every_module_in_its_folders_row():
    """The map a newcomer is sent to: a row per folder of the package, naming each module."""
    page = (ROOT / "docs" / "explanation" / "layout.md").read_text()
    table = page[page.index("| folder of `src/formation_bench/` |") :].split("\n\n")[0]
    rows = {}
    for line in table.splitlines()[2:]:
        found = re.match(r"\| `(\./|[a-z_/]+/)` \|", line)
        assert found, line
        rows[f"formation_bench/{found.group(1)}".removesuffix("./").rstrip("/")] = line
    missing = []
    for path in sorted(PACKAGE.rglob("*.py")):
        folder = path.parent.relative_to(PACKAGE.parent).as_posix()
        row = rows.get(folder)
        if row is None:
            missing.append(f"no row for src/{folder}/")
        elif path.name != "__init__.py" and f"`{path.name}`" not in row:
            missing.append(f"src/{folder}/{path.name}")
    assert not sorted(set(missing)), sorted(set(missing))
