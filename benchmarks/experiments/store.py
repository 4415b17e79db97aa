"""The results store of a sweep: one Parquet file per finished run, and a manifest.

Layout of a results folder ``DIR``::

    DIR/manifest.json            suite file, package versions, git commit, machine, sessions
    DIR/runs/<key>.parquet       one row: the run's identity and metrics (the "finished" mark)
    DIR/traces/<key>.parquet     the per-instant trace, when the suite asks for traces

``<key>`` is the hash of the run's identity
(:attr:`formation_bench.benchmarks.spec.RunSpec.key`).
Every file is written to a temporary name and renamed, and a trace is written
before its run row, so a run row exists only for a finished run. On resume each
row is read back whole; a file that cannot be read, holds the wrong run, was
produced by a different configuration, or lacks its trace is redone.

Everything reads back as one pandas DataFrame (:func:`load_results`), and DuckDB
reads the same files directly::

    SELECT optimizer, trigger, median(tracking_error_max_m)
    FROM read_parquet('DIR/runs/*.parquet', union_by_name = true) GROUP BY ALL
"""

from __future__ import annotations

import contextlib
import fcntl
import io
import json
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from formation_bench.benchmarks.outputs import atomic_write_bytes
from formation_bench.benchmarks.record import RECORD_FORMAT, value_type

MANIFEST = "manifest.json"
RUNS = "runs"
TRACES = "traces"
LOCK = ".lock"


class StoreError(RuntimeError):
    """A results folder that cannot be used as asked (reported in one line)."""


class StoreBusy(StoreError):
    """Another sweep holds the results folder."""


@dataclass(frozen=True)
class RunStatus:
    """What the store holds for one run key."""

    state: str
    """``done``, ``missing``, ``corrupt`` (unreadable or wrong contents), ``stale``
    (another configuration) or ``no-trace`` (trace required but missing or unreadable)."""
    detail: str = ""


class ResultStore:
    """A results folder (see the module docstring)."""

    def __init__(self, root: Path | str) -> None:
        self.root = Path(root)
        self.runs_dir = self.root / RUNS
        self.traces_dir = self.root / TRACES

    # paths ----------------------------------------------------------------------------------------

    def run_path(self, key: str) -> Path:
        return self.runs_dir / f"{key}.parquet"

    def trace_path(self, key: str) -> Path:
        return self.traces_dir / f"{key}.parquet"

    @property
    def manifest_path(self) -> Path:
        return self.root / MANIFEST

    # writing --------------------------------------------------------------------------------------

    def create(self) -> None:
        self.runs_dir.mkdir(parents=True, exist_ok=True)
        self.traces_dir.mkdir(parents=True, exist_ok=True)

    @contextlib.contextmanager
    def lock(self) -> Iterator[None]:
        """Hold the folder for one sweep; a second sweep into it fails instead of racing.

        The kernel drops the lock when the process dies, even by SIGKILL.
        """
        self.root.mkdir(parents=True, exist_ok=True)
        with open(self.root / LOCK, "a+") as handle:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise StoreBusy(
                    f"{self.root} is in use by another sweep (wait for it, or choose another --out)"
                ) from None
            try:
                yield
            finally:
                fcntl.flock(handle, fcntl.LOCK_UN)

    def remove_temporaries(self) -> int:
        """Delete temporary files left by an interrupted write (call while holding the lock)."""
        removed = 0
        for folder in (self.runs_dir, self.traces_dir, self.root):
            if folder.is_dir():
                for path in folder.glob(".*.tmp"):
                    path.unlink(missing_ok=True)
                    removed += 1
        return removed

    def write_run(self, key: str, row: dict[str, Any], trace: pd.DataFrame | None) -> None:
        """Store a finished run: its trace first (if any), then its row, each atomically."""
        if trace is not None:
            atomic_write_bytes(self.trace_path(key), _parquet_bytes(pa.Table.from_pandas(trace)))
        table = pa.Table.from_pylist([row])
        for k, column in enumerate(table.schema):
            if pa.types.is_null(column.type):  # all-None column: give it a real type
                kind = _ARROW_TYPES.get(value_type(column.name), pa.float64())
                table = table.set_column(k, column.name, table.column(k).cast(kind))
        atomic_write_bytes(self.run_path(key), _parquet_bytes(table))

    def write_manifest(self, manifest: dict[str, Any]) -> None:
        atomic_write_bytes(
            self.manifest_path, (json.dumps(manifest, indent=2, default=str) + "\n").encode()
        )

    # reading --------------------------------------------------------------------------------------

    def read_manifest(self) -> dict[str, Any] | None:
        if not self.manifest_path.is_file():
            return None
        try:
            return json.loads(self.manifest_path.read_text())
        except (OSError, json.JSONDecodeError):
            return None

    def status(self, key: str, config_hash: str, need_trace: bool) -> RunStatus:
        """Whether the run ``key`` is stored whole (see :class:`RunStatus`)."""
        path = self.run_path(key)
        if not path.exists():
            return RunStatus("missing")
        try:
            table = pq.read_table(path)
            if table.num_rows != 1:
                return RunStatus("corrupt", f"{table.num_rows} rows")
            row = table.to_pylist()[0]
        except Exception as err:  # any failure to read back means the file is not a result
            return RunStatus("corrupt", f"{type(err).__name__}: {err}")
        if row.get("run_key") != key:
            return RunStatus("corrupt", f"holds run {row.get('run_key')!r}")
        if row.get("record_format") != RECORD_FORMAT:
            return RunStatus("stale", "stored by a version with other result columns")
        if row.get("config_hash") != config_hash:
            return RunStatus("stale", "configuration changed since it ran")
        if need_trace:
            try:
                trace = pq.read_table(self.trace_path(key))
            except Exception as err:
                return RunStatus("no-trace", f"{type(err).__name__}: {err}")
            if trace.num_rows == 0:
                return RunStatus("no-trace", "empty trace")
        return RunStatus("done")

    def keys(self) -> list[str]:
        """Keys of every run file present (read or not)."""
        if not self.runs_dir.is_dir():
            return []
        return sorted(p.stem for p in self.runs_dir.glob("*.parquet"))


_ARROW_TYPES = {int: pa.int64(), str: pa.string(), bool: pa.bool_()}


def _parquet_bytes(table: pa.Table) -> bytes:
    buffer = io.BytesIO()
    pq.write_table(table, buffer, compression="zstd")
    return buffer.getvalue()


def load_results(root: Path | str, *, strict: bool = False) -> pd.DataFrame:
    """Every stored run of ``root`` as one DataFrame, one row per run, sorted by identity.

    Unreadable files are skipped (a warning goes to stderr), or raise with ``strict``.
    """
    store = ResultStore(root)
    if not store.runs_dir.is_dir():
        raise StoreError(f"{root} holds no results (no {RUNS}/ folder); run a sweep into it first")
    frames = []
    for key in store.keys():
        path = store.run_path(key)
        try:
            frames.append(pq.read_table(path).to_pandas())
        except Exception as err:
            if strict:
                raise
            print(f"warning: skipped unreadable {path}: {err}", file=sys.stderr)
    if not frames:
        raise StoreError(f"{root} holds no finished runs")
    frame = pd.concat(frames, ignore_index=True)
    order = [
        c
        for c in ("scenario", "optimizer", "budget", "trigger", "seed", "run_key")
        if c in frame.columns
    ]
    return frame.sort_values(order, kind="stable", ignore_index=True)


def load_traces(root: Path | str, keys: list[str] | None = None) -> pd.DataFrame:
    """The stored traces (all, or of ``keys``) as one long DataFrame with a ``run_key`` column."""
    store = ResultStore(root)
    frames = []
    wanted = (
        keys if keys is not None else sorted(p.stem for p in store.traces_dir.glob("*.parquet"))
    )
    for key in wanted:
        frame = pd.read_parquet(store.trace_path(key))
        frame.insert(0, "run_key", key)
        frames.append(frame)
    if not frames:
        raise StoreError(f"{root} holds no traces (set trace = true in the suite)")
    return pd.concat(frames, ignore_index=True)
