"""Commands import only what they use, and the trace they write keeps pandas' layout."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from formation_bench.mpc.scenario import get_scenario
from formation_bench.optimizers import get_optimizer
from formation_bench.pipeline.outputs import arrow_column, read_trace, text_column, write_trace
from formation_bench.pipeline.runner import execute
from formation_bench.pipeline.spec import RunSpec

PLOTTING = ("matplotlib", "seaborn")
STATISTICS = ("scipy.stats", "sklearn", "joblib", "statsmodels", "scikit_posthocs")
SOLVERS = ("casadi", "osqp", "cvxpy")
TABLES = ("pandas", "pyarrow")
SHORT = ["--set", "n_steps=6", "--set", "settle_time_s=0.5", "--set", "max_iterations=3"]

# Runs one command in this interpreter, then prints the modules it left imported.
PROBE = """
import json, sys
from formation_bench.cli.main import main
try:
    code = main(sys.argv[1:])
except SystemExit as stop:
    code = stop.code
print(json.dumps(sorted(sys.modules)), file=sys.stderr)
raise SystemExit(code)
"""


def modules_after(*command: str) -> set[str]:
    """Every module ``formation-bench COMMAND`` imports, run in a fresh interpreter."""
    done = subprocess.run(
        [sys.executable, "-c", PROBE, *command], capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr
    return set(json.loads(done.stderr.strip().splitlines()[-1]))


def imported(modules: set[str], names: tuple[str, ...]) -> list[str]:
    """Those of ``names`` imported, as a package or any of its submodules."""
    return [n for n in names if any(m == n or m.startswith(n + ".") for m in modules)]


@pytest.mark.parametrize("command", [["--help"], ["list"], ["list", "--fields", "pso"]])
def test_commands_that_only_print_import_no_heavy_library(command):
    modules = modules_after(*command)
    assert imported(modules, (*PLOTTING, *STATISTICS, *SOLVERS, *TABLES, "tqdm")) == []


def test_run_without_figures_imports_neither_plotting_nor_pandas(tmp_path):
    modules = modules_after(
        "run", "--optimizer", "modified-bso", "--no-figures", *SHORT, "--out", str(tmp_path / "r")
    )
    assert imported(modules, (*PLOTTING, *STATISTICS, *SOLVERS, "pandas", "tqdm")) == []
    assert imported(modules, ("pyarrow", "numba")) == ["pyarrow", "numba"]  # it writes Parquet
    assert (tmp_path / "r" / "trace.parquet").is_file()


@pytest.mark.slow
def test_run_with_figures_draws_them_without_seaborn(tmp_path):
    out = tmp_path / "r"
    modules = modules_after("run", "--optimizer", "modified-bso", *SHORT, "--out", str(out))
    assert imported(modules, ("seaborn", *STATISTICS, *SOLVERS)) == []
    assert imported(modules, ("matplotlib", "pandas")) == ["matplotlib", "pandas"]
    assert sorted(p.name for p in out.glob("*.png")) == [
        "fig5_trajectory_trigger.png",
        "fig6_states_trigger.png",
        "fig7_solve_instants_trigger.png",
        "separation_trigger.png",
    ]


def test_the_trace_table_is_what_pandas_would_have_written(tmp_path):
    """Built from buffers, the table equals the pandas route: NaN stored as null, the same
    column types, the same values; and it reads back as the run's DataFrame."""
    scenario = get_scenario("paper", n_steps=5, settle_time_s=0.2)
    optimizer = get_optimizer("modified-bso", max_iterations=2)
    spec = RunSpec.of("modified-bso", optimizer, "paper", scenario, trigger=True, seed=3)
    outcome = execute(spec)
    table = outcome.table
    via_pandas = pa.Table.from_pandas(outcome.frame, preserve_index=False)
    assert table.schema.remove_metadata() == via_pandas.schema.remove_metadata()
    assert table.equals(via_pandas.replace_schema_metadata(None))
    assert table["solve_time_s"].null_count > 0  # instants without a solve: null, not NaN
    types = {field.name: str(field.type) for field in table.schema}
    assert types["optimizer"] == types["budget"] == "large_string"
    assert types["seed"] == types["nfev"] == types["step"] == "int64"
    assert types["solved"] == "bool" and types["x_m"] == "double"
    path = tmp_path / "trace.parquet"
    write_trace(path, table)
    assert pq.read_table(path).equals(table)
    assert read_trace(path).equals(outcome.frame)


def test_arrow_columns_keep_values_and_mark_nan_missing():
    values = np.array([1.5, math.nan, -0.0, math.inf])
    column = arrow_column(values)
    assert column.type == pa.float64() and column.null_count == 1
    assert column.to_pylist() == [1.5, None, -0.0, math.inf]
    flags = np.array([True, False, True, True, False, False, True, False, True])
    assert arrow_column(flags).to_pylist() == flags.tolist()
    assert arrow_column(np.array([3, -(2**62)], dtype=np.int64)).to_pylist() == [3, -(2**62)]
    assert text_column("paper", 3).to_pylist() == ["paper"] * 3
    assert text_column("", 2).to_pylist() == ["", ""]
    with pytest.raises(TypeError, match="float64, int64 or bool, got int32"):
        arrow_column(np.zeros(2, dtype=np.int32))
