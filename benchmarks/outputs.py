"""Writing and reading a run's outputs: ``metrics.json`` and the Parquet trace.

The trace is stored long: one row per update instant and UAV, so that pandas
(or DuckDB) can group and plot it without knowing the array layout.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from formation_bench.mpc.loop import Trace
from formation_bench.mpc.trigger import TRIGGER_CONDITIONS


def trace_frame(trace: Trace) -> pd.DataFrame:
    """The trace as a long DataFrame: one row per instant (0..T) and UAV.

    The last instant holds the final state only: its control and solve
    columns are NaN / False.
    """
    n_instants, n_uav = trace.states.shape[:2]
    n_steps = n_instants - 1
    step = np.repeat(np.arange(n_instants), n_uav)
    uav = np.tile(np.arange(1, n_uav + 1), n_instants)

    def pad(values: np.ndarray, fill: Any) -> np.ndarray:
        extra = np.full((1, *values.shape[1:]), fill, dtype=np.result_type(values, type(fill)))
        return np.concatenate([values, extra]).reshape(n_instants * n_uav, *values.shape[2:])

    states = trace.states.reshape(-1, 4)
    controls = pad(trace.controls, np.nan)
    reasons = pad(trace.reasons, False)
    desired = (trace.reference[:, None, :] + trace.desired_offsets).reshape(-1, 2)
    frame = pd.DataFrame(
        {
            "optimizer": trace.optimizer,
            "scenario": trace.scenario.name,
            "trigger": trace.trigger,
            # a 128-bit seed (a sweep run's entropy, repeated with run --seed) does not fit an
            # int64 column: such a seed is stored as its decimal string
            "seed": trace.seed if trace.seed < 2**63 else str(trace.seed),
            "step": step,
            "time_s": np.repeat(trace.times, n_uav),
            "uav": uav,
            "x_m": states[:, 0],
            "y_m": states[:, 1],
            "heading_rad": states[:, 2],
            "speed_m_s": states[:, 3],
            "accel_m_s2": controls[:, 0],
            "turn_rate_rad_s": controls[:, 1],
            "solved": pad(trace.solved, False).astype(bool),
            **{
                f"trigger_{name}": reasons[:, k].astype(bool)
                for k, name in enumerate(TRIGGER_CONDITIONS)
            },
            "solve_time_s": pad(trace.solve_time_s, np.nan),
            "nfev": pad(trace.nfev, 0).astype(np.int64),
            "solve_cost": pad(trace.solve_cost, np.nan),
            "solve_failed": pad(trace.solve_failed, False).astype(bool),
            "plan_at_bound": pad(trace.plan_at_bound, False).astype(bool),
            "ref_x_m": np.repeat(trace.reference[:, 0], n_uav),
            "ref_y_m": np.repeat(trace.reference[:, 1], n_uav),
            "ref_heading_rad": np.repeat(trace.reference_heading, n_uav),
            "desired_x_m": desired[:, 0],
            "desired_y_m": desired[:, 1],
        }
    )
    assert len(frame) == (n_steps + 1) * n_uav
    return frame


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file and rename, so no half file is left."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
        # mkstemp makes the file private (0o600); a result is an ordinary file
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_metrics(path: Path, metrics: dict[str, Any] | list[dict[str, Any]]) -> None:
    """Write metrics as indented JSON."""
    atomic_write_bytes(path, (json.dumps(metrics, indent=2) + "\n").encode())


def write_text(path: Path, text: str) -> None:
    """Write a text file atomically."""
    atomic_write_bytes(path, text.encode())


def write_trace(path: Path, frame: pd.DataFrame) -> None:
    """Write a trace DataFrame as Parquet."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    frame.to_parquet(tmp, index=False)
    os.replace(tmp, path)


def read_trace(path: Path) -> pd.DataFrame:
    """Read a trace written by :func:`write_trace`."""
    return pd.read_parquet(path)
