"""Ctrl-C at any moment: never a death by signal, and nothing half-written that looks finished.

A Ctrl-C whose handler raised inside numba's boxing of a compiled function's result (its
first return, in a run's first second or two) lost the interrupt and handed Python a tuple
holding NULL: a segmentation fault when it was read, or, when the interrupt surfaced later,
an exit by SIGINT (-2) after the command's one line.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from formation_bench.experiments.store import load_results
from formation_bench.experiments.suite import load_suite
from formation_bench.experiments.sweep import run_sweep
from formation_bench.pipeline.record import is_timing_column

ROOT = Path(__file__).resolve().parent.parent


@pytest.mark.slow
def test_ctrl_c_inside_numbas_boxing_is_raised_after_the_call_returns():
    # the handler runs where Python found the main thread: here inside numba's callback that
    # fetches an array's type while boxing a compiled function's first result (a profile
    # hook stands in for the signal, so the moment is exact)
    script = textwrap.dedent("""
        import signal, sys, time
        import numpy as np
        from numba import njit
        import numba.core.serialize as serialize
        from formation_bench.pipeline.interrupts import raise_interrupt

        @njit
        def pair(n):
            return np.zeros(n), np.ones(n)

        pair.compile("(int64,)")
        signal.signal(signal.SIGINT, raise_interrupt)
        pressed = []

        def press(frame, event, arg):
            if event == "call" and frame.f_code is serialize._numba_unpickle.__code__:
                if not pressed:
                    pressed.append(frame)
                    raise_interrupt(signal.SIGINT, frame)

        try:
            sys.setprofile(press)
            try:
                result = pair(3)
            finally:
                sys.setprofile(None)
            print("sums", [float(a.sum()) for a in result], flush=True)
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:
                pass
            print("never interrupted", flush=True)
        except BaseException as err:
            print("raised", type(err).__name__, flush=True)
    """)
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.splitlines() == ["sums [0.0, 3.0]", "raised KeyboardInterrupt"]


SUITE = """\
name = "interrupted"
seeds = 3
triggers = [false]

[[optimizers]]
name = "modified-bso"
overrides = { max_iterations = 5 }

[[scenarios]]
name = "paper"
overrides = { n_steps = 20, settle_time_s = 1.0 }
"""
TRIALS = 100
"""Interrupted commands, reproduce and sweep alternately."""
LATEST_S = 2.5
"""The latest moment a Ctrl-C is pressed after a command starts: a warm reproduce ends in
about 2.5 s on a 2-core machine, so some finish first and the rest are caught in their
imports, their compiled kernels or their writes."""


def deterministic(frame: pd.DataFrame) -> pd.DataFrame:
    keep = [c for c in frame.columns if not is_timing_column(c)]
    return frame[keep].sort_values("run_key").reset_index(drop=True)


def paper_metrics(folder: Path) -> list[dict]:
    """The reproduce records without what differs between two runs (times, provenance)."""
    records = json.loads((folder / "metrics.json").read_text())
    return [
        {k: v for k, v in record["metrics"].items() if "time" not in k and "_ms" not in k}
        | {"description": record["description"]}
        for record in records
    ]


def command(args: list[str]) -> list[str]:
    return [sys.executable, "-m", "formation_bench.cli", *args]


def interrupt(args: list[str], log: Path, rng: np.random.Generator) -> int:
    """Run the command, press Ctrl-C at a random moment (sometimes twice), return its code."""
    with open(log, "wb") as handle:
        process = subprocess.Popen(
            command(args), stdout=handle, stderr=handle, cwd=ROOT,
            start_new_session=True,  # its own process group, as a terminal job's
            # a test runner started in the background ignores SIGINT, and a child inherits it
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )  # fmt: skip
    try:
        try:
            process.wait(timeout=float(rng.uniform(0.2, LATEST_S)))
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGINT)  # Ctrl-C reaches the whole group
            if rng.random() < 0.2:
                time.sleep(float(rng.uniform(0.0, 0.3)))
                os.killpg(process.pid, signal.SIGINT)
        return process.wait(timeout=120)
    finally:
        try:
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


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

    rng = np.random.default_rng(np.random.SeedSequence(0x1C7C))
    codes: dict[int, int] = {}
    swept = tmp_path / "swept"  # one sweep folder, resumed and interrupted again and again
    for trial in range(TRIALS):
        log = tmp_path / f"trial{trial}.log"
        if trial % 2 == 0:
            out = tmp_path / f"paper{trial}"
            code = interrupt(["reproduce", "--no-figures", "--out", str(out)], log, rng)
        else:
            jobs = "2" if trial % 10 == 1 else "1"
            out = swept
            code = interrupt(["sweep", str(suite), "--out", str(out), "--jobs", jobs], log, rng)
        text = log.read_text(errors="replace")
        codes[code] = codes.get(code, 0) + 1
        assert code in (0, 130), f"trial {trial}: exit {code}\n{text[-3000:]}"
        assert "Traceback" not in text and "Fatal Python" not in text, text[-3000:]
        if code == 130:
            assert text.strip().splitlines()[-1].endswith("interrupted"), text[-1000:]
        leftovers = [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]
        assert leftovers == [], f"trial {trial} left {leftovers}"
        if out is swept:
            if (out / "runs").is_dir():
                got = load_results(out, strict=True)
                assert got["run_key"].is_unique
                assert not list((out / "runs").glob(".*"))
                mine = expected_rows[expected_rows["run_key"].isin(got["run_key"])]
                pd.testing.assert_frame_equal(
                    deterministic(got), mine.reset_index(drop=True), check_exact=True
                )
        else:
            # all or nothing: a finished folder is the reference's, an interrupted one absent
            assert out.exists() == (code == 0), f"trial {trial}: exit {code}, {out.exists()}"
            if code == 0:
                assert paper_metrics(out) == expected_paper
    # the draws caught commands in every state: some finished, most were interrupted
    assert codes.get(130, 0) >= TRIALS // 2 and sum(codes.values()) == TRIALS, codes
