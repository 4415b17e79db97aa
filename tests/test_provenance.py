"""Every run record, metrics.json and manifest says which solver libraries and CPU made it."""

import json
from importlib import metadata
from pathlib import Path

import pytest

from formation_bench.cli.main import main
from formation_bench.experiments.store import load_results
from formation_bench.experiments.suite import parse_suite
from formation_bench.experiments.sweep import run_sweep
from formation_bench.pipeline import provenance
from formation_bench.pipeline.record import Provenance, is_timing_column

ONE_RUN = """\
name = "one"
seeds = 1
triggers = [true]

[[optimizers]]
name = "modified-bso"
overrides = { max_iterations = 3 }

[[scenarios]]
name = "paper"
overrides = { n_steps = 10, settle_time_s = 1.0 }
"""

LIBRARIES = ("casadi", "osqp", "cvxpy", "ioh")


def installed(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def cpuinfo_model() -> str | None:
    """The model name as /proc/cpuinfo gives it, read here independently of the code."""
    path = Path("/proc/cpuinfo")
    if not path.is_file():
        return None
    names = [line.split(":", 1)[1].strip() for line in path.read_text().splitlines()
             if line.startswith("model name")]  # fmt: skip
    return names[0] if names else None


def expected() -> dict[str, str | None]:
    return {f"{name}_version": installed(name) for name in LIBRARIES}


def test_the_new_provenance_columns_are_declared_as_describing_the_machine():
    for column in ("cpu_model", *expected()):
        assert column in Provenance.__dataclass_fields__
        assert is_timing_column(column)  # not compared between two runs of the same thing
    # the derivative-based baselines need casadi and osqp: a record always names them
    assert installed("casadi") and installed("osqp")


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    out = tmp_path_factory.mktemp("provenance") / "out"
    suite = parse_suite(ONE_RUN, Path("one.toml"))
    run_sweep(suite, out, jobs=1, progress=False, log=lambda _: None)
    return out


def test_a_stored_run_records_the_solver_libraries_and_the_cpu_model(swept):
    (row,) = load_results(swept).to_dict("records")
    for column, version in expected().items():
        assert row[column] == version
    assert row["cpu_model"] == provenance.cpu_model()
    if cpuinfo_model() is not None:
        assert row["cpu_model"] == cpuinfo_model()


def test_the_manifest_records_the_solver_libraries_and_the_cpu_model(swept):
    manifest = json.loads((swept / "manifest.json").read_text())
    for name in LIBRARIES:
        assert manifest["versions"][name] == installed(name)
    assert manifest["machine"]["cpu_model"] == provenance.cpu_model()
    session = manifest["sessions"][-1]
    assert session["versions"] == manifest["versions"]


def test_metrics_json_of_run_carries_the_same_columns(tmp_path, swept):
    out = tmp_path / "run"
    argv = ["run", "--optimizer", "modified-bso", "--set", "n_steps=10"]
    argv += ["--set", "settle_time_s=1.0", "--set", "max_iterations=3", "--out", str(out)]
    assert main(argv) == 0
    (record,) = json.loads((out / "metrics.json").read_text())
    (row,) = load_results(swept).to_dict("records")
    for column in ("cpu_model", *expected()):
        assert record[column] == row[column]
