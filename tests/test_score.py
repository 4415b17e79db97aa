"""``formation-bench score`` on the shipped library, then ``report`` on its results."""

import math

import numpy as np
import pandas as pd
import pytest

from formation_bench.benchmarks.cli import main
from formation_bench.benchmarks.experiments.score import (
    execute_score,
    load_scores,
    score_runs,
    target_column,
)
from formation_bench.benchmarks.instances.library import shipped


@pytest.fixture(scope="module")
def scored(tmp_path_factory):
    out = tmp_path_factory.mktemp("score")
    for name in ("pso", "modified-bso"):
        argv = ["score", "--optimizer", name, "--budgets", "200", "default", "--seeds", "0", "1"]
        assert main([*argv, "--out", str(out), "--jobs", "2"]) == 0
    return out


def test_score_stores_one_row_per_instance_and_run_and_resumes(scored, capsys):
    scores = load_scores(scored)
    library = shipped()
    assert len(scores) == 2 * 2 * 2 * len(library)  # optimisers x budgets x seeds
    assert set(scores["budget"]) == {"max_evaluations=200", "default"}
    small = scores[scores["budget"] == "max_evaluations=200"]
    assert (small["nfev"] <= 200).all()
    # the gap is measured against the shipped J*, and nothing beats it
    j_star = np.array([library[k].j_star for k in small["instance"]])
    np.testing.assert_allclose(small["gap"], (small["fun"] - j_star) / j_star)
    assert small["gap"].min() >= -1e-6
    # a target reached is reached within the evaluations used
    reached = small[target_column(1e-1)].dropna()
    assert (reached <= small.loc[reached.index, "nfev"]).all()
    argv = ["score", "--optimizer", "pso", "--budgets", "200", "default", "--seeds", "0", "1"]
    assert main([*argv, "--out", str(scored)]) == 0
    assert "(0 new)" in capsys.readouterr().out


def test_a_score_run_is_repeatable_and_independent_of_where_it_runs(scored):
    (run,) = score_runs("pso", {}, [(200, None)], [1])
    again = execute_score(run)
    stored = load_scores(scored)
    stored = stored[stored["run_key"] == run.key].reset_index(drop=True)
    columns = ["instance", "fun", "gap", "nfev", "nit", target_column(1e-2)]
    pd.testing.assert_frame_equal(again[columns], stored[columns], check_dtype=False)


def test_report_writes_the_score_statistics(scored, capsys):
    assert main(["report", str(scored), "--out", str(scored / "rep")]) == 0
    printed = capsys.readouterr().out
    assert "# Score on the instance library v1" in printed and "## budget default" in printed
    folder = scored / "rep"
    summary = pd.read_csv(folder / "score_summary.csv")
    assert set(summary["optimizer"]) == {"pso", "modified-bso"}
    assert (summary["trials"] == 2 * len(shipped())).all()
    for column in ("success_1e-02", "success_1e-03", "success_1e-04"):
        assert summary[column].between(0, 1).all()
    assert (summary["success_1e-02"] >= summary["success_1e-04"]).all()
    ert = pd.read_csv(folder / "score_ert.csv")
    assert len(ert) == 4 * 6
    finite = ert["ert_evaluations"].replace(math.inf, np.nan).dropna()
    assert (finite > 0).all()
    profile = pd.read_csv(folder / "score_profile.csv")
    assert profile.groupby(["budget", "optimizer"])["share"].is_monotonic_increasing.all()
    for name in ("score_ecdf.png", "score_profile.png"):
        assert (folder / "figures" / name).stat().st_size > 10_000


def test_score_refuses_bad_input(tmp_path, capsys):
    cases = [
        (["--optimizer", "psoo"], "--optimizer: unknown name 'psoo'"),
        (["--optimizer", "pso", "--budgets", "0"], "--budgets: must be 'default' or a number"),
        (["--optimizer", "pso", "--set", "population_size=1"], "population_size"),
    ]
    for extra, needle in cases:
        try:
            code = main(["score", *extra, "--out", str(tmp_path / "s")])
        except SystemExit as stop:
            code = stop.code
        assert code == 2
        err = capsys.readouterr().err
        assert needle in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "s").exists()
