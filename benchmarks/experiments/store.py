"""The results store of a sweep: one Parquet file per finished run, and a manifest.

Layout of a results folder ``DIR``::

    DIR/manifest.json            suite file, package versions, git commit, machine, sessions
    DIR/runs/<key>.parquet       one row: the run's identity and metrics (the "finished" mark)
    DIR/traces/<key>.parquet     the per-instant trace, when the suite asks for traces

``<key>`` is the hash of the run's identity
(:attr:`formation_bench.benchmarks.experiments.suite.RunSpec.key`).
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
import datetime as dt
import fcntl
import io
import json
import os
import platform
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from formation_bench.benchmarks.outputs import atomic_write_bytes

MANIFEST = "manifest.json"
RUNS = "runs"
TRACES = "traces"
LOCK = ".lock"

PACKAGES = (
    "formation-bench",
    "numpy",
    "numba",
    "scipy",
    "scikit-learn",
    "pandas",
    "pyarrow",
    "joblib",
    "dask",
    "distributed",
    "scikit-posthocs",
    "statsmodels",
    "seaborn",
    "matplotlib",
)

INTEGER_COLUMNS = ("budget_max_evaluations", "budget_max_iterations")
"""Nullable integer columns (None = not set)."""

TIMING_COLUMNS = ("wall_time_s", "run_time_s", "finished_at", "worker_host", "worker_pid")
"""Columns that measure time or place, and so differ between two runs of the same thing."""
TIMING_PREFIXES = ("solve_time", "wall_time")


def is_timing_column(name: str) -> bool:
    """True for columns that are timings or bookkeeping (not reproducible bit for bit)."""
    return name in TIMING_COLUMNS or name.startswith(TIMING_PREFIXES)


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
                kind = pa.int64() if column.name in INTEGER_COLUMNS else pa.float64()
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


# --- manifest facts ---------------------------------------------------------------------------


def package_versions() -> dict[str, str | None]:
    versions: dict[str, str | None] = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def git_info() -> dict[str, Any]:
    """The commit of the installed formation-bench code, never of the current directory.

    A regular install carries the commit it was built from (stamped by
    setuptools-scm; ``dirty`` when built from a tree with uncommitted changes).
    An editable install runs the source folder as it is now, so its HEAD and
    dirty flag are read from that folder.
    """
    import formation_bench

    try:
        from formation_bench import _version

        built: str | None = getattr(_version, "__commit_id__", None)
    except ImportError:
        built = None
    version = formation_bench.__version__
    info: dict[str, Any] = {
        "version": version,
        "commit": built.removeprefix("g") if built else None,
        "dirty": ".d" in version.partition("+")[2] if built else None,
        "source": "built",
    }
    source = _editable_source()
    if source is None:
        return info
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=source, capture_output=True, text=True,
            timeout=10, check=True,
        ).stdout.strip()  # fmt: skip
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"], cwd=source,
            capture_output=True, text=True, timeout=10, check=True,
        ).stdout.strip()  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return {**info, "commit": None, "dirty": None, "source": str(source)}
    return {**info, "commit": commit, "dirty": bool(dirty), "source": str(source)}


def _editable_source() -> Path | None:
    """The source folder of an editable install (PEP 610's direct_url.json), else None."""
    try:
        text = metadata.distribution("formation-bench").read_text("direct_url.json")
    except metadata.PackageNotFoundError:
        return None
    if not text:
        return None
    try:
        direct = json.loads(text)
    except json.JSONDecodeError:
        return None
    if not direct.get("dir_info", {}).get("editable"):
        return None
    url = str(direct.get("url", ""))
    return Path(url.removeprefix("file://")) if url.startswith("file://") else None


def machine_info() -> dict[str, Any]:
    info: dict[str, Any] = {
        "hostname": platform.node(),
        "platform": platform.platform(),
        "machine": platform.machine(),
        "processor": platform.processor() or None,
        "cpu_count": os.cpu_count(),
    }
    if hasattr(os, "sched_getaffinity"):
        info["cpus_available"] = len(os.sched_getaffinity(0))
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                info["cpu_model"] = line.split(":", 1)[1].strip()
                break
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                info["memory_gib"] = round(int(line.split()[1]) / 2**20, 1)
                break
    return info


def now() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
