"""The Dask path: a small suite on a LocalCluster gives the local path's results."""

import sys
import time

import pandas as pd
import pytest

from formation_bench.cli.main import main
from formation_bench.experiments.executors import SCHEDULER_TIMEOUT_S
from formation_bench.experiments.store import load_results
from formation_bench.experiments.suite import parse_suite
from formation_bench.experiments.sweep import SweepError, run_sweep
from formation_bench.pipeline.record import is_timing_column

distributed = pytest.importorskip("dask.distributed")

SUITE = """\
name = "dask"
seeds = 3
triggers = [true, false]

[[optimizers]]
name = "modified-bso"
overrides = { max_iterations = 3 }

[[optimizers]]
name = "modified-bso-no-chaos-replacement"
label = "no-chaos-replacement-3"
overrides = { max_iterations = 3 }

[[scenarios]]
name = "paper"
overrides = { n_steps = 10, settle_time_s = 1.0 }
"""


def deterministic(frame: pd.DataFrame) -> pd.DataFrame:
    keep = [c for c in frame.columns if not is_timing_column(c)]
    return frame[keep].sort_values("run_key").reset_index(drop=True)


@pytest.mark.slow
def test_dask_local_cluster_matches_the_local_path(tmp_path):
    suite_file = tmp_path / "dask.toml"
    suite_file.write_text(SUITE)
    suite = parse_suite(SUITE, suite_file)
    local = tmp_path / "local"
    run_sweep(suite, local, jobs=1, progress=False, log=lambda _: None)

    with (
        distributed.LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            host="127.0.0.1",
        ) as cluster,
        distributed.Client(cluster) as client,
    ):
        out = tmp_path / "dask"
        code = main(["sweep", str(suite_file), "--out", str(out), "--scheduler",
                     cluster.scheduler_address, "--no-progress"])  # fmt: skip
        assert code == 0
        hosts = load_results(out)["worker_pid"].unique()
        worker_pids = set(client.run(lambda: __import__("os").getpid()).values())
        assert set(hosts) <= worker_pids
        # resume through the cluster: nothing left to do
        summary = run_sweep(
            suite, out, scheduler=cluster.scheduler_address, progress=False, log=lambda _: None
        )
        assert summary.already == 12 and summary.stored == 0

    got = load_results(out)
    assert len(got) == 12
    pd.testing.assert_frame_equal(
        deterministic(got), deterministic(load_results(local)), check_exact=True
    )


def test_an_unreachable_scheduler_is_a_quick_one_line_error_and_leaves_no_folder(tmp_path):
    suite = parse_suite(SUITE, tmp_path / "dask.toml")
    start = time.monotonic()
    with pytest.raises(SweepError, match="cannot reach a Dask scheduler") as info:
        run_sweep(
            suite,
            tmp_path / "o",
            scheduler="tcp://127.0.0.1:1",
            progress=False,
            log=lambda _: None,
        )
    # refused at once, not after the client's own timeout
    assert time.monotonic() - start < SCHEDULER_TIMEOUT_S / 2
    assert "\n" not in str(info.value)
    assert not (tmp_path / "o").exists()


def test_without_the_dask_extra_the_scheduler_option_names_it_and_leaves_no_folder(
    tmp_path, monkeypatch, capsys
):
    suite_file = tmp_path / "dask.toml"
    suite_file.write_text(SUITE)
    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # what a missing extra raises
    out = tmp_path / "o"
    code = main(["sweep", str(suite_file), "--out", str(out), "--scheduler", "tcp://host:8786"])
    assert code == 2
    assert capsys.readouterr().err == (
        'formation-bench sweep: error: --scheduler needs the dask extra: pip install ".[dask]" '
        "(import failed: import of dask.distributed halted; None in sys.modules)\n"
    )
    assert not out.exists()


@pytest.mark.slow
def test_no_live_worker_for_the_timeout_stops_with_one_line_and_resumes(tmp_path, capsys):
    suite_file = tmp_path / "dask.toml"
    suite_file.write_text(SUITE)
    out = tmp_path / "o"
    with distributed.LocalCluster(
        n_workers=0, processes=True, dashboard_address=None, host="127.0.0.1"
    ) as cluster:
        start = time.monotonic()
        code = main(["sweep", str(suite_file), "--out", str(out), "--no-progress", "--scheduler",
                     cluster.scheduler_address, "--worker-timeout", "1"])  # fmt: skip
        waited = time.monotonic() - start
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert err[-1] == (
        f"formation-bench sweep: error: --scheduler: no live Dask worker at "
        f"{cluster.scheduler_address} for 1 s (--worker-timeout); stopped: 0 of 12 runs in "
        f"{out}; start workers and run the same command again"
    )
    assert 1 <= waited < 30
    # the folder is a resumable one: the next sweep, with workers, finishes it
    assert run_sweep(parse_suite(SUITE, suite_file), out, jobs=1, progress=False,
                     log=lambda _: None).stored == 12  # fmt: skip
