"""A sweep killed with SIGKILL (or stopped with Ctrl-C) mid-way resumes to the same results."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import psutil
import pytest

from formation_bench.experiments.store import load_results
from formation_bench.experiments.suite import load_suite
from formation_bench.experiments.sweep import run_sweep
from formation_bench.pipeline.record import is_timing_column

SUITE = """\
name = "kill"
seeds = 12
triggers = [true, false]

[[optimizers]]
name = "modified-bso"
overrides = { max_iterations = 10 }

[[scenarios]]
name = "paper"
overrides = { n_steps = 30, settle_time_s = 1.0 }
"""
TOTAL = 24
ROOT = Path(__file__).resolve().parent.parent


def deterministic(frame: pd.DataFrame) -> pd.DataFrame:
    keep = [c for c in frame.columns if not is_timing_column(c)]
    return frame[keep].sort_values("run_key").reset_index(drop=True)


def stored(out: Path) -> int:
    runs = out / "runs"
    return len(list(runs.glob("*.parquet"))) if runs.is_dir() else 0


def start_sweep(suite: Path, out: Path, log: Path) -> subprocess.Popen:
    with open(log, "ab") as handle:
        return subprocess.Popen(
            [sys.executable, "-m", "formation_bench.cli", "sweep", str(suite), "--out", str(out)],
            stdout=handle,
            stderr=handle,
            cwd=ROOT,
            start_new_session=True,  # its own process group, as a terminal job would be
        )


def wait_for_results(proc: subprocess.Popen, out: Path, at_least: int, timeout: float = 180):
    """Poll the results folder until ``at_least`` runs are stored (the process must still run)."""
    deadline = time.monotonic() + timeout
    while stored(out) < at_least:
        assert proc.poll() is None, f"sweep ended early with {proc.returncode}"
        assert time.monotonic() < deadline, "no results in time"
        time.sleep(0.005)


def kill_group(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


@pytest.fixture
def suite_file(tmp_path):
    path = tmp_path / "kill.toml"
    path.write_text(SUITE)
    return path


@pytest.mark.slow
def test_sigkill_then_resume_gives_every_run_once_and_identical_metrics(suite_file, tmp_path):
    out, log = tmp_path / "killed", tmp_path / "sweep.log"
    proc = start_sweep(suite_file, out, log)
    try:
        wait_for_results(proc, out, 3)
        workers = psutil.Process(proc.pid).children(recursive=True)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
        assert proc.returncode == -signal.SIGKILL
        # the workers die with the sweep (no orphan keeps computing)
        _, alive = psutil.wait_procs(workers, timeout=30)
        assert not alive
    finally:
        kill_group(proc)
    after_kill = stored(out)
    assert 0 < after_kill < TOTAL

    resumed = subprocess.run(
        [sys.executable, "-m", "formation_bench.cli", "sweep", str(suite_file), "--out", str(out)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    assert resumed.returncode == 0, resumed.stderr
    assert f"{after_kill} already stored" in resumed.stderr

    reference = tmp_path / "uninterrupted"
    run_sweep(load_suite(str(suite_file)), reference, jobs=1, progress=False, log=lambda _: None)
    expected = deterministic(load_results(reference))
    got = load_results(out, strict=True)
    assert len(got) == TOTAL and got["run_key"].is_unique
    assert sorted(p.stem for p in (out / "runs").iterdir()) == sorted(expected["run_key"])
    assert not list((out / "runs").glob(".*"))
    pd.testing.assert_frame_equal(deterministic(got), expected, check_exact=True)


@pytest.mark.slow
def test_ctrl_c_stops_cleanly_and_leaves_a_resumable_folder(suite_file, tmp_path):
    out, log = tmp_path / "interrupted", tmp_path / "sweep.log"
    proc = start_sweep(suite_file, out, log)
    try:
        wait_for_results(proc, out, 2)
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C reaches the whole foreground group
        proc.wait(timeout=60)
    finally:
        kill_group(proc)
    text = log.read_text()
    assert proc.returncode == 130, text
    assert "interrupted:" in text and "run the same command again" in text
    assert "Traceback" not in text
    assert 0 < stored(out) < TOTAL
    state = load_results(out, strict=True)
    assert state["run_key"].is_unique


@pytest.mark.slow
def test_ctrl_c_at_random_moments_even_twice_exits_130_in_one_line(suite_file, tmp_path):
    """Ctrl-C while the sweep imports, starts its workers or runs, and a second Ctrl-C
    during the clean-up of the first: always exit 130, one line, no traceback."""
    rng = np.random.default_rng(np.random.SeedSequence(0xC7C))
    # long enough that the sweep is still running at the latest moment drawn (3 s), with a
    # wide margin: 120 runs of this suite took 2.3 s on a warm 2-core machine, and the suite
    # is interrupted anyway, so its length costs nothing
    long_suite = tmp_path / "long.toml"
    long_suite.write_text(SUITE.replace("seeds = 12", "seeds = 600"))
    trials = 4
    for trial in range(trials):
        out, log = tmp_path / f"out{trial}", tmp_path / f"sweep{trial}.log"
        proc = start_sweep(long_suite, out, log)
        try:
            try:
                proc.wait(timeout=float(rng.uniform(0.3, 3.0)))  # the random moment
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGINT)
            else:
                pytest.fail(f"the sweep ended before it was interrupted: {log.read_text()}")
            try:
                proc.wait(timeout=float(rng.uniform(0.0, 0.3)))
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGINT)  # the second, during the clean-up
            proc.wait(timeout=60)
        finally:
            kill_group(proc)
        text = log.read_text()
        assert proc.returncode == 130, text
        assert "Traceback" not in text, text
        assert "interrupted" in text.strip().splitlines()[-1]
        if stored(out):
            assert load_results(out, strict=True)["run_key"].is_unique
