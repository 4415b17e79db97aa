"""The results store of a sweep: one Parquet file per finished run, and a manifest.

Layout of a results folder ``DIR``::

    DIR/manifest.json            suite file, package versions, git commit, machine, sessions
    DIR/runs/<key>.parquet       one row: the run's identity and metrics (the "finished" mark)
    DIR/traces/<key>.parquet     the per-instant trace, when the suite asks for traces
    DIR/score/<key>.parquet      a score run's rows, one per instance
                                 (:mod:`~formation_bench.experiments.score`)

``<key>`` is the hash of the run's identity
(:attr:`formation_bench.pipeline.spec.Identified.key`).
Every file is written to a temporary name and renamed, and a trace is written
before its run row, so a run row exists only for a finished run.

Every file proves it is intact. A Parquet file is written with page checksums (CRC-32 of
each data page) and carries a *seal* in its footer's key-value metadata
(:data:`~formation_bench.experiments.seal.SEAL_KEY`): JSON naming what the
file holds (``kind``: run, trace or score, and the ``key`` it must be stored under) and,
last, the SHA-256 of the whole file's bytes taken with that digest's own 64 characters set
to ``0``. So every byte is covered, the footer and the metadata too, which page checksums
leave out. A run file's seal also holds its trace's digest (``trace``), so a trace garbled,
swapped for another run's or left from an earlier run of the same key is told apart.
``manifest.json`` begins with ``manifest_seal`` and ends with ``manifest_sha256``, the
SHA-256 of the file taken the same way; a manifest that lost either field is damaged, not
taken for one written before checksums.

Every reader verifies: resume (:meth:`ResultStore.status` for a sweep's runs,
:meth:`ResultStore.score_status` for score runs) checks the digest, the
kind, the key against the file name, the page checksums and the row's own ``run_key``, and
redoes a file that fails any of them (a trace is checked by its digest and the run's seal,
without decoding it). :func:`load_results`, :func:`load_traces` and :func:`load_scores` (what
``report``, ``export-ioh`` and the notebook read) leave such a file out and name it on
stderr, one line per file.

A stored row names the format of its columns (``record_format``, a score row's
``score_format``). Resume keeps a row whose format means what today's columns mean (the
record's :data:`~formation_bench.pipeline.record.SAME_MEANING_FORMATS`, the score's
:data:`~formation_bench.experiments.score.SAME_MEANING_SCORE_FORMATS`) and whose
``config_hash`` is the run's (a score row stored before score rows had one is kept), and
redoes the rest (``stale``). Adding a column changes no format: the readers give a row stored
before it the column empty (missing), so no stored run is redone for it.

A file whose content belongs to another key (copied under another run's name) fails the key
check everywhere, so it is never counted twice.

A damaged manifest (not UTF-8, not JSON, not an object, fields of the wrong type, a failed
checksum) or one missing while ``runs/`` holds runs stops a sweep with one line naming it
and the command that rebuilds it from the verified run rows,
``formation-bench sweep SUITE --out DIR --rebuild-manifest``
(:func:`~formation_bench.experiments.manifest.rebuild_manifest`).
The manifest is never reset silently.

Files written before seals were kept carry none: resume redoes them (state
``unverified``), so a resumed folder ends fully sealed; the readers use them and say
once, on stderr, how many were used unverified. A manifest with neither field is taken
for one written before seals only when it says format 1 and no run beside it is sealed
(:func:`~formation_bench.experiments.manifest.read_manifest`); it is then checked for its
shape only, and gets its digest when the next sweep rewrites it. A stored duration below
zero is damage too (:func:`read_checked`).

The store owns only its own files (:data:`STORE_FILE`, the manifest, the lock and the
temporaries of its writes, :data:`TEMPORARY`): nothing else in the folder is read,
hashed or deleted. Every file or folder it writes or deletes goes through
:meth:`ResultStore.inside`, which refuses a symbolic link inside the folder
(:func:`~formation_bench.pipeline.staging.confined`).

This module holds the folder's layout, its lock, the run and trace files and their readers;
:mod:`~formation_bench.experiments.seal` makes and checks the seals and the
manifest's digest, and :mod:`~formation_bench.experiments.manifest` reads, writes
and rebuilds the manifest.

Everything reads back as one pandas DataFrame (:func:`load_results`), and DuckDB
reads the same files directly (the seal is footer metadata, not a column)::

    SELECT optimizer, trigger, median(tracking_error_max_m)
    FROM read_parquet('DIR/runs/*.parquet', union_by_name = true) GROUP BY ALL
"""

from __future__ import annotations

import contextlib
import fcntl
import re
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc

from formation_bench.experiments.errors import IntegrityError, StoreBusy, StoreError
from formation_bench.experiments.seal import (
    decode,
    read_sealed,
    read_table,
    sealed_parquet,
)
from formation_bench.pipeline.outputs import ARROW_THREADS, atomic_write_bytes
from formation_bench.pipeline.record import (
    SAME_MEANING_FORMATS,
    duration_columns,
    record_columns,
    value_type,
)
from formation_bench.pipeline.staging import confined

MANIFEST = "manifest.json"
RUNS = "runs"
TRACES = "traces"
SCORE = "score"
"""Subfolder of a results folder that holds score runs."""
LOCK = ".lock"
STORE_FILE = re.compile(r"[0-9a-f]{24}\.parquet")
"""Names of the files the store owns in ``runs/``, ``traces/`` and ``score/``: a run key
(24 hex digits, :attr:`~formation_bench.pipeline.spec.Identified.key`) and ``.parquet``.
Any other file there is not the store's: no reader opens it and no sweep touches it."""
TEMPORARY = re.compile(r"\.(?:[0-9a-f]{24}\.parquet|manifest\.json)\.[^.]+\.tmp")
"""Names of the temporary files an interrupted write of the store's own files leaves
(:func:`~formation_bench.pipeline.outputs.atomic_write_bytes`)."""


# --- notices of the readers --------------------------------------------------------------------


def left_out(path: Path, reason: str, redo: str) -> None:
    """Say on stderr, in one line, that a reader left a damaged file out."""
    print(
        f"warning: left out {path}: {reason}; the results read here do not include it "
        f"({redo} redoes it)",
        file=sys.stderr,
    )


def to_stderr(line: str) -> None:
    print(line, file=sys.stderr)


def unverified_notice(count: int, folder: Path, redo: str, notice: Callable[[str], None]) -> None:
    """Say once that ``count`` files without a seal were used."""
    if count:
        notice(
            f"note: {count} file(s) in {folder} were stored before checksums were kept and "
            f"are used unverified ({redo} replaces them with sealed ones)"
        )


def intact_frames(
    files: list[tuple[Path, str]],
    read: Callable[[str], tuple[pd.DataFrame, bool]],
    *,
    redo: str,
    redo_all: str,
    folder: Path,
    strict: bool = False,
    notice: Callable[[str], None] = to_stderr,
) -> list[pd.DataFrame]:
    """What ``read`` gives (a frame, and whether its file was sealed) for each ``(path,
    key)`` whose file passes its checks.

    A file that fails is left out and named on stderr (``redo`` says what redoes it), or
    raises :class:`IntegrityError` with ``strict``; how many were used unverified goes to
    ``notice`` in one line (``redo_all`` says what replaces them).
    """
    frames = []
    unverified = 0
    for path, key in files:
        try:
            frame, sealed = read(key)
        except IntegrityError as err:
            if strict:
                raise IntegrityError(f"{path}: {err}") from None
            left_out(path, str(err), redo)
            continue
        unverified += not sealed
        frames.append(frame)
    unverified_notice(unverified, folder, redo_all, notice)
    return frames


# --- the store ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunStatus:
    """What the store holds for one run key."""

    state: str
    """``done``, ``missing``, ``corrupt`` (fails its checksum, unreadable or wrong contents,
    its trace too), ``stale`` (another configuration, or columns that mean other things),
    ``unverified`` (stored before checksums were kept) or ``no-trace`` (trace required but
    missing)."""
    detail: str = ""


def stale_reason(
    formats: set[Any], same_meaning: frozenset[int], hashes: set[Any], config_hash: str | None
) -> str | None:
    """Why stored rows of these formats and configuration hashes are not the run asked for
    (None: they are). A row without a hash (None) was stored before its kind kept one; a
    ``config_hash`` of None accepts any."""
    if not formats <= same_meaning:
        return "stored by a version whose result columns mean other things"
    if config_hash is not None and hashes - {None, config_hash}:
        return "configuration changed since it ran"
    return None


class ResultStore:
    """A results folder (see the module docstring)."""

    def __init__(self, root: Path | str) -> None:
        self.root = Path(root)
        self.runs_dir = self.root / RUNS
        self.traces_dir = self.root / TRACES
        self.score_dir = self.root / SCORE

    # paths ----------------------------------------------------------------------------------------

    def run_path(self, key: str) -> Path:
        return self.runs_dir / f"{key}.parquet"

    def trace_path(self, key: str) -> Path:
        return self.traces_dir / f"{key}.parquet"

    def score_path(self, key: str) -> Path:
        return self.score_dir / f"{key}.parquet"

    @property
    def manifest_path(self) -> Path:
        return self.root / MANIFEST

    def inside(self, path: Path) -> Path:
        """``path``, a file or folder the store writes or deletes, checked to reach no
        place outside the folder through a symbolic link
        (:func:`~formation_bench.pipeline.staging.confined`)."""
        return confined(self.root, path)

    def check_links(self) -> None:
        """Refuse a folder whose own subfolders or files are links out of it, before
        anything is written into it."""
        for path in (self.runs_dir, self.traces_dir, self.score_dir, self.manifest_path,
                     self.root / LOCK):  # fmt: skip
            self.inside(path)

    # writing --------------------------------------------------------------------------------------

    def create(self) -> None:
        self.inside(self.runs_dir).mkdir(parents=True, exist_ok=True)
        self.inside(self.traces_dir).mkdir(parents=True, exist_ok=True)

    @contextlib.contextmanager
    def lock(self) -> Iterator[None]:
        """Hold the folder for one sweep or score; a second one into it fails instead of
        racing.

        The kernel drops the lock when the process dies, even by SIGKILL.
        """
        self.check_links()
        self.root.mkdir(parents=True, exist_ok=True)
        with open(self.root / LOCK, "a+") as handle:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                raise StoreBusy(
                    f"{self.root} is in use by another sweep or score (wait for it, or choose "
                    "another --out)"
                ) from None
            try:
                yield
            finally:
                fcntl.flock(handle, fcntl.LOCK_UN)

    def remove_temporaries(self) -> int:
        """Delete temporary files left by an interrupted write (call while holding the lock)."""
        removed = 0
        for folder in (self.runs_dir, self.traces_dir, self.score_dir, self.root):
            if self.inside(folder).is_dir():
                for path in folder.glob(".*.tmp"):
                    if TEMPORARY.fullmatch(path.name):
                        self.inside(path).unlink(missing_ok=True)
                        removed += 1
        return removed

    def write_run(self, key: str, row: dict[str, Any], trace: pd.DataFrame | None) -> None:
        """Store a finished run: its trace first (if any), then its row, each atomically and
        sealed; the row's seal holds the trace's digest."""
        trace_digest = None
        if trace is not None:
            data, trace_digest = sealed_parquet(pa.Table.from_pandas(trace), "trace", key)
            atomic_write_bytes(self.inside(self.trace_path(key)), data)
        table = pa.Table.from_pylist([row])
        for k, column in enumerate(table.schema):
            if pa.types.is_null(column.type):  # all-None column: give it a real type
                kind = _ARROW_TYPES.get(value_type(column.name), pa.float64())
                table = table.set_column(k, column.name, table.column(k).cast(kind))
        data, _ = sealed_parquet(table, "run", key, trace=trace_digest)
        atomic_write_bytes(self.inside(self.run_path(key)), data)

    def write_score(self, key: str, rows: pd.DataFrame) -> Path:
        """Store a finished score run, its rows in one file, atomically and sealed."""
        path = self.inside(self.score_path(key))
        data, _ = sealed_parquet(pa.Table.from_pandas(rows, preserve_index=False), "score", key)
        atomic_write_bytes(path, data)
        return path

    # reading --------------------------------------------------------------------------------------

    def status(self, key: str, config_hash: str, need_trace: bool) -> RunStatus:
        """Whether the run ``key`` is stored whole (see :class:`RunStatus`)."""
        path = self.run_path(key)
        if not path.exists():
            return RunStatus("missing")
        try:
            table, seal = read_checked(path, "run", key)
        except IntegrityError as err:
            return RunStatus("corrupt", str(err))
        if table.num_rows != 1:
            return RunStatus("corrupt", f"{table.num_rows} rows")
        row = table.to_pylist()[0]
        stale = stale_reason(
            {row.get("record_format")}, SAME_MEANING_FORMATS, {row.get("config_hash")}, config_hash
        )
        if stale is not None or row.get("config_hash") is None:
            return RunStatus("stale", stale or "stored without its configuration hash")
        if seal is None:
            return RunStatus("unverified", "stored before checksums were kept")
        if need_trace:
            trace_path = self.trace_path(key)
            if not trace_path.exists():
                return RunStatus("no-trace", "trace missing")
            try:
                _, trace_seal = read_sealed(trace_path, "trace", key)
            except IntegrityError as err:
                return RunStatus("corrupt", f"trace: {err}")
            if seal.get("trace") is None:
                return RunStatus("no-trace", "stored without a trace")
            if trace_seal is None or trace_seal.get("sha256") != seal["trace"]:
                return RunStatus("corrupt", "trace: not the trace stored with the run")
        return RunStatus("done")

    def score_status(
        self, key: str, config_hash: str | None, formats: frozenset[int], format_column: str
    ) -> RunStatus:
        """Whether the score run ``key`` is stored whole and sealed, its rows of one of
        ``formats`` (in ``format_column``) and of the configuration ``config_hash`` (None:
        of any)."""
        path = self.score_path(key)
        if not path.exists():
            return RunStatus("missing")
        try:
            table, seal = read_checked(
                path, "score", key, ["run_key", format_column, "config_hash", *duration_columns()]
            )
        except IntegrityError as err:
            return RunStatus("corrupt", str(err))
        stale = stale_reason(
            set(_column(table, format_column)),
            formats,
            set(_column(table, "config_hash")),
            config_hash,
        )
        if stale is not None:
            return RunStatus("stale", stale)
        if seal is None:
            return RunStatus("unverified", "stored before checksums were kept")
        return RunStatus("done")

    def keys(self) -> list[str]:
        """Keys of every run file present (read or not)."""
        return _stems(self.runs_dir)

    def score_keys(self) -> list[str]:
        """Keys of every score file present (read or not)."""
        return _stems(self.score_dir)


def _stems(folder: Path) -> list[str]:
    """The keys of the store's own files in ``folder`` (:data:`STORE_FILE`)."""
    if not folder.is_dir():
        return []
    return sorted(p.stem for p in folder.glob("*.parquet") if STORE_FILE.fullmatch(p.name))


def read_checked(
    path: Path, kind: str, key: str, columns: list[str] | None = None
) -> tuple[pa.Table, dict[str, Any] | None]:
    """:func:`~formation_bench.experiments.seal.read_table`, and no stored duration below
    zero: durations come from a monotonic clock, so a negative one is a defect of the file
    (raises :class:`IntegrityError`, which every reader reports in one line)."""
    table, seal = read_table(path, kind, key, columns)
    for name in duration_columns():
        if name not in table.column_names:
            continue
        values = table.column(name)
        if pa.types.is_list(values.type):
            values = pc.list_flatten(values)
        lowest = pc.min(values).as_py()
        if lowest is not None and lowest < 0:
            raise IntegrityError(
                f"holds a negative duration {name}={lowest:g} s (durations come from a "
                "monotonic clock)"
            )
    return table, seal


def _column(table: pa.Table, name: str) -> list[Any]:
    """The values of a column; a column the file lacks (stored before it existed) is None."""
    if name not in table.column_names:
        return [None] * table.num_rows
    return table.column(name).to_pylist()


def with_declared_columns(frame: pd.DataFrame, columns: list[str]) -> pd.DataFrame:
    """``frame`` with every column of ``columns`` it lacks added empty (missing): rows stored
    before a column was declared read it so."""
    missing = [c for c in columns if c not in frame.columns]
    if not missing:
        return frame
    empty = pd.DataFrame({c: pd.Series(None, index=frame.index, dtype=object) for c in missing})
    return pd.concat([frame, empty], axis=1)


_ARROW_TYPES = {int: pa.int64(), str: pa.string(), bool: pa.bool_()}


def load_results(
    root: Path | str, *, strict: bool = False, notice: Callable[[str], None] = to_stderr
) -> pd.DataFrame:
    """Every intact stored run of ``root`` as one DataFrame, one row per run, sorted by
    identity.

    A file that fails its checks is left out and named on stderr (one line each), or raises
    :class:`IntegrityError` with ``strict``. How many files were used unverified (stored
    before checksums were kept) goes to ``notice``, in one line.
    """
    store = ResultStore(root)
    if not store.runs_dir.is_dir():
        raise StoreError(f"{root} holds no results (no {RUNS}/ folder); run a sweep into it first")

    def read(key: str) -> tuple[pd.DataFrame, bool]:
        table, seal = read_checked(store.run_path(key), "run", key)
        return table.to_pandas(use_threads=ARROW_THREADS), seal is not None

    frames = intact_frames(
        [(store.run_path(key), key) for key in store.keys()], read,
        redo=f"a sweep of the suite holding the run into {root}",
        redo_all=f"a sweep of their suite into {root}",
        folder=store.runs_dir, strict=strict, notice=notice,
    )  # fmt: skip
    if not frames:
        raise StoreError(f"{root} holds no finished runs")
    frame = with_declared_columns(
        pd.concat(frames, ignore_index=True), [name for name, _, _ in record_columns()]
    )
    order = [
        c
        for c in ("scenario", "optimizer", "budget", "trigger", "seed", "run_key")
        if c in frame.columns
    ]
    return frame.sort_values(order, kind="stable", ignore_index=True)


def load_traces(
    root: Path | str,
    keys: list[str] | None = None,
    *,
    strict: bool = False,
    notice: Callable[[str], None] = to_stderr,
) -> pd.DataFrame:
    """The stored traces (all, or of ``keys``) as one long DataFrame with a ``run_key`` column.

    A trace is read only with its run: it must be the trace whose digest the run's seal
    holds. One that is not (or whose run is not stored whole) is left out and named on
    stderr, or raises :class:`IntegrityError` with ``strict``.
    """
    store = ResultStore(root)
    wanted = keys if keys is not None else _stems(store.traces_dir)

    def read(key: str) -> tuple[pd.DataFrame, bool]:
        frame, sealed = _verified_trace(store, key)
        frame.insert(0, "run_key", key)
        return frame, sealed

    frames = intact_frames(
        [(store.trace_path(key), key) for key in wanted], read,
        redo=f"a sweep of the suite holding the run into {root}",
        redo_all=f"a sweep of their suite into {root}",
        folder=store.traces_dir, strict=strict, notice=notice,
    )  # fmt: skip
    if not frames and wanted:
        raise StoreError(f"{root} holds no intact trace of the {len(wanted)} run(s) asked for")
    if not frames:
        raise StoreError(f"{root} holds no traces (set trace = true in the suite)")
    return pd.concat(frames, ignore_index=True)


def _verified_trace(store: ResultStore, key: str) -> tuple[pd.DataFrame, bool]:
    """The trace of ``key`` checked against its run's seal, and whether it was sealed."""
    path = store.trace_path(key)
    if not path.exists():
        raise IntegrityError("no such trace")
    try:
        _, run_seal = read_sealed(store.run_path(key), "run", key)
    except IntegrityError as err:
        raise IntegrityError(f"its run file is not stored whole ({err})") from None
    data, seal = read_sealed(path, "trace", key)
    if run_seal is not None and (seal is None or run_seal.get("trace") != seal.get("sha256")):
        raise IntegrityError("not the trace stored with its run")
    return decode(data).to_pandas(use_threads=ARROW_THREADS), seal is not None


def load_scores(
    root: Path | str,
    declared: list[str] | None = None,
    *,
    notice: Callable[[str], None] = to_stderr,
) -> pd.DataFrame:
    """Every intact stored score row of ``root``, one row per (run, instance), with the
    ``declared`` columns a row lacks empty.

    A file that fails its checks is left out and named on stderr, one line each. How many
    files were used unverified (stored before checksums were kept) goes to ``notice``.
    """
    store = ResultStore(root)
    redo = f"'formation-bench score' with the run's options and --out {root}"

    def read(key: str) -> tuple[pd.DataFrame, bool]:
        table, seal = read_checked(store.score_path(key), "score", key)
        return table.to_pandas(use_threads=ARROW_THREADS), seal is not None

    frames = intact_frames(
        [(store.score_path(key), key) for key in store.score_keys()], read,
        redo=redo, redo_all=redo, folder=store.score_dir, notice=notice,
    )  # fmt: skip
    if not frames:
        raise StoreError(f"{root} holds no score runs (no intact {SCORE}/*.parquet)")
    frame = with_declared_columns(pd.concat(frames, ignore_index=True), declared or [])
    return frame.sort_values(
        ["optimizer", "budget", "seed", "library", "instance"], ignore_index=True
    )
