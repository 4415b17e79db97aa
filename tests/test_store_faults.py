"""The results store under faults a user or a machine injects: symbolic links inside a results
folder, a manifest stripped of its seal or unreadable, a sweep resumed under another commit,
a negative stored duration, files the store does not own, a sweep stopped while two local
workers compute, and a Dask scheduler or all its workers lost.

Each fault ends in one line (exit 2) or one notice, touches nothing outside the folder the
user named, and leaves a folder the same command resumes.
"""

from __future__ import annotations

import json
import os
import select
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from formation_bench.analysis.results_page import suite_provenance
from formation_bench.cli.main import main
from formation_bench.experiments import manifest as manifest_module
from formation_bench.experiments.manifest import read_manifest, write_manifest
from formation_bench.experiments.seal import MANIFEST_DIGEST, MANIFEST_SEAL
from formation_bench.experiments.store import ResultStore, load_results
from formation_bench.experiments.suite import load_suite
from formation_bench.experiments.sweep import run_sweep
from formation_bench.pipeline import provenance

SUITE = """\
name = "store-faults"
seeds = {seeds}
triggers = [true, false]
trace = true

[[optimizers]]
name = "modified-bso"
overrides = {{ max_iterations = 3 }}

[[scenarios]]
name = "paper"
overrides = {{ n_steps = 10, settle_time_s = 1.0 }}
"""
SEEDS = 2
RUNS = 2 * SEEDS
COMMAND = [sys.executable, "-m", "formation_bench.cli.main"]
DEADLINE_S = 240.0


def suite_file(folder: Path, seeds: int = SEEDS) -> Path:
    path = folder / f"store-faults-{seeds}.toml"
    path.write_text(SUITE.format(seeds=seeds))
    return path


def sweep(suite: Path, out: Path, messages: list[str] | None = None):
    log = messages.append if messages is not None else (lambda _: None)
    return run_sweep(load_suite(str(suite)), out, jobs=1, progress=False, log=log)


def one_line(text: str) -> str:
    lines = text.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


def snapshot(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes() if p.is_file() else b"<dir>"
        for p in sorted(root.rglob("*"))
    }


@pytest.fixture(scope="module")
def stored(tmp_path_factory) -> tuple[Path, Path]:
    """A suite file and a finished sweep of it (runs, traces, manifest)."""
    root = tmp_path_factory.mktemp("store-faults")
    suite = suite_file(root)
    out = root / "store"
    assert sweep(suite, out).stored == RUNS
    return suite, out


def copy_of(stored: tuple[Path, Path], tmp_path: Path) -> Path:
    out = tmp_path / "store"
    shutil.copytree(stored[1], out)
    return out


def elsewhere(tmp_path: Path) -> Path:
    """A folder outside the results folder, holding a sentinel file and a file named like a
    temporary file of the store, which a link inside the results folder points to."""
    target = tmp_path / "elsewhere"
    target.mkdir()
    (target / "sentinel.txt").write_text("the user's own file\n")
    (target / f".{'0' * 24}.parquet.abcd1234.tmp").write_text("not the store's\n")
    return target


# --- symbolic links inside a results folder ----------------------------------------------------


def test_report_overwrite_never_deletes_through_a_linked_report_folder(stored, tmp_path, capsys):
    out = copy_of(stored, tmp_path)
    target = elsewhere(tmp_path)
    (out / "report").symlink_to(target)
    before = snapshot(target)
    for extra in ([], ["--overwrite"]):
        assert main(["report", str(out), "--no-figures", *extra]) == 2
        line = one_line(capsys.readouterr().err)
        assert line.startswith(f"formation-bench report: error: DIR {out}: {out / 'report'} is a ")
        assert f"symbolic link (to {target})" in line
    assert snapshot(target) == before  # nothing deleted, nothing written
    assert not list(tmp_path.glob(".elsewhere*")) and not list(out.glob(".report*"))


@pytest.mark.parametrize("folder", ["traces", "runs"])
def test_a_sweep_never_writes_or_deletes_through_a_linked_store_folder(
    stored, tmp_path, capsys, folder
):
    suite, _ = stored
    out = copy_of(stored, tmp_path)
    target = elsewhere(tmp_path)
    for path in (out / folder).iterdir():
        path.unlink()  # every run (or trace) to do again, so the sweep would write there
    (out / folder).rmdir()
    (out / folder).symlink_to(target)
    before, inside = snapshot(target), snapshot(out)
    assert main(["sweep", str(suite), "--out", str(out), "--no-progress"]) == 2
    line = one_line(capsys.readouterr().err)
    assert f"{out / folder} is a symbolic link (to {target})" in line
    assert snapshot(target) == before
    assert snapshot(out) == inside


def test_a_linked_lock_file_is_not_created_through(stored, tmp_path, capsys):
    suite, _ = stored
    out = copy_of(stored, tmp_path)
    target = elsewhere(tmp_path)
    (out / ".lock").unlink()
    (out / ".lock").symlink_to(target / "their.lock")  # opening it would create that file
    before = snapshot(target)
    assert main(["sweep", str(suite), "--out", str(out), "--no-progress"]) == 2
    assert f"{out / '.lock'} is a symbolic link" in one_line(capsys.readouterr().err)
    assert snapshot(target) == before


def test_a_store_folder_swapped_for_a_link_mid_sweep_is_not_written_through(
    stored, tmp_path, monkeypatch, capsys
):
    suite, _ = stored
    out = tmp_path / "store"
    target = elsewhere(tmp_path)
    before = snapshot(target)
    real_replace = os.replace
    swapped: list[Path] = []

    def replace_then_swap(src, dst, *args, **kwargs):
        real_replace(src, dst, *args, **kwargs)
        if Path(dst).parent == out / "runs" and not swapped:  # after the first run is stored
            shutil.rmtree(out / "traces")
            (out / "traces").symlink_to(target)
            swapped.append(out / "traces")

    monkeypatch.setattr(os, "replace", replace_then_swap)
    assert main(["sweep", str(suite), "--out", str(out), "--no-progress", "--jobs", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert swapped and f"{out / 'traces'} is a symbolic link (to {target})" in err[-1]
    assert err[-1].startswith("formation-bench sweep: error: ")
    assert snapshot(target) == before
    assert len(list((out / "runs").glob("*.parquet"))) == 1


# --- report --page ------------------------------------------------------------------------------


def _chattr(flag: str, path: Path) -> bool:
    if shutil.which("chattr") is None:
        return False
    return subprocess.run(["chattr", flag, str(path)], capture_output=True).returncode == 0


def test_a_page_is_regenerated_only_with_overwrite_and_never_on_an_immutable_path(
    stored, tmp_path, capsys
):
    out = copy_of(stored, tmp_path)
    page = tmp_path / "page.md"
    assert main(["report", str(out), "--no-figures", "--page", str(page)]) == 0
    capsys.readouterr()
    report = snapshot(out / "report")
    assert main(["report", str(out), "--no-figures", "--page", str(page)]) == 2
    assert "exists; add --overwrite to write it anew" in one_line(capsys.readouterr().err)
    if not _chattr("+i", page):
        pytest.skip("no immutable files here (chattr)")
    try:
        args = ["report", str(out), "--no-figures", "--overwrite", "--page", str(page)]
        assert main(args) == 2
        line = one_line(capsys.readouterr().err)
        assert f"--page {page}: exists and is not writable (read-only or immutable)" in line
    finally:
        _chattr("-i", page)
    assert snapshot(out / "report") == report  # refused before the report was rewritten
    (out / "report").rename(tmp_path / "first-report")
    folder = tmp_path / "locked"
    folder.mkdir()
    assert _chattr("+i", folder)
    try:
        assert main(["report", str(out), "--no-figures", "--page", str(folder / "p.md")]) == 2
        line = one_line(capsys.readouterr().err)
        assert f"{folder} is not writable (read-only or immutable)" in line
    finally:
        _chattr("-i", folder)
    assert not (out / "report").exists()  # refused before the report folder was written
    assert main(["report", str(out), "--no-figures", "--overwrite", "--page", str(page)]) == 0


# --- the manifest ------------------------------------------------------------------------------


def _strip_seal(path: Path, **changes: object) -> dict:
    manifest = json.loads(path.read_text())
    del manifest[MANIFEST_SEAL], manifest[MANIFEST_DIGEST]
    manifest.update(changes)
    path.write_text(json.dumps(manifest, indent=2))
    return manifest


@pytest.mark.parametrize(
    "form", ["current format", "current format beside unsealed runs", "format 1 beside sealed runs"]
)
def test_a_manifest_stripped_of_its_seal_is_damage_never_resealed(stored, tmp_path, capsys, form):
    suite, _ = stored
    out = copy_of(stored, tmp_path)
    manifest = out / "manifest.json"
    if form == "current format beside unsealed runs":
        for file in (out / "runs").glob("*.parquet"):
            pq.write_table(pq.read_table(file), file)  # as written before seals
    invented = {"git": {"commit": "f" * 40, "dirty": False}, "versions": {"formation-bench": "9"}}
    if form == "format 1 beside sealed runs":
        invented["format"] = 1
    _strip_seal(manifest, **invented)
    before = snapshot(out)
    assert main(["sweep", str(suite), "--out", str(out), "--no-progress"]) == 2
    line = one_line(capsys.readouterr().err)
    assert f"{manifest} has no seal" in line and "--rebuild-manifest" in line
    assert snapshot(out) == before  # not re-sealed with the invented provenance


def test_a_manifest_from_before_seals_beside_runs_from_before_seals_is_taken_then_sealed(
    stored, tmp_path
):
    suite, _ = stored
    out = copy_of(stored, tmp_path)
    for file in (out / "runs").glob("*.parquet"):
        pq.write_table(pq.read_table(file), file)  # as written before seals
    manifest = _strip_seal(out / "manifest.json", format=1)
    assert read_manifest(ResultStore(out)) == manifest
    assert sweep(suite, out).redo == {"unverified": RUNS}
    sealed = json.loads((out / "manifest.json").read_text())
    assert next(iter(sealed)) == MANIFEST_SEAL and sealed["format"] == 2


def test_a_manifest_that_cannot_be_read_is_said_so_not_called_damaged(stored, tmp_path, capsys):
    suite, _ = stored
    out = copy_of(stored, tmp_path)
    manifest = out / "manifest.json"
    manifest.unlink()
    manifest.mkdir()  # an I/O error that stops root too (EISDIR)
    before = snapshot(out)
    for extra in ([], ["--dry-run"], ["--rebuild-manifest"]):
        assert main(["sweep", str(suite), "--out", str(out), *extra]) == 2
        line = one_line(capsys.readouterr().err)
        assert f"{manifest} could not be read (Is a directory)" in line, line
        assert "damaged" not in line and "--rebuild-manifest" not in line
    assert snapshot(out) == before


# --- provenance --------------------------------------------------------------------------------


def _at_commit(monkeypatch, commit: str) -> None:
    info = {"version": f"1.0+g{commit[:9]}", "commit": commit, "dirty": False, "source": "x"}
    monkeypatch.setattr(provenance, "git_info", lambda: info)
    monkeypatch.setattr(manifest_module, "git_info", lambda: info)


def test_a_sweep_resumed_under_another_commit_says_the_folder_now_mixes_commits(
    stored, tmp_path, monkeypatch
):
    suite, _ = stored
    out = tmp_path / "store"
    store = ResultStore(out)
    earlier = "a" * 40
    _at_commit(monkeypatch, earlier)
    assert sweep(suite, out).stored == RUNS
    messages: list[str] = []
    assert sweep(suite, out, messages).already == RUNS  # the same code: nothing said
    assert not [m for m in messages if "mixes" in m]
    for key in store.keys()[:2]:
        store.run_path(key).unlink()
    other = "b" * 40
    _at_commit(monkeypatch, other)
    assert sweep(suite, out, messages).stored == 2
    notes = [m for m in messages if "mixes code versions" in m]
    assert len(notes) == 1 and "\n" not in notes[0]
    assert notes[0].startswith("note: the 2 runs stored in this folder were made at commit ")
    assert f"{earlier[:10]}; this sweep runs commit {other[:10]}" in notes[0]
    version = suite_provenance(out, load_results(out)).version
    assert "; the runs were made at 2 different commits, so this folder mixes code " in version
    assert f"{other[:10]} (2 runs)" in version and f"{earlier[:10]}" in version


def test_results_pages_read_the_manifest_verified(stored, tmp_path, capsys):
    out = copy_of(stored, tmp_path)
    results = load_results(out)
    _strip_seal(out / "manifest.json", versions={"formation-bench": "invented"})
    with pytest.raises(manifest_module.ManifestError, match="has no seal"):
        suite_provenance(out, results)
    page = tmp_path / "page.md"
    assert main(["report", str(out), "--no-figures", "--page", str(page)]) == 2
    assert "has no seal" in one_line(capsys.readouterr().err)
    assert not page.exists() and not (out / "report").exists()  # stopped before any output


# --- durations ---------------------------------------------------------------------------------


def test_a_negative_stored_duration_is_refused_in_one_line_and_redone(stored, tmp_path, capsys):
    suite, _ = stored
    out = copy_of(stored, tmp_path)
    store = ResultStore(out)
    key = store.keys()[0]
    row = load_results(out).set_index("run_key").loc[key]
    row = {**row.to_dict(), "run_key": key, "run_time_s": -3.5}
    trace = pq.read_table(store.trace_path(key)).to_pandas()
    store.write_run(key, row, trace)  # sealed: intact bytes holding an impossible duration
    assert len(load_results(out)) == RUNS - 1
    line = one_line(capsys.readouterr().err)
    assert f"left out {store.run_path(key)}: holds a negative duration run_time_s=-3.5 s" in line
    assert sweep(suite, out).redo == {"corrupt": 1}
    assert load_results(out)["run_time_s"].min() >= 0
    manifest = read_manifest(store)
    manifest["sessions"][-1]["wall_s"] = -1.25
    write_manifest(store, manifest)
    assert main(["sweep", str(suite), "--out", str(out), "--no-progress"]) == 2
    line = one_line(capsys.readouterr().err)
    assert "has a session with a negative duration wall_s=-1.25 s" in line


# --- files the store does not own --------------------------------------------------------------


def test_files_the_store_does_not_own_are_neither_read_nor_redone(stored, tmp_path, capsys):
    suite, _ = stored
    out = copy_of(stored, tmp_path)
    unrelated = [out / "runs" / "notes.parquet", out / "traces" / "big.parquet"]
    for path in unrelated:
        path.write_bytes(b"not a result of this store")
    leftover = out / "runs" / ".notes.parquet.x1.tmp"  # named like a temporary file, not ours
    leftover.write_bytes(b"mine")
    assert len(load_results(out)) == RUNS
    assert capsys.readouterr().err == ""  # no warning that a sweep would redo them
    summary = sweep(suite, out)
    assert summary.already == RUNS and summary.redo == {}
    for path in [*unrelated, leftover]:
        assert path.exists()


# --- a sweep stopped while two local workers compute --------------------------------------------


@pytest.fixture
def small_tmpfs(tmp_path):
    """A real 64 KiB tmpfs (root only; skipped where it cannot be mounted)."""
    mount_point = tmp_path / "mnt"
    mount_point.mkdir()
    if shutil.which("mount") is None or os.geteuid() != 0:
        pytest.skip("needs root to mount a small file system")
    made = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount_point)], capture_output=True
    )
    if made.returncode != 0:
        pytest.skip("cannot mount a small file system here")
    yield mount_point
    subprocess.run(["umount", "-l", str(mount_point)], check=True)


@pytest.mark.slow
@pytest.mark.parametrize("fault", ["folder deleted", "disk full"])
def test_a_sweep_stopped_under_two_local_workers_is_one_line(tmp_path, request, fault):
    suite = suite_file(tmp_path, seeds=12)
    place = request.getfixturevalue("small_tmpfs") if fault == "disk full" else tmp_path
    out = place / "out"
    proc = subprocess.Popen(
        [*COMMAND, "sweep", str(suite), "--out", str(out), "--no-progress", "--jobs", "2"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        if fault == "folder deleted":
            deadline = time.monotonic() + DEADLINE_S
            while len(list((out / "runs").glob("*.parquet"))) < 2:
                assert proc.poll() is None and time.monotonic() < deadline
                time.sleep(0.01)
            shutil.rmtree(out)  # both workers are computing the next runs
        _, err = proc.communicate(timeout=DEADLINE_S)
    finally:
        proc.kill()
    lines = err.strip().splitlines()
    assert proc.returncode == 2, err
    assert lines[0].startswith("suite store-faults: 24 runs")
    assert len(lines) == 2, err  # the one line, and no warning of joblib's before or after it
    said = "was deleted" if fault == "folder deleted" else f"disk full writing {out}"
    assert lines[1].startswith("formation-bench sweep: error: --out: ") and said in lines[1]


# --- Dask: the scheduler lost, every worker lost -------------------------------------------------


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _dask(*args: str, log: Path) -> subprocess.Popen:
    with open(log, "ab") as handle:
        return subprocess.Popen(
            [sys.executable, "-m", *args], stdout=handle, stderr=handle, start_new_session=True
        )


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, 9)
    proc.wait(timeout=60)


def _scheduler_and_workers(tmp_path: Path) -> tuple[str, subprocess.Popen, subprocess.Popen]:
    address = f"tcp://127.0.0.1:{_free_port()}"
    port = address.rsplit(":", 1)[1]
    scheduler = _dask(
        "distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", port,
        "--no-dashboard", log=tmp_path / "scheduler.log",
    )  # fmt: skip
    workers = _dask(
        "distributed.cli.dask_worker", address, "--nworkers", "2", "--nthreads", "1",
        "--host", "127.0.0.1", "--no-dashboard", log=tmp_path / "workers.log",
    )  # fmt: skip
    from dask.distributed import Client

    with Client(address, timeout="60s") as client:
        client.wait_for_workers(2, timeout=120)
    return address, scheduler, workers


@pytest.mark.slow
def test_a_lost_dask_scheduler_is_one_line_and_the_sweep_resumes(tmp_path):
    pytest.importorskip("dask.distributed")
    suite = suite_file(tmp_path, seeds=12)
    out = tmp_path / "out"
    address, scheduler, workers = _scheduler_and_workers(tmp_path)
    try:
        sweep_proc = subprocess.Popen(
            [*COMMAND, "sweep", str(suite), "--out", str(out), "--no-progress",
             "--scheduler", address],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        deadline = time.monotonic() + DEADLINE_S
        while len(list((out / "runs").glob("*.parquet"))) < 2:
            assert sweep_proc.poll() is None and time.monotonic() < deadline
            time.sleep(0.01)
        _stop(scheduler)
        _, err = sweep_proc.communicate(timeout=DEADLINE_S)
    finally:
        _stop(scheduler)
        _stop(workers)
    lines = err.strip().splitlines()
    assert sweep_proc.returncode == 2, err
    assert len(lines) == 2 and lines[0].startswith("suite store-faults: 24 runs"), err
    kept = len(list((out / "runs").glob("*.parquet")))
    assert lines[1] == (
        f"formation-bench sweep: error: --scheduler: lost the connection to the Dask scheduler "
        f"at {address}; stopped: {kept} of 24 runs in {out}; start the scheduler and its "
        "workers again and run the same command to finish"
    )
    assert "failed" not in err
    address, scheduler, workers = _scheduler_and_workers(tmp_path)
    try:
        again = subprocess.run(
            [*COMMAND, "sweep", str(suite), "--out", str(out), "--no-progress",
             "--scheduler", address],
            capture_output=True, text=True, timeout=DEADLINE_S,
        )  # fmt: skip
    finally:
        _stop(scheduler)
        _stop(workers)
    assert again.returncode == 0, again.stderr
    assert f"{kept} already stored" in again.stderr
    results = load_results(out)
    assert len(results) == 24 and results["run_key"].is_unique


@pytest.mark.slow
def test_a_dask_sweep_without_live_workers_says_it_waits(tmp_path):
    distributed = pytest.importorskip("dask.distributed")
    suite = suite_file(tmp_path)
    out = tmp_path / "out"
    with distributed.LocalCluster(
        n_workers=0, processes=True, dashboard_address=None, host="127.0.0.1"
    ) as cluster:
        proc = subprocess.Popen(
            [*COMMAND, "sweep", str(suite), "--out", str(out), "--no-progress",
             "--scheduler", cluster.scheduler_address, "--worker-timeout", "120"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            said = []
            deadline = time.monotonic() + 60
            while not any("no live Dask worker" in line for line in said):
                assert time.monotonic() < deadline, said
                ready, _, _ = select.select([proc.stderr], [], [], 1.0)
                if ready:
                    said.append(proc.stderr.readline())
            assert proc.poll() is None  # said while it waits
            cluster.scale(1)
            _, rest = proc.communicate(timeout=DEADLINE_S)
        finally:
            proc.kill()
    notice = next(line for line in said if "no live Dask worker" in line).strip()
    assert notice == (
        f"note: no live Dask worker at {cluster.scheduler_address}; waiting up to 120 s "
        "(--worker-timeout) for one, the finished runs stored"
    )
    assert proc.returncode == 0, rest
    assert "a Dask worker is live again" in rest
    assert len(load_results(out)) == RUNS
