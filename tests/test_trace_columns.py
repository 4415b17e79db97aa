"""The trace table's columns: declared once, written, read back and documented from the
declaration."""

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from formation_bench.mpc.scenario import get_scenario
from formation_bench.optimizers import get_optimizer
from formation_bench.pipeline.outputs import read_trace, write_trace
from formation_bench.pipeline.runner import execute
from formation_bench.pipeline.spec import RunSpec
from formation_bench.pipeline.trace_columns import (
    TRACE_COLUMN_NAMES,
    TRACE_COLUMNS,
    Kind,
    Span,
    TraceFormatError,
    check_schema,
    columns_table,
)

REFERENCE = Path(__file__).parents[1] / "docs" / "_ext" / "formation_reference.py"


@pytest.fixture(scope="module")
def outcome():
    scenario = get_scenario("swarm-5", n_steps=6, settle_time_s=0.2, packet_loss=0.3)
    optimizer = get_optimizer("pso", max_iterations=2)
    spec = RunSpec.of("pso", optimizer, "swarm-5", scenario, trigger=True, seed=2**64 + 3)
    return execute(spec)


def test_the_documented_table_is_the_declared_one():
    """The documentation's reference page of the columns holds the declared table as it is."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("formation_reference", REFERENCE)
    reference = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(reference)
    page = reference.columns_page()
    assert columns_table() in page.split("## Trace columns", 1)[1]


def test_every_column_is_declared_once_with_a_meaning():
    assert len(set(TRACE_COLUMN_NAMES)) == len(TRACE_COLUMNS)
    assert all(column.doc for column in TRACE_COLUMNS)
    assert all(column.span is Span.RUN for column in TRACE_COLUMNS if column.kind is Kind.TEXT)


def test_a_run_writes_the_declared_columns_with_their_values(outcome):
    table, trace = outcome.table, outcome.trace
    check_schema(table.schema)
    assert table.column_names == list(TRACE_COLUMN_NAMES)
    assert str(table.schema.field("seed").type) == "large_string"  # 2^64 + 3 does not fit
    n_steps, n_uav = trace.controls.shape[:2]
    assert table.num_rows == (n_steps + 1) * n_uav
    frame = outcome.frame
    for column in TRACE_COLUMNS:
        if column.span is Span.RUN:
            continue
        values = frame[column.name].to_numpy().reshape(n_steps + 1, n_uav)
        if column.span is Span.PERIOD:  # the final state's row has nothing to show
            last = values[-1]
            assert np.all(np.isnan(last)) if column.kind is Kind.FLOAT else not last.any()
    np.testing.assert_array_equal(
        frame["plans_lost"].to_numpy().reshape(n_steps + 1, n_uav)[:-1], trace.plans_lost
    )
    np.testing.assert_array_equal(
        frame["y_m"].to_numpy().reshape(n_steps + 1, n_uav), trace.states[:, :, 1]
    )


def test_reading_checks_the_columns_against_the_declaration(outcome, tmp_path):
    path = tmp_path / "trace.parquet"
    write_trace(path, outcome.table)
    assert read_trace(path).equals(outcome.frame)
    for name, table, message in (
        ("missing", outcome.table.drop_columns(["wind_y_m_s"]), "missing wind_y_m_s"),
        (
            "extra",
            outcome.table.append_column("extra", pa.array(np.zeros(outcome.table.num_rows))),
            "unexpected extra",
        ),
        (
            "order",
            outcome.table.select([*TRACE_COLUMN_NAMES[1:], TRACE_COLUMN_NAMES[0]]),
            "out of order",
        ),
        (
            "type",
            outcome.table.set_column(
                outcome.table.column_names.index("nfev"),
                "nfev",
                pa.array(np.zeros(outcome.table.num_rows)),
            ),
            "'nfev' holds double, declared int64",
        ),
    ):
        damaged = tmp_path / f"{name}.parquet"
        pq.write_table(table, damaged)
        with pytest.raises(TraceFormatError, match=message):
            read_trace(damaged)
