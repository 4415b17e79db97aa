"""Sweeps: worker-count and order independence, resume, corrupt files, traces, the store."""

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from formation_bench.experiments.manifest import write_manifest
from formation_bench.experiments.store import (
    ResultStore,
    load_results,
    load_traces,
)
from formation_bench.experiments.suite import parse_suite
from formation_bench.experiments.sweep import SweepError, run_sweep
from formation_bench.optimizers import OPTIMIZERS, Budget, Optimizer
from formation_bench.optimizers.registry import RegisteredOptimizer
from formation_bench.pipeline.record import is_timing_column

TINY = """\
name = "tiny"
seeds = {seeds}
triggers = [true, false]
trace = {trace}

[[optimizers]]
name = "modified-bso"
overrides = {{ max_iterations = 3 }}

[[optimizers]]
name = "modified-bso-no-modifications"
overrides = {{ max_iterations = 3 }}

[[scenarios]]
name = "paper"
overrides = {{ n_steps = 10, settle_time_s = 1.0 }}
"""


def tiny(seeds="3", trace="false", path=Path("tiny.toml")):
    return parse_suite(TINY.format(seeds=seeds, trace=trace), path)


def sweep(suite, out, **kwargs):
    kwargs.setdefault("jobs", 1)
    return run_sweep(suite, out, progress=False, log=lambda _: None, **kwargs)


def deterministic(frame: pd.DataFrame) -> pd.DataFrame:
    """The results without timings and bookkeeping, in a fixed order."""
    keep = [c for c in frame.columns if not is_timing_column(c)]
    return frame[keep].sort_values("run_key").reset_index(drop=True)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted one-worker sweep of the tiny suite."""
    out = tmp_path_factory.mktemp("reference")
    summary = sweep(tiny(), out)
    assert summary.stored == 12 and summary.exit_code == 0
    return out, deterministic(load_results(out))


def test_one_and_two_workers_give_identical_results(reference, tmp_path):
    _, expected = reference
    summary = sweep(tiny(), tmp_path, jobs=2)
    assert summary.stored == 12 and not summary.failed
    got = load_results(tmp_path)
    assert got["worker_pid"].nunique() >= 1
    pd.testing.assert_frame_equal(deterministic(got), expected, check_exact=True)


def test_queue_order_and_suite_subset_do_not_change_a_run(reference, tmp_path):
    _, expected = reference
    sweep(tiny(seeds="[2, 0]"), tmp_path)
    got = deterministic(load_results(tmp_path))
    assert sorted(got["seed"].unique()) == [0, 2]
    subset = expected[expected["seed"].isin([0, 2])].reset_index(drop=True)
    pd.testing.assert_frame_equal(got, subset, check_exact=True)


def test_rerun_skips_finished_runs(reference, tmp_path):
    out = tmp_path / "r"
    shutil.copytree(reference[0], out)
    before = {p.name: p.stat().st_mtime_ns for p in (out / "runs").iterdir()}
    summary = sweep(tiny(), out)
    assert summary.already == 12 and summary.stored == 0 and summary.redo == {}
    assert {p.name: p.stat().st_mtime_ns for p in (out / "runs").iterdir()} == before
    manifest = json.loads((out / "manifest.json").read_text())
    assert [s["state"] for s in manifest["sessions"]] == ["done", "done"]


def test_corrupt_wrong_and_stale_files_are_redone(reference, tmp_path):
    out = tmp_path / "c"
    shutil.copytree(reference[0], out)
    files = sorted((out / "runs").glob("*.parquet"))
    data = files[0].read_bytes()
    files[0].write_bytes(data[: len(data) // 2])  # truncated
    files[1].write_bytes(b"not parquet at all")  # garbage
    shutil.copy(files[2], files[3])  # another run's result under this run's name
    table = pq.read_table(files[4])  # a result of an older configuration
    table = table.set_column(
        table.schema.get_field_index("config_hash"), "config_hash", pa.array(["0" * 64])
    )
    pq.write_table(table, files[4])
    (out / "runs" / f".{files[5].name}.abc.tmp").write_bytes(b"half a file")
    files[6].unlink()  # never finished
    summary = sweep(tiny(), out)
    assert summary.redo == {"corrupt": 3, "stale": 1}
    assert summary.stored == 5 and summary.already == 7
    assert not list((out / "runs").glob(".*"))
    pd.testing.assert_frame_equal(deterministic(load_results(out)), reference[1], check_exact=True)


def test_traces_are_stored_and_a_missing_trace_is_redone(tmp_path):
    suite = tiny(seeds="[0]", trace="true")
    summary = sweep(suite, tmp_path)
    assert summary.stored == 4
    traces = load_traces(tmp_path)
    assert len(traces) == 4 * 11 * 3
    assert set(traces["seed"]) == {0} and set(traces["budget"]) == {"default"}
    results = load_results(tmp_path)
    assert set(traces["run_key"]) == set(results["run_key"])
    solved = traces.groupby("run_key")["solved"].sum()
    assert (solved == results.set_index("run_key")["solves_total"].reindex(solved.index)).all()
    next(iter((tmp_path / "traces").glob("*.parquet"))).unlink()
    again = sweep(suite, tmp_path)
    assert again.redo == {"no-trace": 1} and again.stored == 1


def test_a_second_sweep_into_a_busy_folder_is_refused(tmp_path):
    with ResultStore(tmp_path).lock(), pytest.raises(SweepError, match="in use by another sweep"):
        sweep(tiny(), tmp_path)


def test_a_changed_suite_file_is_refused_unless_allowed(reference, tmp_path):
    out = tmp_path / "s"
    shutil.copytree(reference[0], out)
    bigger = tiny(seeds="4")
    with pytest.raises(SweepError, match="different suite file"):
        sweep(bigger, out)
    summary = sweep(bigger, out, allow_suite_change=True)
    assert summary.already == 12 and summary.stored == 4
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["suite"]["sha256"] == bigger.sha256
    assert len(manifest["previous_suites"]) == 1


def test_manifest_records_versions_commit_machine_and_suite(reference):
    manifest = json.loads((reference[0] / "manifest.json").read_text())
    assert manifest["suite"]["name"] == "tiny"
    assert manifest["suite"]["text"] == TINY.format(seeds="3", trace="false")
    assert manifest["suite"]["runs"] == 12
    assert manifest["versions"]["numpy"] and manifest["versions"]["python"]
    assert "commit" in manifest["git"]
    assert manifest["machine"]["cpu_count"] >= 1
    session = manifest["sessions"][-1]
    assert session["state"] == "done" and session["stored"] == 12 and session["failed"] == []


def test_duckdb_reads_the_parquet_store(reference):
    duckdb = pytest.importorskip("duckdb")
    out, _ = reference
    pattern = str(out / "runs" / "*.parquet")
    got = duckdb.sql(
        "SELECT optimizer, trigger, median(tracking_error_max_m) AS m, count(*) AS n "
        f"FROM read_parquet('{pattern}', union_by_name = true) GROUP BY ALL ORDER BY ALL"
    ).df()
    frame = load_results(out)
    expected = (
        frame.groupby(["optimizer", "trigger"])["tracking_error_max_m"]
        .agg(m="median", n="count")
        .reset_index()
    )
    assert got["n"].tolist() == expected["n"].tolist() == [3, 3, 3, 3]
    assert got["m"].tolist() == pytest.approx(expected["m"].tolist(), rel=0, abs=0)


@dataclass(frozen=True)
class _Broken(Optimizer):
    @property
    def default_budget(self) -> Budget:
        return Budget(max_iterations=1)

    def minimize(self, objective, bounds, rng, budget=None, x0=None):
        raise RuntimeError("this optimiser always fails")


def test_a_failing_run_is_reported_not_stored_and_retried(tmp_path, monkeypatch):
    monkeypatch.setitem(OPTIMIZERS, "broken", RegisteredOptimizer("broken", _Broken(), "fails"))
    text = TINY.format(seeds="[0]", trace="false").split("[[optimizers]]")[0]
    text += '[[optimizers]]\nname = "modified-bso"\n[[optimizers]]\nname = "broken"\n'
    text += '[[scenarios]]\nname = "paper"\noverrides = { n_steps = 10, settle_time_s = 1.0 }\n'
    suite = parse_suite(text, Path("b.toml"))
    messages = []
    summary = run_sweep(suite, tmp_path, jobs=1, progress=False, log=messages.append)
    assert summary.stored == 2 and len(summary.failed) == 2 and summary.exit_code == 1
    assert "always fails" in summary.failed[0]["error"]
    assert any(m.startswith("failed: broken") for m in messages)
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["sessions"][-1]["state"] == "failed"
    again = run_sweep(suite, tmp_path, jobs=1, progress=False, log=lambda _: None)
    assert again.already == 2 and len(again.failed) == 2


def test_results_read_back_as_one_frame(reference):
    frame = load_results(reference[0])
    assert len(frame) == 12 and frame["run_key"].is_unique
    for column in (
        "optimizer",
        "scenario",
        "trigger",
        "seed",
        "seed_entropy",
        "distance_error_max_m_d12",
        "solves_uav1",
        "solves_total",
        "tracking_error_max_m",
        "trigger_expiry",
    ):
        assert column in frame.columns
    assert set(frame["optimizer"]) == {
        "modified-bso[max_iterations=3]",
        "modified-bso-no-modifications[max_iterations=3]",
    }
    off = frame[~frame["trigger"]]
    assert (off["solves_total"] == 30).all()


def test_the_recorded_commit_is_the_installed_code_not_the_current_directory(tmp_path, monkeypatch):
    import subprocess

    from formation_bench.pipeline.provenance import git_info

    other = tmp_path / "unrelated"
    other.mkdir()
    git = ["git", "-C", str(other), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run([*git, "init", "-q"], check=True)
    (other / "f").write_text("x")
    subprocess.run([*git, "add", "f"], check=True)
    subprocess.run([*git, "commit", "-qm", "x"], check=True)
    unrelated = subprocess.run(
        [*git, "rev-parse", "HEAD"], capture_output=True, text=True, check=True
    ).stdout.strip()
    monkeypatch.chdir(other)
    info = git_info()
    assert info["commit"] != unrelated
    import formation_bench

    assert info["version"] == formation_bench.__version__


def test_a_sweep_that_fails_or_was_killed_is_not_left_running(tmp_path, monkeypatch):
    import json

    out = tmp_path / "store"

    def explode(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr("formation_bench.experiments.sweep._execute", explode)
    with pytest.raises(OSError, match="disk full"):
        sweep(tiny(seeds="1"), out)
    sessions = json.loads((out / "manifest.json").read_text())["sessions"]
    assert [s["state"] for s in sessions] == ["error"]
    # a sweep killed with SIGKILL leaves "running"; the next sweep holds the lock and knows
    manifest = json.loads((out / "manifest.json").read_text())
    manifest["sessions"][0]["state"] = "running"
    write_manifest(ResultStore(out), manifest)  # as the killed sweep wrote it, with its checksum
    monkeypatch.undo()
    sweep(tiny(seeds="1"), out)
    states = [s["state"] for s in json.loads((out / "manifest.json").read_text())["sessions"]]
    assert states == ["killed", "done"]


# --- records that describe themselves ----------------------------------------------------------


def rewritten(path: Path, change) -> None:
    """Store ``change(table)`` as the run file ``path`` (sealed, as a sweep writes it)."""
    table = change(pq.read_table(path))
    ResultStore(path.parent.parent).write_run(path.stem, table.to_pylist()[0], None)


def test_a_row_holds_every_setting_of_what_ran_and_rebuilds_it(reference):
    from formation_bench.pipeline.record import stored_configuration
    from formation_bench.pipeline.spec import flat_config, resolved_config_hash

    runs = {spec.key: spec for spec in tiny().runs()}
    rows = load_results(reference[0]).to_dict("records")
    for row in rows:
        scenario, optimizer = stored_configuration(row)
        expected_scenario, expected_optimizer = runs[row["run_key"]].configured()
        assert (scenario, optimizer) == (expected_scenario, expected_optimizer)
        assert json.loads(row["scenario_config"])["class"] == "Scenario"
        # the stored settings are the very ones the configuration hash was taken of
        budget = runs[row["run_key"]].budget_for(optimizer)
        assert resolved_config_hash(scenario, optimizer, budget) == row["config_hash"]
        assert flat_config(scenario)["n_steps"] == 10


def test_a_stored_configuration_is_read_without_todays_registry(reference, monkeypatch):
    from formation_bench.mpc import scenario as scenario_module
    from formation_bench.pipeline.record import stored_configuration

    row = load_results(reference[0]).to_dict("records")[0]
    before = stored_configuration(row)
    # today's registry knows another "paper": the stored row still says what ran
    changed = scenario_module.get_scenario("paper", eps_p=0.123)
    monkeypatch.setitem(scenario_module.SCENARIOS, "paper", changed)
    assert stored_configuration(row) == before
    # a row stored before configurations were kept is rebuilt from the registry only when
    # that reproduces its configuration hash: here it no longer does
    old = {k: v for k, v in row.items() if k not in ("scenario_config", "optimizer_config")}
    assert stored_configuration(old) == (None, None)
    monkeypatch.undo()
    assert stored_configuration(old) == before


def test_an_added_column_redoes_no_stored_run_and_reads_empty(reference, tmp_path):
    out = tmp_path / "old"
    shutil.copytree(reference[0], out)
    files = sorted((out / "runs").glob("*.parquet"))

    def before_configurations(table: pa.Table) -> pa.Table:
        return table.drop_columns(["scenario_config", "optimizer_config"])

    def format_3(table: pa.Table) -> pa.Table:  # 4 only added columns to 3
        table = before_configurations(table)
        index = table.schema.get_field_index("record_format")
        return table.set_column(index, "record_format", pa.array([3]))

    def format_2(table: pa.Table) -> pa.Table:  # columns that meant other things
        index = table.schema.get_field_index("record_format")
        return table.set_column(index, "record_format", pa.array([2]))

    rewritten(files[0], before_configurations)
    rewritten(files[1], format_3)
    rewritten(files[2], format_2)
    summary = sweep(tiny(), out)
    assert summary.redo == {"stale": 1} and summary.stored == 1 and summary.already == 11
    results = load_results(out)
    old = results["run_key"].isin([files[0].stem, files[1].stem])
    assert results.loc[old, "scenario_config"].isna().all()
    assert results.loc[~old, "scenario_config"].notna().all()
    expected = reference[1].drop(columns=["scenario_config", "optimizer_config", "record_format"])
    got = deterministic(results).drop(columns=["scenario_config", "optimizer_config"])
    pd.testing.assert_frame_equal(got.drop(columns="record_format"), expected, check_exact=True)
