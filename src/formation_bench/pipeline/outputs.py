"""Writing and reading a run's outputs: ``metrics.json`` and the Parquet trace.

The trace is stored long: one row per update instant and UAV, so that pandas
(or DuckDB) can group and plot it without knowing the array layout; its columns are
declared in :mod:`~formation_bench.pipeline.trace_columns`. It is built
and written with pyarrow alone: pandas takes longer to import than a warm run of
the paper scenario spends outside its solves, and only the figures need it.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from formation_bench.mpc.loop import Trace
from formation_bench.pipeline.trace_columns import (
    TRACE_COLUMN_NAMES,
    TRACE_COLUMNS,
    Kind,
    RunLabels,
    Span,
    check_schema,
)

ARROW_THREADS = False
"""Whether Arrow reads and converts tables on its thread pool. Off: the files are small, and a
command interrupted (Ctrl-C) while a pool thread still worked on an abandoned read could abort
at exit ("terminate called without an active exception", exit -6; apache/arrow#34314), as
one sweep did in the Ctrl-C stress test (tests/test_interrupt_stress.py)."""

if TYPE_CHECKING:
    import pandas as pd
    import pyarrow as pa


def arrow_column(values: np.ndarray) -> pa.Array:
    """A 1-D float64, int64 or bool array as an Arrow array, NaN stored as null (as pandas
    writes it).

    Built from the array's buffers: ``pyarrow.array`` imports pandas to ask whether its
    argument is a pandas object, which alone costs more than writing the trace.
    """
    import pyarrow as pa  # here, not at the top: commands that write no trace skip it

    n_rows = values.shape[0]
    if values.dtype == np.bool_:
        return pa.Array.from_buffers(
            pa.bool_(), n_rows, [None, pa.py_buffer(np.packbits(values, bitorder="little"))], 0
        )
    kinds = {np.dtype(np.float64): pa.float64(), np.dtype(np.int64): pa.int64()}
    if values.dtype not in kinds:
        raise TypeError(f"trace columns are float64, int64 or bool, got {values.dtype}")
    data = pa.py_buffer(np.ascontiguousarray(values))
    missing = np.isnan(values) if values.dtype == np.float64 else np.zeros(n_rows, dtype=bool)
    n_missing = int(missing.sum())
    valid = pa.py_buffer(np.packbits(~missing, bitorder="little")) if n_missing else None
    return pa.Array.from_buffers(kinds[values.dtype], n_rows, [valid, data], n_missing)


def text_column(value: str, n_rows: int) -> pa.Array:
    """``value`` repeated ``n_rows`` times, typed as pandas writes its string columns."""
    import pyarrow as pa

    encoded = value.encode()
    offsets = np.arange(n_rows + 1, dtype=np.int64) * len(encoded)
    return pa.Array.from_buffers(
        pa.large_string(), n_rows, [None, pa.py_buffer(offsets), pa.py_buffer(encoded * n_rows)], 0
    )


def seed_column(seed: int, n_rows: int) -> pa.Array:
    """A run's seed on every row: int64, or its decimal string when it does not fit (a
    128-bit sweep entropy repeated with ``run --seed``)."""
    if seed < 2**63:
        return arrow_column(np.full(n_rows, seed, dtype=np.int64))
    return text_column(str(seed), n_rows)


def trace_table(trace: Trace, labels: RunLabels) -> pa.Table:
    """The trace as a long table: one row per instant (0..T) and UAV, a column per
    :data:`~formation_bench.pipeline.trace_columns.TRACE_COLUMNS` entry, in its order.

    The last instant holds the final state only: its control, solve, network and wind
    columns are NaN / 0 / False.
    """
    import pyarrow as pa

    n_instants, n_uav = trace.states.shape[:2]
    n_rows = n_instants * n_uav
    arrays = []
    for column in TRACE_COLUMNS:
        values = column.values(trace, labels)
        if column.kind is Kind.TEXT:
            arrays.append(text_column(values, n_rows))
        elif column.kind is Kind.SEED:
            arrays.append(seed_column(values, n_rows))
        elif column.span is Span.RUN:
            arrays.append(arrow_column(np.full(n_rows, values, dtype=column.kind.dtype)))
        else:
            arrays.append(arrow_column(values))
    return pa.Table.from_arrays(arrays, names=list(TRACE_COLUMN_NAMES))


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


def write_trace(path: Path, table: pa.Table) -> None:
    """Write a trace table as Parquet with page checksums, atomically."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, write_page_checksum=True)
    atomic_write_bytes(path, sink.getvalue().to_pybytes())


def read_trace(path: Path) -> pd.DataFrame:
    """Read a trace written by :func:`write_trace`, every page checked against its checksum
    and its columns against the declared ones (:func:`~.trace_columns.check_schema`)."""
    import pyarrow.parquet as pq

    table = pq.read_table(path, page_checksum_verification=True, use_threads=ARROW_THREADS)
    check_schema(table.schema)
    return table.to_pandas(use_threads=ARROW_THREADS)
