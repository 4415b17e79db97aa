"""``formation-bench score`` over a split of the library, then ``report`` on its results.

The split library here is a small synthetic v2 built from v1 instances (every other one in
the test split, one marked degenerate), so the tests do not depend on the size of the
shipped v2; one test scores the whole shipped v1.
"""

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from formation_bench.analysis.score_report import write_score_report
from formation_bench.cli.main import main
from formation_bench.experiments import score
from formation_bench.experiments.errors import StoreError
from formation_bench.experiments.score import (
    SCORE_FORMAT,
    ScoreError,
    ScoreRun,
    execute_score,
    load_scores,
    score_runs,
    target_column,
)
from formation_bench.instances import library as library_module
from formation_bench.instances.library import PHASES, Library, load_shipped
from formation_bench.optimizers import Budget
from formation_bench.pipeline.spec import canonical_json

DEGENERATE = 1
"""The instance of the toy library marked degenerate (in the test split)."""
BUDGET = ["--budgets", "200"]


def split_library(size: int = 8) -> Library:
    """``size`` instances of v1 as a library with splits: odd positions test, even
    validation, instance :data:`DEGENERATE` degenerate."""
    base = load_shipped("v1")
    pick = np.linspace(0, len(base) - 1, size).astype(int)
    sub = Library("v1", base.manifest, {k: v[pick] for k, v in base.arrays.items()})
    instances = list(sub)
    arrays = dict(sub.arrays)
    arrays.update(
        neighbour_count=np.full(size, arrays["neighbour_positions"].shape[1], dtype=np.int16),
        centre_offset_sum=np.full((size, *arrays["reference"].shape[1:]), np.nan),
        has_centre_offset_sum=np.zeros(size, dtype=bool),
        content_hash=np.array([i.content_hash for i in instances]),
        warm_cost=np.array([i.warm_cost for i in instances]),
        degenerate=np.arange(size) == DEGENERATE,
        phase_index=np.array([PHASES.index(i.phase) for i in instances], dtype=np.int8),
        split_index=(np.arange(size) % 2).astype(np.int8),  # 0 validation, 1 test
    )
    return Library("v2", {**base.manifest, "format_version": 2}, arrays)


@pytest.fixture(scope="module")
def toy_v2():
    """The toy library served as the shipped v2 (in this process: ``--jobs 1``)."""
    toy = split_library()
    real = library_module.load_shipped

    def fake(version: str) -> Library:
        return toy if version == "v2" else real(version)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(library_module, "load_shipped", fake)
        patch.setattr(score, "load_shipped", fake)
        yield toy


def run_cli(*argv: str) -> int:
    try:
        return main(list(argv))
    except SystemExit as stop:  # argparse's refusals
        return int(stop.code)


@pytest.fixture(scope="module")
def scored(toy_v2, tmp_path_factory):
    out = str(tmp_path_factory.mktemp("score"))
    common = ["--library", "v2", *BUDGET, "--out", out, "--jobs", "1"]
    assert run_cli("score", "--optimizer", "pso", "--seeds", "0", "1", *common) == 0
    assert run_cli("score", "--optimizer", "modified-bso", "--split", "all", *common) == 0
    assert run_cli("score", "--optimizer", "pso-warm", *common) == 0
    return out


def test_score_solves_every_instance_of_its_split_degenerate_ones_included(scored, toy_v2):
    scores = load_scores(scored)
    pso = scores[scores["optimizer"] == "pso"]
    test = toy_v2.instances("test", degenerate=None)
    assert len(test) == 4 and any(i.degenerate for i in test)
    # default split: test, each seed
    assert len(pso) == 2 * len(test) and set(pso["split"]) == {"test"}
    assert set(pso["run_split"]) == {"test"} and set(pso["library"]) == {"v2"}
    every = scores[scores["optimizer"] == "modified-bso"]
    assert len(every) == len(toy_v2) and set(every["run_split"]) == {"all"}
    assert (scores["score_format"] == SCORE_FORMAT).all()
    for row in scores.to_dict("records"):
        instance = toy_v2[row["instance"]]
        assert row["content_hash"] == instance.content_hash
        assert (row["family"], row["phase"], row["split"]) == (
            instance.family,
            instance.phase,
            instance.split,
        )
        assert (row["degenerate"], row["warm_cost"]) == (instance.degenerate, instance.warm_cost)
        assert row["gap"] == pytest.approx(instance.gap(row["fun"]), rel=1e-12)
        hits = [row[target_column(t)] for t in score.TARGETS]
        if instance.degenerate:
            assert math.isnan(row["normalised_gap"]) and all(math.isnan(h) for h in hits)
        else:
            assert row["normalised_gap"] == pytest.approx(
                instance.normalised_gap(row["fun"]), rel=1e-12
            )
            assert row["normalised_gap"] >= -1e-6  # nothing beats J*
            # a target is reached within the evaluations used, and only at a lower gap
            for target, hit in zip(score.TARGETS, hits, strict=True):
                assert math.isnan(hit) or hit <= row["nfev"]
                if row["normalised_gap"] <= target:
                    assert hit <= row["nfev"]


def test_score_resumes(scored, capsys):
    argv = ["score", "--optimizer", "pso", "--library", "v2", *BUDGET, "--seeds", "0", "1"]
    assert run_cli(*argv, "--out", scored, "--jobs", "1") == 0
    assert "(0 new)" in capsys.readouterr().out


def test_the_split_is_part_of_a_run_but_all_keeps_the_key_of_before(toy_v2):
    runs = {
        split: score_runs("pso", {}, [Budget(200)], [0], library=toy_v2, split=split)[0]
        for split in ("test", "validation", "all")
    }
    assert len({run.key for run in runs.values()}) == 3
    assert len({run.entropy for run in runs.values()}) == 3
    assert score_runs("pso", {}, [Budget(200)], [0], library=toy_v2)[0].key == runs["test"].key
    # a run over a whole library has the identity (and key) runs had before splits
    legacy = {
        "optimizer": "pso",
        "optimizer_overrides": {},
        "max_evaluations": 200,
        "max_iterations": None,
        "deadline_ms": None,
        "seed": 0,
        "library": "v2",
    }
    assert runs["all"].identity() == legacy
    assert runs["test"].identity() == {**legacy, "split": "test"}
    assert ScoreRun("pso", "pso", canonical_json({}), Budget(200), 0, "v2").key == runs["all"].key


@pytest.mark.slow  # two worker processes on all 504 instances of v1: about 7 s
def test_a_score_run_over_v1_is_repeatable_and_independent_of_where_it_runs(tmp_path):
    out = str(tmp_path / "v1")
    argv = ["score", "--optimizer", "random-search", "--library", "v1", "--budgets", "20"]
    assert run_cli(*argv, "--seeds", "0", "1", "--out", out, "--jobs", "2") == 0
    stored = load_scores(out)
    v1 = load_shipped("v1")
    assert len(stored) == 2 * len(v1)  # v1 has no splits: all of it
    assert set(stored["run_split"]) == {"all"} and set(stored["split"]) == {""}
    (run,) = score_runs("random-search", {}, [Budget(20)], [1], library=v1)
    again = execute_score(run)
    stored = stored[stored["run_key"] == run.key].reset_index(drop=True)
    columns = ["instance", "content_hash", "fun", "gap", "normalised_gap", "nfev", "nit"]
    columns.append(target_column(1e-1))
    pd.testing.assert_frame_equal(again[columns], stored[columns], check_dtype=False)


def test_report_writes_a_leaderboard_per_split_and_its_tables(scored, toy_v2, capsys):
    # pso and pso-warm solved the test split, modified-bso all of the library: the test and
    # validation instances are reported apart, never pooled into one row
    report = f"{scored}/rep"
    assert run_cli("report", scored, "--out", report) == 0
    printed = capsys.readouterr().out
    assert "# Score on the instance library v2, test instances (runs over split all, test)" in (
        printed
    )
    assert "# Score on the instance library v2, validation instances (runs over split all)" in (
        printed
    )
    assert "solved instances of 2 splits (test, validation)" in printed
    assert "**Ranked by the median normalised gap**" in printed
    assert "score_phases.csv" in printed and "score_paired.csv" in printed
    summary = pd.read_csv(f"{report}/score_summary.csv")
    test_rows = summary[summary["split"] == "test"].set_index("optimizer")
    assert set(test_rows.index) == {"pso", "pso-warm", "modified-bso"}
    # the non-degenerate problems of the test split, each once, for every optimiser
    assert (test_rows["instances"] == 3).all() and test_rows["trials"]["pso"] == 2 * 3
    validation = summary[summary["split"] == "validation"].set_index("optimizer")
    assert list(validation.index) == ["modified-bso"]
    assert validation["instances"]["modified-bso"] == len(toy_v2) - 4
    assert set(summary["split"]) == {"test", "validation"}
    for _, rows in summary.groupby("split"):
        assert sorted(rows["rank"]) == sorted(rows["norm_gap_median"].rank(method="min"))
    for column in ("success_norm_1e-02", "success_norm_1e-03", "success_norm_1e-04"):
        assert summary[column].between(0, 1).all()
    assert (summary["success_norm_1e-02"] >= summary["success_norm_1e-04"]).all()
    degenerate = pd.read_csv(f"{report}/score_degenerate.csv").set_index("optimizer")
    assert (degenerate["instances"] == 1).all() and len(degenerate) == 3
    assert set(degenerate["split"]) == {"test"}
    phases = pd.read_csv(f"{report}/score_phases.csv")
    assert set(phases["phase"]) == set(PHASES) and len(phases) == (3 + 1) * len(PHASES)
    paired = pd.read_csv(f"{report}/score_paired.csv")
    # the leader: the smallest median normalised gap over the paired problems
    leader = test_rows["norm_gap_median"].sort_index().idxmin()
    others = sorted(o for o in ("pso", "pso-warm", "modified-bso") if o != leader)
    expected = [("pso", "modified-bso"), ("pso-warm", "modified-bso")]
    if leader != "modified-bso":
        expected += [(o, leader) for o in others]
    expected.append(("pso-warm", "pso"))
    assert list(zip(paired["x"], paired["y"], strict=True)) == expected
    assert set(paired["comparison"]) >= {"against modified-bso", "warm start against uniform start"}
    assert (paired["pairs"] == 3).all() and set(paired["split"]) == {"test"}
    ert = pd.read_csv(f"{report}/score_ert.csv")
    assert len(ert) == (3 + 1) * len(score.TARGETS)
    assert set(ert["target_norm_gap"]) == set(score.TARGETS)
    profile = pd.read_csv(f"{report}/score_profile.csv")
    steps = profile.groupby(["split", "budget", "optimizer"])["share"]
    assert steps.is_monotonic_increasing.all()
    for name in ("score_ecdf", "score_profile"):
        for split in ("test", "validation"):
            assert (Path(report) / "figures" / f"{name}_{split}.png").stat().st_size > 10_000


def test_a_report_of_one_split_has_no_split_column(scored, tmp_path):
    scores = load_scores(scored)
    only_test = scores[scores["run_split"] == "test"]
    write_score_report(only_test, tmp_path / "r", figures=False)
    summary = pd.read_csv(tmp_path / "r" / "score_summary.csv")
    assert "split" not in summary and set(summary["optimizer"]) == {"pso", "pso-warm"}
    assert "no row pools them" not in (tmp_path / "r" / "score.md").read_text()


def test_report_refuses_runs_of_an_older_score_format(scored, toy_v2, tmp_path, capsys):
    (run,) = score_runs("random-search", {}, [Budget(20)], [0], library=toy_v2)
    frame = execute_score(run, toy_v2).assign(score_format=SCORE_FORMAT - 1)
    with pytest.raises(StoreError, match=r"1 score run.* older score format"):
        write_score_report(frame, tmp_path / "r", figures=False)
    score.write_score(tmp_path / "old", run, frame)
    assert run_cli("report", str(tmp_path / "old"), "--no-figures") == 2
    err = capsys.readouterr().err
    assert "older score format" in err and len(err.strip().splitlines()) == 1


def test_score_refuses_a_split_the_library_does_not_have(tmp_path, capsys):
    out = str(tmp_path / "s")
    cases = [
        (["--library", "v1", "--split", "test"], "--split: 'test' is not a split of library v1"),
        (["--library", "v1", "--split", "validation"], "allowed: all"),
        (["--split", "every"], "argument --split: invalid choice: 'every' (choose from"),
        (["--library", "v3"], "argument --library: invalid choice: 'v3' (choose from"),
    ]
    for extra, needle in cases:
        assert run_cli("score", "--optimizer", "pso", *extra, "--out", out) == 2
        err = capsys.readouterr().err
        assert needle in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "s").exists()
    v1 = load_shipped("v1")
    with pytest.raises(ScoreError, match=r"--split: 'test' .* allowed: all"):
        score_runs("pso", {}, [None], [0], library=v1, split="test")
    assert score_runs("pso", {}, [None], [0], library=v1)[0].split == "all"


def test_split_choices_are_the_score_splits():
    from formation_bench.cli.main import build_parser

    parser = build_parser()
    (sub,) = [a for a in parser._actions if a.dest == "command"]
    actions = {a.dest: a for a in sub.choices["score"]._actions}
    assert tuple(actions["split"].choices) == score.SPLITS
    assert tuple(actions["library"].choices) == library_module.LIBRARY_VERSIONS


def test_score_refuses_bad_input(tmp_path, capsys):
    cases = [
        (["--optimizer", "psoo"], "--optimizer: unknown name 'psoo'"),
        (["--optimizer", "pso", "--budgets", "0"], "--budgets: must be 'default' or a number"),
        (["--optimizer", "pso", "--set", "population_size=1"], "population_size"),
    ]
    for extra, needle in cases:
        code = run_cli("score", *extra, "--out", str(tmp_path / "s"))
        assert code == 2
        err = capsys.readouterr().err
        assert needle in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "s").exists()


def test_a_run_stored_before_its_configuration_was_kept_is_kept_and_read_with_it_empty(
    toy_v2, tmp_path
):
    (run,) = score_runs("random-search", {}, [Budget(20)], [0], library=toy_v2)
    rows = execute_score(run, toy_v2)
    assert set(rows["config_hash"]) == {run.config_hash}
    assert '"class":"RandomSearch"' in rows["optimizer_config"].iloc[0]
    # a row of the same score format without the columns added since: kept, not redone
    score.write_score(tmp_path, run, rows.drop(columns=["config_hash", "optimizer_config"]))
    assert list(score.run_scores([run], tmp_path, jobs=1, library=toy_v2)) == []
    stored = load_scores(tmp_path)
    assert stored["config_hash"].isna().all() and stored["optimizer_config"].isna().all()
    columns = ["instance", "fun", "normalised_gap", "nfev"]
    pd.testing.assert_frame_equal(stored[columns], rows[columns])


def test_a_run_stored_with_other_settings_is_redone(toy_v2, tmp_path):
    (run,) = score_runs("random-search", {}, [Budget(20)], [0], library=toy_v2)
    rows = execute_score(run, toy_v2)
    score.write_score(tmp_path, run, rows.assign(config_hash="0" * 64))
    assert score.stored_keys(tmp_path) == {run.key}  # whole and sealed
    assert score.stored_keys(tmp_path, [run]) == set()  # but not of this configuration
    assert [r.key for r in score.run_scores([run], tmp_path, jobs=1, library=toy_v2)] == [run.key]
    assert set(load_scores(tmp_path)["config_hash"]) == {run.config_hash}


def test_a_score_deadline_is_a_budget_in_seconds_named_in_milliseconds(toy_v2):
    timed, capped = score_runs(
        "pso", {}, [Budget(deadline_s=0.002), Budget(200, deadline_s=0.002)], [0], library=toy_v2
    )
    optimizer = timed.optimizer()
    assert timed.identity()["deadline_ms"] == 2.0 and timed.identity()["max_evaluations"] is None
    assert timed.budget_label == "deadline_ms=2"
    assert capped.budget_label == "max_evaluations=200,deadline_ms=2"
    # a deadline alone keeps the optimiser's own limits
    own = optimizer.default_budget
    assert timed.budget_for(optimizer) == Budget(
        own.max_evaluations, own.max_iterations, deadline_s=0.002
    )
    assert (
        len({timed.key, capped.key, score_runs("pso", {}, [None], [0], library=toy_v2)[0].key}) == 3
    )


def test_a_failing_score_run_is_named_and_the_others_are_stored(
    toy_v2, tmp_path, monkeypatch, capsys
):
    real = score.execute_score

    def fails_on_seed_1(run, library=None):
        if run.seed == 1:
            raise RuntimeError("a solver that broke")
        return real(run, library)

    monkeypatch.setattr(score, "execute_score", fails_on_seed_1)
    out = str(tmp_path / "s")
    argv = ["score", "--optimizer", "random-search", "--library", "v2", "--budgets", "20"]
    assert run_cli(*argv, "--seeds", "0", "1", "--out", out, "--jobs", "1") == 1
    err = capsys.readouterr().err
    assert "failed: random-search / max_evaluations=20 / seed 1: RuntimeError: a solver" in err
    assert "1 of 2 score runs stored" in err and "Traceback" not in err
    assert set(load_scores(out)["seed"]) == {0}
