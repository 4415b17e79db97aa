"""Faults injected at random moments into sweeps and the commands that write folders.

Each kind of fault is tried a number of times (the trials); the moments and places come from
a seeded generator. Every kind prints one line with its trials, how many survived, how many
runs were lost (stored, then gone; or finished and not stored once the folder is resumed),
silently changed (a stored result whose non-timing columns differ from an undisturbed
reference run) and how many command outputs held a traceback: the target is 0 lost, 0
silently changed, 0 tracebacks, every trial survived.

Garbled store files are tried in ``test_store_integrity.py``.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from formation_bench.cli.main import main
from formation_bench.experiments.suite import parse_suite
from formation_bench.experiments.sweep import run_sweep
from formation_bench.pipeline.record import is_timing_column
from formation_bench.pipeline.staging import staged_folder

ENTROPY = 0x5EED_FA17
SUITE = """\
name = "faults"
seeds = {seeds}
triggers = [true, false]

[[optimizers]]
name = "modified-bso"
overrides = {{ max_iterations = 10 }}

[[scenarios]]
name = "paper"
overrides = {{ n_steps = 30, settle_time_s = 1.0 }}
"""
LARGE_SEEDS, SMALL_SEEDS = 20, 4
"""Runs: twice the seeds (with and without trigger). The large suite is for sweeps killed
from outside, which need runs to interrupt; the small one for faults injected in-process."""
SHORT_RUN = ["--set", "n_steps=25", "--set", "settle_time_s=1.0", "--set", "max_iterations=8"]
COMMAND = [sys.executable, "-m", "formation_bench.cli.main"]
DEADLINE_S = 180.0
REAL_REPLACE = os.replace


def generator(kind: str) -> np.random.Generator:
    """The seeded generator of one kind of fault (each kind its own stream)."""
    return np.random.default_rng(np.random.SeedSequence(ENTROPY, spawn_key=(sum(kind.encode()),)))


# --- counting -----------------------------------------------------------------------------------


@dataclass
class Tally:
    """Trials of one kind of fault and what they did."""

    kind: str
    trials: int = 0
    survived: int = 0
    lost: int = 0
    changed: int = 0
    tracebacks: int = 0

    def add(self, *, ok: bool, lost: int = 0, changed: int = 0, outputs: tuple[str, ...] = ()):
        tracebacks = sum("Traceback" in text for text in outputs)
        self.trials += 1
        self.lost += lost
        self.changed += changed
        self.tracebacks += tracebacks
        self.survived += ok and not (lost or changed or tracebacks)

    def check(self, expected_trials: int) -> None:
        print(
            f"\n{self.kind}: {self.trials} trials, {self.survived} survived, {self.lost} lost, "
            f"{self.changed} silently changed, {self.tracebacks} tracebacks"
        )
        assert self.trials == expected_trials
        assert (self.lost, self.changed, self.tracebacks) == (0, 0, 0), self
        assert self.survived == self.trials, self


# --- the store ---------------------------------------------------------------------------------


def stored_keys(out: Path) -> set[str]:
    runs = out / "runs"
    return {p.stem for p in runs.glob("*.parquet")} if runs.is_dir() else set()


def leftovers(out: Path) -> list[Path]:
    """Temporary files of interrupted writes (the next sweep removes them)."""
    return [p for p in out.rglob(".*.tmp")] if out.is_dir() else []


def deterministic_rows(out: Path) -> dict[str, pd.DataFrame]:
    """Each stored run's row, without the columns that differ between two runs of it."""
    rows = {}
    for key in stored_keys(out):
        frame = pd.read_parquet(out / "runs" / f"{key}.parquet")
        rows[key] = frame[[c for c in frame.columns if not is_timing_column(c)]]
    return rows


def changed_rows(out: Path, reference: dict[str, pd.DataFrame], keys: set[str] | None = None):
    """How many stored runs (of ``keys``, default all) differ from the reference run."""
    got = deterministic_rows(out)
    wanted = got.keys() if keys is None else keys & got.keys()
    return sum(not got[key].equals(reference[key]) for key in wanted)


def suite_file(folder: Path, seeds: int) -> Path:
    path = folder / f"faults{seeds}.toml"
    path.write_text(SUITE.format(seeds=seeds))
    return path


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> tuple[Path, dict[str, pd.DataFrame], Path]:
    """The small suite's file, its undisturbed reference rows and folder."""
    folder = tmp_path_factory.mktemp("small")
    path = suite_file(folder, SMALL_SEEDS)
    reference = folder / "reference"
    run_sweep(parse_suite(path.read_text(), path), reference, jobs=1, progress=False,
              log=lambda _: None)  # fmt: skip
    return path, deterministic_rows(reference), reference


@pytest.fixture(scope="module")
def large(tmp_path_factory) -> tuple[Path, dict[str, pd.DataFrame]]:
    folder = tmp_path_factory.mktemp("large")
    path = suite_file(folder, LARGE_SEEDS)
    reference = folder / "reference"
    run_sweep(parse_suite(path.read_text(), path), reference, jobs=1, progress=False,
              log=lambda _: None)  # fmt: skip
    return path, deterministic_rows(reference)


# --- processes -----------------------------------------------------------------------------------


def start(args: list[str], log: Path) -> subprocess.Popen:
    with open(log, "ab") as handle:
        return subprocess.Popen(
            [*COMMAND, *args], stdout=handle, stderr=handle, start_new_session=True
        )


def wait_until(condition: Callable[[], bool], proc: subprocess.Popen | None = None) -> bool:
    """Poll ``condition`` until it holds (True) or ``proc`` ends (False), within the deadline."""
    deadline = time.monotonic() + DEADLINE_S
    while not condition():
        if proc is not None and proc.poll() is not None:
            return False
        assert time.monotonic() < deadline, "no progress in time"
        time.sleep(0.005)
    return True


def pause(proc: subprocess.Popen, seconds: float) -> None:
    """Let ``proc`` go on for ``seconds`` (the random moment of a fault), or until it ends."""
    try:
        proc.wait(timeout=seconds)
    except subprocess.TimeoutExpired:
        pass


def kill_group(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait(timeout=60)


def last_line(text: str) -> str:
    lines = text.strip().splitlines()
    return lines[-1] if lines else ""


# --- injected write failures --------------------------------------------------------------------


class WritesInto:
    """``os.replace`` and ``os.rename`` (the last step of every store and output write) that
    count the files and folders put in place under ``folder`` and, at the ``after``-th (and
    on, unless ``once``), call ``fault(src, dst)`` instead, which may do the write itself."""

    def __init__(
        self, folder: Path, after: int, fault: Callable[[str, str], None], once: bool = False
    ) -> None:
        self.folder, self.after, self.fault, self.once = str(folder), after, fault, once
        self.done = 0

    def __call__(self, src, dst, *args, **kwargs) -> None:
        if not str(dst).startswith(self.folder):
            return REAL_REPLACE(src, dst, *args, **kwargs)
        self.done += 1
        if self.done - 1 == self.after or (self.done - 1 > self.after and not self.once):
            return self.fault(src, dst)
        return REAL_REPLACE(src, dst, *args, **kwargs)


def refuse(code: int) -> Callable[[str, str], None]:
    def fault(src: str, dst: str) -> None:
        raise OSError(code, os.strerror(code), dst)

    return fault


@contextlib.contextmanager
def injected(monkeypatch, writes: WritesInto) -> Iterator[WritesInto]:
    with monkeypatch.context() as patch:
        patch.setattr(os, "replace", writes)
        patch.setattr(os, "rename", writes)  # Path.rename: a staged folder put in place
        yield writes


def sweep_args(suite: Path, out: Path, *extra: str) -> list[str]:
    return ["sweep", str(suite), "--out", str(out), "--no-progress", *extra]


# --- in-process faults (quick) -------------------------------------------------------------------


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS], ids=["disk-full", "read-only"])
@pytest.mark.slow
def test_a_refused_write_stops_a_sweep_in_one_line_and_it_resumes(
    small, tmp_path, monkeypatch, capsys, code
):
    suite, reference, _ = small
    rng = generator(f"refused-{code}")
    tally = Tally(f"sweep, injected {errno.errorcode[code]} from a random write on")
    trials = 4
    for trial in range(trials):
        out = tmp_path / f"trial{trial}"
        # write 0 is the manifest, then one per run, then the manifest again
        after = int(rng.integers(0, 2 * SMALL_SEEDS + 2))
        with injected(monkeypatch, WritesInto(out, after, refuse(code))):
            stopped = main([*sweep_args(suite, out), "--jobs", "1"])
        first = capsys.readouterr().err
        kept = stored_keys(out)
        line = last_line(first)
        counted = f"; {len(kept)} of {2 * SMALL_SEEDS} runs stored in {out} and intact; "
        ok = (
            stopped == 2
            and line.startswith(f"formation-bench sweep: error: --out: {os.strerror(code)}")
            is False  # the message is the project's, not the system's
            and line.startswith("formation-bench sweep: error: --out: ")
            and f" writing {out}" in line
            and counted in line
            and not leftovers(out)
        )
        resumed = main([*sweep_args(suite, out), "--jobs", "1"])
        second = capsys.readouterr().err
        final = stored_keys(out)
        lost = len(kept - final) + len(reference.keys() - final)
        tally.add(
            ok=ok and resumed == 0 and f"{len(kept)} already stored" in second,
            lost=lost,
            changed=changed_rows(out, reference),
            outputs=(first, second),
        )
    tally.check(trials)


def _delete(folder: Path, *, mid_write: bool) -> Callable[[str, str], None]:
    def fault(src: str, dst: str) -> None:
        if mid_write:  # the folder goes while a file is on its way in
            shutil.rmtree(folder)
        REAL_REPLACE(src, dst)
        if not mid_write:
            shutil.rmtree(folder)

    return fault


@pytest.mark.slow
def test_a_folder_or_lock_taken_away_mid_sweep_stops_it_without_recreating(
    small, tmp_path, monkeypatch, capsys
):
    suite, reference, _ = small
    rng = generator("vanish")
    tally = Tally("sweep, results folder deleted, moved or lock file deleted in-process")
    kinds = ["deleted", "deleted", "moved", "moved", "lock", "lock"]
    for trial, kind in enumerate(kinds):
        out = tmp_path / f"trial{trial}"
        moved = tmp_path / f"moved{trial}"
        after = int(rng.integers(1, 2 * SMALL_SEEDS))  # between the first and the last run
        mid_write = bool(rng.integers(0, 2))
        if kind == "deleted":
            fault = _delete(out, mid_write=mid_write)
        elif kind == "moved":

            def fault(src: str, dst: str, out=out, moved=moved) -> None:
                REAL_REPLACE(src, dst)
                out.rename(moved)
        else:

            def fault(src: str, dst: str, out=out) -> None:
                REAL_REPLACE(src, dst)
                (out / ".lock").unlink()

        writes = WritesInto(out, after, fault, once=True)
        with injected(monkeypatch, writes):
            stopped = main([*sweep_args(suite, out), "--jobs", "1"])
        first = capsys.readouterr().err
        line = last_line(first)
        ok = stopped == 2 and line.startswith("formation-bench sweep: error: --out: ")
        lost = 0
        if kind == "deleted":
            ok = ok and "was deleted while the sweep ran" in line and not out.exists()
            resumed = main([*sweep_args(suite, out), "--jobs", "1"])
            home = out
        elif kind == "moved":
            ok = ok and f"moved to {moved}" in line and not out.exists()
            ok = ok and "0 of" in line  # counted from the (empty) place it was
            resumed = main([*sweep_args(suite, moved), "--jobs", "1"])
            home = moved
        else:
            ok = ok and "lock file" in line and out.is_dir()
            kept = stored_keys(out)
            resumed = main([*sweep_args(suite, out), "--jobs", "1"])
            lost = len(kept - stored_keys(out))
            home = out
        second = capsys.readouterr().err
        lost += len(reference.keys() - stored_keys(home))
        tally.add(
            ok=ok and resumed == 0,
            lost=lost,
            changed=changed_rows(home, reference),
            outputs=(first, second),
        )
    tally.check(len(kinds))


COMMANDS = {
    "run": ["run", "--optimizer", "modified-bso", *SHORT_RUN, "--no-figures"],
    "score": ["score", "--optimizer", "modified-bso", "--budgets", "40", "--seeds", "0", "1",
              "--jobs", "1"],
    "report": ["report", "{results}", "--no-figures"],
    "reproduce": ["reproduce", "--no-figures"],
}  # fmt: skip
WRITES = {"run": 3, "score": 2, "report": 1, "reproduce": 3}
"""Files (or, for a staged folder, the folder itself) each command puts in place."""


@pytest.mark.parametrize(
    "command", ["report", pytest.param("reproduce", marks=pytest.mark.slow), "run", "score"]
)
def test_a_full_disk_in_a_command_is_one_line_and_leaves_nothing_half_written(
    small, tmp_path, monkeypatch, capsys, command
):
    _, _, results = small
    rng = generator(f"full-{command}")
    tally = Tally(f"{command}, injected ENOSPC from a random write on")
    trials = 2
    for trial in range(trials):
        place = tmp_path / f"trial{trial}"
        place.mkdir()
        out = place / "out"
        args = [a.format(results=results) for a in COMMANDS[command]] + ["--out", str(out)]
        after = int(rng.integers(0, WRITES[command]))
        with injected(monkeypatch, WritesInto(place, after, refuse(errno.ENOSPC))):
            stopped = main(args)
        first = capsys.readouterr().err
        line = last_line(first)
        ok = (
            stopped == 2
            and line.startswith(f"formation-bench {command}: error: --out")
            and f"disk full writing {out}" in line
            and "run the same command again when there is room" in line
            and not list(place.glob(".out.*"))  # no staging folder, no temporary file
            and not leftovers(out)
        )
        kept: set[str] = set()
        if command == "score":
            kept = {p.stem for p in (out / "score").glob("*.parquet")}
            ok = ok and f"; {len(kept)} of 2 score runs stored" in line
        else:
            ok = ok and not out.exists()
        again = main(args)
        second = capsys.readouterr().err
        lost = len(kept - {p.stem for p in (out / "score").glob("*.parquet")})
        tally.add(ok=ok and again == 0, lost=lost, outputs=(first, second))
    tally.check(trials)


def test_report_into_a_folder_another_command_is_writing_is_refused(small, tmp_path, capsys):
    _, _, results = small
    out = tmp_path / "report"
    with staged_folder(out, overwrite=False) as staging:  # another command, still writing
        (staging / "report.md").write_text("first\n")
        assert main(["report", str(results), "--out", str(out), "--no-figures"]) == 2
        err = capsys.readouterr().err
        assert last_line(err).startswith(
            f"formation-bench report: error: --out {out}: another command (pid {os.getpid()}) "
            "is writing it now"
        )
        assert len(err.strip().splitlines()) == 1
    # the first one's output is there, unreplaced
    assert (out / "report.md").read_text() == "first\n"


def test_two_commands_into_one_new_folder_do_not_replace_each_other(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(ValueError, match="another command wrote this folder while this one ran"):
        with staged_folder(out, overwrite=False) as staging:
            (staging / "mine.txt").write_text("second")
            out.mkdir()
            (out / "theirs.txt").write_text("first")
    assert [p.name for p in out.iterdir()] == ["theirs.txt"]
    assert not list(tmp_path.glob(".out.*"))


def test_partial_folders_of_dead_commands_are_removed_and_a_broken_link_is_one_line(
    tmp_path, capsys
):
    out = tmp_path / "out"
    dead = [tmp_path / ".out.4194305.abcd1234.partial", tmp_path / ".out.k2j3h4g5.partial"]
    other = tmp_path / ".out.b.77.abcd1234.partial"  # the folder of --out out.b: kept
    for folder in (*dead, other):
        folder.mkdir()
        (folder / "metrics.json").write_text("{}")
    with staged_folder(out, overwrite=False) as staging:
        (staging / "x").write_text("x")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["out", other.name])
    link = tmp_path / "link"
    link.symlink_to(tmp_path / "nowhere")
    assert main(["run", "--optimizer", "modified-bso", "--out", str(link)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == (
        f"formation-bench run: error: --out {link}: is a broken symbolic link (to "
        f"{tmp_path / 'nowhere'}); remove it or choose another folder"
    )


# --- processes killed from outside (slow) ---------------------------------------------------------


@pytest.mark.slow
def test_sigkill_at_random_moments_then_resume(large, tmp_path):
    """Ten sweeps into one folder, each SIGKILLed at a random moment after it stored a new
    run; each next sweep resumes the last, and a final one finishes it."""
    suite, reference = large
    rng = generator("sigkill")
    out, log = tmp_path / "killed", tmp_path / "sweep.log"
    tally = Tally("sweep, SIGKILL at a random moment then resume")
    trials = 10
    for _ in range(trials):
        before = stored_keys(out)
        offset = log.stat().st_size if log.exists() else 0
        # one job: the moment of the kill, not starting workers, is what is tried here
        # (test_sweep_kill.py kills a sweep with workers)
        proc = start([*sweep_args(suite, out), "--jobs", "1"], log)
        try:
            wait_until(lambda: len(stored_keys(out)) > len(before), proc)  # noqa: B023
            pause(proc, float(rng.uniform(0.0, 0.3)))
        finally:
            kill_group(proc)
        after = stored_keys(out)
        output = log.read_bytes()[offset:].decode(errors="replace")
        tally.add(
            ok=proc.returncode in (-signal.SIGKILL, 0) and after >= before,
            lost=len(before - after),
            changed=changed_rows(out, reference, after - before),
            outputs=(output,),
        )
    kept = stored_keys(out)
    final = subprocess.run(
        [*COMMAND, *sweep_args(suite, out)], capture_output=True, text=True, timeout=DEADLINE_S
    )
    assert final.returncode == 0, final.stderr
    assert f"{len(kept)} already stored" in final.stderr and "Traceback" not in final.stderr
    assert stored_keys(out) == reference.keys() and not leftovers(out)
    assert changed_rows(out, reference) == 0
    tally.check(trials)


@pytest.mark.slow
def test_a_folder_taken_away_from_a_running_sweep_process(large, tmp_path):
    """The folder deleted or moved, or its lock file deleted and a second sweep started,
    while a sweep process runs: it stops at its next write, recreates nothing, and the
    second sweep finishes alone."""
    suite, reference = large
    rng = generator("vanish-process")
    tally = Tally("sweep process, results folder deleted, moved or lock deleted")
    kinds = ["deleted", "moved", "lock"]
    for trial, kind in enumerate(kinds):
        out, moved, log = tmp_path / f"out{trial}", tmp_path / f"moved{trial}", tmp_path / "log"
        log.write_bytes(b"")
        proc = start([*sweep_args(suite, out), "--jobs", "1"], log)
        second = None
        try:
            at = int(rng.integers(1, 8))
            wait_until(lambda: len(stored_keys(out)) >= at, proc)  # noqa: B023
            if kind == "deleted":
                shutil.rmtree(out)
            elif kind == "moved":
                out.rename(moved)
            else:
                kept = stored_keys(out)
                (out / ".lock").unlink()
                second = subprocess.Popen(
                    [*COMMAND, *sweep_args(suite, out), "--jobs", "1"],
                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                )  # fmt: skip
            proc.wait(timeout=DEADLINE_S)
        finally:
            kill_group(proc)
        output = log.read_text()
        line = last_line(output)
        ok = proc.returncode == 2 and line.startswith("formation-bench sweep: error: --out: ")
        outputs: tuple[str, ...] = (output,)
        lost = 0
        if kind == "deleted":
            ok = ok and "was deleted while the sweep ran" in line and not out.exists()
            home = None
        elif kind == "moved":
            ok = ok and f"moved to {moved}" in line and not out.exists()
            home = moved
        else:
            assert second is not None
            _, second_err = second.communicate(timeout=DEADLINE_S)
            outputs += (second_err,)
            ok = ok and "lock file" in line and second.returncode == 0
            lost = len(kept - stored_keys(out)) + len(reference.keys() - stored_keys(out))
            home = out
        changed = changed_rows(home, reference) if home is not None else 0
        tally.add(ok=ok, lost=lost, changed=changed, outputs=outputs)
    tally.check(len(kinds))


STAGED = {
    "run": ["run", "--optimizer", "modified-bso", *SHORT_RUN, "--no-figures"],
    "reproduce": ["reproduce", "--no-figures"],
    "report": ["report", "{results}", "--no-figures"],
}
PAUSE_S = {"run": 0.3, "reproduce": 1.0, "report": 0.3}
"""The longest random wait before the kill: about a third of the command's own time (from its
partial folder on: a report of the small results puts its folder in place about 0.4 s later)."""


@pytest.mark.slow
@pytest.mark.parametrize("command", sorted(STAGED))
def test_a_killed_command_leaves_a_partial_folder_the_next_one_removes(
    small, tmp_path, capsys, command
):
    _, _, results = small
    rng = generator(f"partial-{command}")
    tally = Tally(f"{command}, SIGKILL at a random moment then the same command")
    args = [a.format(results=results) for a in STAGED[command]]
    reference_out = tmp_path / "reference"
    assert main([*args, "--out", str(reference_out)]) == 0
    capsys.readouterr()
    trials, partials = 2, 0
    for trial in range(trials):
        place = tmp_path / f"trial{trial}"
        place.mkdir()
        out, log = place / "out", place / "log"
        proc = start([*args, "--out", str(out)], log)
        try:
            started = wait_until(lambda: any(place.glob(".out.*.partial")), proc)  # noqa: B023
            pause(proc, float(rng.uniform(0.0, PAUSE_S[command])))
        finally:
            kill_group(proc)
        left = sorted(p.name for p in place.glob(".out.*"))
        again = main([*args, "--out", str(out), "--overwrite"])  # it may have finished
        err = capsys.readouterr().err
        ok = (
            started
            and again == 0
            and not list(place.glob(".out.*"))  # what the killed one left is gone
            and out.is_dir()
        )
        changed = 0
        if command != "report":
            changed = int(_metrics(out) != _metrics(reference_out))
        partials += bool(left)
        tally.add(ok=ok, changed=changed, outputs=(log.read_text(), err))
    print(f"\n{command}: {partials} of {trials} killed commands left a partial folder")
    assert partials > 0  # else nothing was tried
    tally.check(trials)


def _metrics(folder: Path) -> list[dict]:
    return [
        {k: v for k, v in record.items() if not is_timing_column(k)}
        for record in json.loads((folder / "metrics.json").read_text())
    ]


@pytest.mark.slow
def test_a_killed_dask_worker_loses_and_changes_nothing(large, tmp_path, capsys):
    distributed = pytest.importorskip("dask.distributed")
    suite, reference = large
    rng = generator("dask-worker")
    tally = Tally("dask sweep, a worker SIGKILLed at a random moment")
    trials = 3
    with (
        distributed.LocalCluster(
            n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
            host="127.0.0.1",
        ) as cluster,
        distributed.Client(cluster) as client,
    ):  # fmt: skip
        for trial in range(trials):
            out = tmp_path / f"trial{trial}"
            at = int(rng.integers(1, len(reference) - 4))
            victim = int(rng.integers(0, 2))
            client.wait_for_workers(2, timeout=60)  # the nanny restarted the last one killed
            pids = sorted(client.run(os.getpid).values())
            done = threading.Event()

            killed: list[int] = []

            def kill(out=out, at=at, pid=pids[victim], done=done, killed=killed) -> None:
                while len(stored_keys(out)) < at:
                    if done.wait(0.005):
                        return
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)

            thread = threading.Thread(target=kill, daemon=True)
            thread.start()
            try:
                first = main([*sweep_args(suite, out), "--scheduler", cluster.scheduler_address])
            finally:
                done.set()
                thread.join(timeout=60)
            first_err = capsys.readouterr().err
            kept = stored_keys(out)
            # a run on a worker killed too often is reported failed and left for the next sweep
            again = main([*sweep_args(suite, out), "--scheduler", cluster.scheduler_address])
            second_err = capsys.readouterr().err
            final = stored_keys(out)
            tally.add(
                ok=bool(killed) and first in (0, 1) and again == 0,
                lost=len(kept - final) + len(reference.keys() - final),
                changed=changed_rows(out, reference),
                outputs=(first_err, second_err),
            )
    tally.check(trials)


@contextlib.contextmanager
def small_file_system(mount_point: Path, size: str) -> Iterator[Path]:
    """A real tmpfs of ``size`` at ``mount_point`` (root only; skipped where it cannot be
    mounted)."""
    mount_point.mkdir()
    made = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mount_point)],
        capture_output=True,
    )
    if made.returncode != 0:
        pytest.skip("cannot mount a small file system here (needs root)")
    try:
        yield mount_point
    finally:
        subprocess.run(["umount", "-l", str(mount_point)], check=True)


def remount(mount_point: Path, options: str) -> None:
    subprocess.run(["mount", "-o", f"remount,{options}", str(mount_point)], check=True)


@pytest.mark.skipif(shutil.which("mount") is None or os.geteuid() != 0, reason="needs root")
def test_a_real_full_then_read_only_file_system(small, tmp_path, capsys):
    """A tmpfs too small for the suite, then grown, then remounted read-only."""
    suite, reference, _ = small
    full = Tally("sweep into a real full tmpfs, then grown")
    read_only = Tally("sweep resumed into a real read-only tmpfs")
    with small_file_system(tmp_path / "mnt", "64k") as mount_point:
        out = mount_point / "results"
        stopped = main([*sweep_args(suite, out), "--jobs", "1"])
        first = capsys.readouterr().err
        line, kept = last_line(first), stored_keys(out)
        ok = (
            stopped == 2
            and line.startswith(f"formation-bench sweep: error: --out: disk full writing {out}")
            and f"; {len(kept)} of {2 * SMALL_SEEDS} runs stored in {out} and intact; " in line
            and len(kept) < len(reference)
            and not leftovers(out)
        )
        remount(mount_point, "size=4m")  # "when there is room"
        resumed = main([*sweep_args(suite, out), "--jobs", "1"])
        second = capsys.readouterr().err
        final = stored_keys(out)
        full.add(
            ok=ok and resumed == 0,
            lost=len(kept - final) + len(reference.keys() - final),
            changed=changed_rows(out, reference),
            outputs=(first, second),
        )
        (out / "runs" / f"{sorted(final)[0]}.parquet").unlink()  # one run left to do
        remount(mount_point, "ro")
        refused = main([*sweep_args(suite, out), "--jobs", "1"])
        third = capsys.readouterr().err
        read_only.add(
            ok=refused == 2
            and len(third.strip().splitlines()) == 1
            and "not writable" in third
            and stored_keys(out) == final - {sorted(final)[0]},
            changed=changed_rows(out, reference),
            outputs=(third,),
        )
        remount(mount_point, "rw")
    full.check(1)
    read_only.check(1)
