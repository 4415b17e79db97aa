"""Ctrl-C at any moment: never a death by signal, and nothing half-written that looks finished.

A Ctrl-C whose handler raised inside numba's boxing of a compiled function's result (its
first return, in a run's first second or two) lost the interrupt and handed Python a tuple
holding NULL: a segmentation fault when it was read, or, when the interrupt surfaced later,
an exit by SIGINT (-2) after the command's one line.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from formation_bench.experiments.store import load_results
from formation_bench.experiments.suite import load_suite
from formation_bench.experiments.sweep import run_sweep
from formation_bench.pipeline.record import Provenance, is_timing_column

ROOT = Path(__file__).resolve().parent.parent


PRESSED_INSIDE = """
signal.signal(signal.SIGINT, {handler})
pressed = []

def press(frame, event, arg):
    if event == "call" and frame.f_code is {target} and not pressed:
        pressed.append(frame)
        {handler}(signal.SIGINT, frame)

try:
    sys.setprofile(press)
    try:
        result = {call}
    finally:
        sys.setprofile(None)
    print({report}, flush=True)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        pass
    print("never interrupted", flush=True)
except BaseException as err:
    print("raised", type(err).__name__, flush=True)
"""
"""A script's end that presses Ctrl-C (``handler`` taking the signal) the first time Python
enters the function whose code is ``target`` during ``call`` (a profile hook standing in for
the signal, so that the moment is exact), prints ``report`` if the call returns, and then
waits for the interrupt."""


def printed_when_pressed_inside(
    setup: str, target: str, call: str, report: str, handler: str = "raise_interrupt"
) -> list[str]:
    """What the script ``setup`` + :data:`PRESSED_INSIDE` prints, run in a new process that
    must end by itself (no death by a signal) and print nothing on its standard error."""
    script = textwrap.dedent(setup) + PRESSED_INSIDE.format(
        target=target, call=call, report=report, handler=handler
    )
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stderr == ""
    return done.stdout.splitlines()


@pytest.mark.parametrize("handler", ["raise_interrupt", "_interrupt_once"])
def test_ctrl_c_inside_a_weakref_callback_is_raised_again_after_python_discards_it(handler):
    # Python prints and discards an exception raised in a weakref callback (importlib frees
    # each module lock through one, so an import can land a Ctrl-C there): it was lost, and
    # the command ran on to its end
    setup = """
        import signal, sys, time, weakref
        from formation_bench.pipeline.interrupts import raise_interrupt
        from formation_bench.cli.main import _interrupt_once

        class Thing:
            pass

        def forgotten(ref):
            pass

        def make_and_forget():
            thing = Thing()
            ref = weakref.ref(thing, forgotten)
            del thing
            return ref() is None
    """
    printed = printed_when_pressed_inside(
        setup, "forgotten.__code__", "make_and_forget()", '"forgotten", result', handler
    )
    assert printed == ["forgotten True", "raised KeyboardInterrupt"]


@pytest.mark.slow
def test_ctrl_c_inside_numbas_boxing_is_raised_after_the_call_returns():
    # inside numba's callback that fetches an array's type while boxing a compiled
    # function's first result
    setup = """
        import signal, sys, time
        import numpy as np
        from numba import njit
        import numba.core.serialize as serialize
        from formation_bench.pipeline.interrupts import raise_interrupt

        @njit
        def pair(n):
            return np.zeros(n), np.ones(n)

        pair.compile("(int64,)")
    """
    printed = printed_when_pressed_inside(
        setup, "serialize._numba_unpickle.__code__", "pair(3)",
        '"sums", [float(a.sum()) for a in result]',
    )  # fmt: skip
    assert printed == ["sums [0.0, 3.0]", "raised KeyboardInterrupt"]


@pytest.mark.slow
@pytest.mark.parametrize(
    "target",
    # numba's own casts, and what numpy runs in Python the first time a bit generator's ctypes
    # interface is asked for (a new Generator: every solve's)
    ["ctypes.cast", "ctypes.CFUNCTYPE", "numpy.random._common.interface.__new__"],
)
def test_ctrl_c_inside_numbas_unboxing_of_a_generator_is_raised_after_the_call_returns(target):
    # numba unboxes a numpy Generator through its bit generator's ctypes interface and reads
    # what each Python call returned without checking it: a Ctrl-C raised inside one crashed
    # a run's first draw of standard normals (population.standard_normals)
    setup = """
        import ctypes, signal, sys, time
        import numpy as np
        import numpy.random._common
        from numba import njit
        from formation_bench.pipeline.interrupts import raise_interrupt

        @njit
        def normals(rng, out):
            for i in range(out.shape[0]):
                out[i] = rng.standard_normal()
            return out

        normals(np.random.default_rng(0), np.empty(4))
    """
    printed = printed_when_pressed_inside(
        setup, f"{target}.__code__", "normals(np.random.default_rng(1), np.empty(4))",
        '"drawn", bool(np.isfinite(result).all()), len(pressed)',
    )  # fmt: skip
    assert printed == ["drawn True 1", "raised KeyboardInterrupt"]


SUITE = """\
name = "interrupted"
seeds = 30
triggers = [false]

[[optimizers]]
name = "modified-bso"
overrides = { max_iterations = 5 }

[[scenarios]]
name = "paper"
overrides = { n_steps = 20, settle_time_s = 1.0 }
"""
INTERRUPTED = 100
"""Commands interrupted (reproduce and sweep alternately, two at a time: CI has two cores);
those that end before their Ctrl-C do not count."""
MOST_TRIALS = 300
"""Commands started at most, finished ones included."""
LATEST_S = 3.0
"""The latest moment a Ctrl-C is pressed after a command starts: a warm reproduce ends in
2.5-4 s on a 2-core machine, so some finish first and the rest are caught in their imports,
their compiled kernels or their writes."""


PROVENANCE = {field.name for field in dataclasses.fields(Provenance)}
"""Columns that say where and with what code a run ran (the same for every trial)."""


def deterministic(frame: pd.DataFrame) -> pd.DataFrame:
    keep = [c for c in frame.columns if not is_timing_column(c) and c not in PROVENANCE]
    return frame[keep].sort_values("run_key").reset_index(drop=True)


def paper_metrics(folder: Path) -> list[dict]:
    """The reproduce records without what differs between two runs (times, machine, code)."""
    records = json.loads((folder / "metrics.json").read_text())
    return [
        {k: v for k, v in r.items() if not is_timing_column(k) and k not in PROVENANCE}
        for r in records
    ]


def command(args: list[str]) -> list[str]:
    # faulthandler: a crash prints where Python was, into the trial's log
    return [sys.executable, "-X", "faulthandler", "-m", "formation_bench.cli", *args]


@dataclass
class Trial:
    """One command, and the moments (seconds after its start) Ctrl-C is pressed on it."""

    number: int
    out: Path
    args: list[str]
    presses: list[float]
    log: Path
    process: subprocess.Popen | None = None

    @property
    def sweep(self) -> bool:
        return self.args[0] == "sweep"

    def start(self) -> None:
        with open(self.log, "wb") as handle:
            self.process = subprocess.Popen(
                command(self.args), stdout=handle, stderr=handle, cwd=ROOT,
                start_new_session=True,  # its own process group, as a terminal job's
                # a test runner started in the background ignores SIGINT, which a child
                # inherits: the default back, so Python turns Ctrl-C into KeyboardInterrupt
                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
            )  # fmt: skip
        started = time.monotonic()
        self.presses = [started + moment for moment in self.presses]

    def press_when_due(self) -> None:
        """Ctrl-C (to the whole group, as a terminal sends it) once its moment has come."""
        assert self.process is not None
        while self.presses and time.monotonic() >= self.presses[0]:
            self.presses.pop(0)
            if self.process.poll() is None:
                os.killpg(self.process.pid, signal.SIGINT)


def trials(tmp_path: Path, suite: Path, lane: int, rng: np.random.Generator) -> Iterator[Trial]:
    """A lane's trials: reproduce and sweep alternately; a sweep folder is resumed and
    interrupted five times, then a new one starts."""
    for k in itertools.count():
        number = 2 * k + lane
        presses = [float(rng.uniform(0.2, LATEST_S))]
        if rng.random() < 0.2:  # pressed twice, the second during the first one's clean-up
            presses.append(presses[0] + float(rng.uniform(0.0, 0.3)))
        if k % 2 == 0:
            out = tmp_path / f"paper{number}"
            args = ["reproduce", "--no-figures", "--out", str(out)]
        else:
            out = tmp_path / f"swept{lane}-{k // 10}"
            jobs = "2" if k % 10 == 1 else "1"
            args = ["sweep", str(suite), "--out", str(out), "--jobs", jobs]
        yield Trial(number, out, args, presses, tmp_path / f"trial{number}.log")


def check(trial: Trial, tmp_path: Path, expected_rows: pd.DataFrame, expected_paper: list) -> int:
    """The trial's exit code, after checking it ended well and left what it should."""
    assert trial.process is not None
    code = trial.process.returncode
    text = trial.log.read_text(errors="replace")
    assert code in (0, 130), f"trial {trial.number}: exit {code}\n{text[-3000:]}"
    assert "Traceback" not in text and "Fatal Python" not in text, text[-3000:]
    if code == 130:
        assert "interrupted" in text.strip().splitlines()[-1], text[-1000:]
    staging = [p.name for p in tmp_path.glob(f".{trial.out.name}.*")]
    assert staging == [], f"trial {trial.number} left {staging}"
    if trial.sweep:
        assert not list(trial.out.glob("runs/.*")), "a temporary file left"
        if list(trial.out.glob("runs/*.parquet")):
            got = load_results(trial.out, strict=True)
            assert got["run_key"].is_unique
            mine = expected_rows[expected_rows["run_key"].isin(got["run_key"])]
            pd.testing.assert_frame_equal(
                deterministic(got), mine.reset_index(drop=True), check_exact=True
            )
    else:
        # all or nothing: the folder appears whole (a Ctrl-C after it appeared, while the
        # command prints its table, still ends in 130) or not at all
        assert trial.out.exists() or code == 130, f"trial {trial.number}: exit {code}"
        if trial.out.exists():
            assert paper_metrics(trial.out) == expected_paper
    return code


@pytest.mark.slow
def test_ctrl_c_at_random_moments_never_kills_reproduce_or_sweep_by_a_signal(tmp_path):
    suite = tmp_path / "interrupted.toml"
    suite.write_text(SUITE)
    # the references, uninterrupted (they also compile what the commands will load)
    reference_sweep = tmp_path / "reference-sweep"
    run_sweep(load_suite(str(suite)), reference_sweep, jobs=1, progress=False, log=lambda _: None)
    expected_rows = deterministic(load_results(reference_sweep))
    reference = tmp_path / "reference"
    subprocess.run(
        command(["reproduce", "--no-figures", "--out", str(reference)]),
        cwd=ROOT, check=True, capture_output=True, timeout=600,
    )  # fmt: skip
    expected_paper = paper_metrics(reference)

    seeds = np.random.SeedSequence(0x1C7C).spawn(2)
    lanes = [trials(tmp_path, suite, k, np.random.default_rng(seeds[k])) for k in range(2)]
    running: list[Trial | None] = [None, None]
    codes: list[int] = []
    deadline = time.monotonic() + 1200
    while True:
        for k, lane in enumerate(lanes):
            trial = running[k]
            if trial is not None and trial.process is not None:
                trial.press_when_due()
                if trial.process.poll() is None:
                    continue
                codes.append(check(trial, tmp_path, expected_rows, expected_paper))
            done = codes.count(130) >= INTERRUPTED or len(codes) >= MOST_TRIALS
            running[k] = None if done else next(lane)
            if running[k] is not None:
                running[k].start()
        if all(trial is None for trial in running):
            break
        assert time.monotonic() < deadline, f"stalled after {len(codes)} trials"
        time.sleep(0.01)
    assert codes.count(130) >= INTERRUPTED, codes
