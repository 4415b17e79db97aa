"""Score rows with their improvement history, and ``formation-bench export-ioh``."""

import json
import zipfile

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from formation_bench.analysis import ioh_export
from formation_bench.analysis.scoring import (
    TARGETS,
    evaluations_to_target,
    normalised_gap,
)
from formation_bench.cli.main import main
from formation_bench.experiments import score
from formation_bench.instances.library import Library, load_shipped
from formation_bench.optimizers import Budget
from formation_bench.pipeline.record import is_timing_column

ioh = pytest.importorskip("ioh")

RUNS = (("pso", [0, 1]), ("cma-es", [0]))
BUDGET = 300


def small_library(size: int = 6) -> Library:
    """A few instances of library v1, spread over its scenarios and triggers; with 6, one
    of them (v1's 402) is degenerate."""
    library = load_shipped("v1")
    pick = np.linspace(0, len(library) - 1, size).astype(int)
    return Library(
        library.version, library.manifest, {k: v[pick] for k, v in library.arrays.items()}
    )


def test_the_small_library_holds_a_degenerate_instance():
    assert [i.degenerate for i in small_library()] == [False] * 4 + [True, False]


@pytest.fixture(scope="module")
def scored(tmp_path_factory):
    out = tmp_path_factory.mktemp("ioh")
    library = small_library()
    for name, seeds in RUNS:
        for run in score.score_runs(name, {}, [Budget(BUDGET)], seeds, library=library):
            score.write_score(out, run, score.execute_score(run, library))
    return out


def parse_dat(path):
    """The runs of a .dat file: its header lines and (evaluations, raw_y) arrays."""
    headers, runs = [], []
    for line in path.read_text().splitlines():
        if not line[0].isdigit():
            headers.append(line)
            runs.append([])
        else:
            n, y = line.split()
            runs[-1].append((int(n), float(y)))
    return headers, [np.array(r) for r in runs]


def test_score_rows_keep_the_improvements_of_the_best_cost(scored):
    rows = score.load_scores(scored)
    library = small_library()
    assert (rows["score_format"] == score.SCORE_FORMAT).all()
    for row in rows.to_dict("records"):
        nfev, fun = row["improvement_nfev"], row["improvement_fun"]
        assert len(nfev) == len(fun) >= 1
        assert (np.diff(nfev) > 0).all() and (np.diff(fun) < 0).all()
        assert nfev[-1] <= row["nfev"] and fun[-1] == row["fun"]
        assert len(row["x"]) == library[row["instance"]].warm_start.size
        # the improvements alone give the stored evaluations to every normalised target
        for target in TARGETS:
            hit = evaluations_to_target(nfev, fun, row["j_star"], row["warm_cost"], target)
            if row["degenerate"]:
                hit = np.nan
            stored = row[score.target_column(target)]
            assert hit == stored or (np.isnan(hit) and np.isnan(stored))
    # and they are the points where the full history of the solve fell to a new low
    (run,) = score.score_runs("pso", {}, [Budget(BUDGET)], [1], library=library)
    instance = library[2]
    rng = np.random.default_rng(np.random.SeedSequence([run.entropy, instance.index]))
    optimizer = run.optimizer()
    problem = instance.problem
    result = optimizer.minimize(
        problem, problem.bounds, rng, run.budget_for(optimizer), instance.warm_start
    )
    stored = rows[(rows["run_key"] == run.key) & (rows["instance"] == 2)].iloc[0]
    new_low = np.r_[True, np.diff(result.history_fun) < 0]
    np.testing.assert_array_equal(stored["improvement_nfev"], result.history_nfev[new_low])
    np.testing.assert_array_equal(stored["improvement_fun"], result.history_fun[new_low])
    np.testing.assert_array_equal(stored["x"], result.x)


def test_runs_stored_in_an_older_format_are_redone(tmp_path, monkeypatch):
    library = small_library(2)
    monkeypatch.setattr(score, "load_shipped", lambda version: library)
    (run,) = score.score_runs("random-search", {}, [Budget(50)], [0], library=library)
    path = score.write_score(tmp_path, run, score.execute_score(run, library))
    assert score.stored_keys(tmp_path) == {run.key}
    old = pd.read_parquet(path).drop(columns=["improvement_nfev", "improvement_fun", "x"])
    old.drop(columns="score_format").to_parquet(path)  # format 1, unsealed
    assert score.stored_keys(tmp_path) == set()
    # format 2, sealed: without the normalised gap and its columns
    format2 = old.drop(columns=["normalised_gap", "warm_cost", "degenerate", "content_hash"])
    score.write_score(tmp_path, run, format2.assign(score_format=2))
    assert score.stored_keys(tmp_path) == set()
    assert [r.key for r in score.run_scores([run], tmp_path, jobs=1)] == [run.key]
    assert score.stored_keys(tmp_path) == {run.key}
    again = pd.read_parquet(path)
    timings = [c for c in old.columns if c == "seconds" or is_timing_column(c)]
    pd.testing.assert_frame_equal(
        again[old.columns].drop(columns=timings), old.drop(columns=timings)
    )
    assert [r.key for r in score.run_scores([run], tmp_path, jobs=1)] == []


def test_export_holds_every_run_with_its_stored_history(scored, capsys):
    assert main(["export-ioh", str(scored), "--out", str(scored / "ioh"), "--zip"]) == 0
    printed = capsys.readouterr().out
    # 3 solves of the degenerate instance (pso seeds 0, 1; cma-es seed 0) left out
    assert "2 algorithms, 15 runs (3 solves of degenerate instances left out)" in printed
    assert "raw_y is the normalised gap" in printed
    rows = score.load_scores(scored)
    rows = rows[~rows["degenerate"]]
    folders = sorted(p.name for p in (scored / "ioh").iterdir())
    assert folders == [f"cma-es@max_evaluations={BUDGET}", f"pso@max_evaluations={BUDGET}"]
    for name, seeds in RUNS:
        folder = scored / "ioh" / f"{name}@max_evaluations={BUDGET}"
        meta = json.loads((folder / "IOHprofiler_f1_formation_library_v1.json").read_text())
        assert meta["algorithm"]["name"] == f"{name} @ max_evaluations={BUDGET}"
        assert (meta["function_id"], meta["function_name"]) == (1, "formation_library_v1")
        assert meta["maximization"] is False and meta["attributes"] == ["evaluations", "raw_y"]
        (scenario,) = meta["scenarios"]
        assert scenario["dimension"] == 10
        headers, lines = parse_dat(folder / scenario["path"])
        mine = rows[rows["optimizer"] == name].sort_values(["seed", "instance"])
        assert len(headers) == len(lines) == len(scenario["runs"]) == len(mine) == 5 * len(seeds)
        assert set(headers) == {"evaluations raw_y"}
        for run, data, row in zip(scenario["runs"], lines, mine.itertuples(), strict=True):
            assert (run["instance"], run["seed"], run["evals"]) == (
                row.instance,
                row.seed,
                row.nfev,
            )
            assert run["j_star"] == row.j_star and run["warm_cost"] == row.warm_cost
            assert run["best"]["y"] == row.normalised_gap
            assert run["best"]["x"] == list(row.x)
            gaps = normalised_gap(np.asarray(row.improvement_fun), row.j_star, row.warm_cost)
            k = len(row.improvement_nfev)
            np.testing.assert_array_equal(data[:k, 0], row.improvement_nfev)
            np.testing.assert_array_equal(data[:k, 1], gaps)  # full precision, read back exactly
            # then the last evaluation, unless the last improvement was at it
            assert len(data) == k + (row.nfev > row.improvement_nfev[-1])
            assert tuple(data[-1]) == (row.nfev, row.normalised_gap)
    with zipfile.ZipFile(scored / "ioh.zip") as zipped:
        names = sorted(zipped.namelist())
    assert names == sorted(
        p.relative_to(scored / "ioh").as_posix() for p in (scored / "ioh").rglob("*") if p.is_file()
    )


def test_layout_matches_what_the_ioh_logger_writes(scored, tmp_path):
    """Replay the stored cma-es solves (whose first record is the first evaluation) through
    ``ioh``'s own Analyzer logger and compare with the export."""
    rows = score.load_scores(scored)
    rows = rows[(rows["optimizer"] == "cma-es") & ~rows["degenerate"]]
    rows = rows.sort_values(["seed", "instance"])
    assert (rows["improvement_nfev"].map(lambda n: n[0]) == 1).all()
    algorithm = f"cma-es @ max_evaluations={BUDGET}"
    logger = ioh.logger.Analyzer(
        root=str(tmp_path),
        folder_name="logged",
        algorithm_name=algorithm,
        algorithm_info="info",
        triggers=[ioh.logger.trigger.ON_IMPROVEMENT],
    )

    class Run:
        seed = 0.0
        j_star = 0.0
        warm_cost = 0.0

    now = Run()
    logger.add_run_attributes(now, list(ioh_export.RUN_ATTRIBUTES))
    logger.set_experiment_attributes({"library": "v1"})
    for row in rows.itertuples():
        # the recorded best so far as a function of the evaluation count
        gaps = normalised_gap(row.improvement_fun, row.j_star, row.warm_cost)
        steps = dict(zip(row.improvement_nfev, gaps, strict=True))
        best, recorded = np.inf, []
        for n in range(1, row.nfev + 1):
            best = steps.get(n, best)
            recorded.append(best)
        values = iter(recorded)
        problem = ioh.wrap_problem(
            lambda x, values=values: float(next(values)),
            name="formation_library_v1",
            dimension=len(row.x),
            instance=int(row.instance),
            lb=-1e9,
            ub=1e9,
        )
        problem.set_id(1)
        problem.attach_logger(logger)
        now.seed, now.j_star, now.warm_cost = float(row.seed), float(row.j_star), row.warm_cost
        for _ in range(row.nfev):
            problem(np.asarray(row.x))
        problem.reset()
    logger.close()

    logged_folder = tmp_path / "logged"
    assert main(["export-ioh", str(scored), "--out", str(tmp_path / "mine")]) == 0
    mine_folder = tmp_path / "mine" / f"cma-es@max_evaluations={BUDGET}"

    def files(folder):
        return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())

    assert files(mine_folder) == files(logged_folder)
    name = "IOHprofiler_f1_formation_library_v1.json"
    logged = json.loads((logged_folder / name).read_text())
    mine = json.loads((mine_folder / name).read_text())
    assert logged["version"] == ioh_export.IOH_FORMAT_VERSION, (
        f"the installed ioh {ioh.__version__} writes format version {logged['version']}, the "
        f"export writes {ioh_export.IOH_FORMAT_VERSION}'s: compare the layouts, then update "
        "IOH_FORMAT_VERSION"
    )
    assert mine["version"] == logged["version"]
    assert list(mine) == list(logged)  # the same keys in the same order
    for key in ("function_id", "function_name", "maximization", "attributes", "run_attributes"):
        assert mine[key] == logged[key]
    assert list(mine["algorithm"]) == list(logged["algorithm"])
    assert mine["algorithm"]["name"] == logged["algorithm"]["name"]
    # experiment attributes: a list of one-key objects in both
    assert logged["experiment_attributes"] == [{"library": "v1"}]
    assert all(len(a) == 1 for a in mine["experiment_attributes"])
    (logged_scenario,), (mine_scenario,) = logged["scenarios"], mine["scenarios"]
    assert list(mine_scenario) == list(logged_scenario)
    assert mine_scenario["path"] == logged_scenario["path"]
    for a, b in zip(mine_scenario["runs"], logged_scenario["runs"], strict=True):
        assert list(a) == list(b) and list(a["best"]) == list(b["best"])
        for key in ("instance", "evals", "seed", "j_star", "warm_cost"):
            assert a[key] == b[key]
        assert a["best"]["evals"] == b["best"]["evals"]
        assert a["best"]["y"] == pytest.approx(b["best"]["y"], rel=1e-12, abs=1e-15)
    # the data files: the same header and lines; the logger prints ten decimals
    logged_headers, logged_runs = parse_dat(logged_folder / logged_scenario["path"])
    mine_headers, mine_runs = parse_dat(mine_folder / mine_scenario["path"])
    assert mine_headers == logged_headers
    for a, b in zip(mine_runs, logged_runs, strict=True):
        np.testing.assert_array_equal(a[:, 0], b[:, 0])
        np.testing.assert_allclose(a[:, 1], b[:, 1], rtol=0, atol=6e-11)


def test_export_refuses_bad_input(scored, tmp_path, capsys):
    old = tmp_path / "old"
    (old / "score").mkdir(parents=True)
    source = sorted((scored / "score").glob("*.parquet"))[0]
    frame = pd.read_parquet(source).drop(columns=["improvement_nfev", "improvement_fun", "x"])
    frame.to_parquet(old / "score" / source.name)
    older = tmp_path / "older"  # a run of score format 2 (no normalised gap)
    (older / "score").mkdir(parents=True)
    pd.read_parquet(source).assign(score_format=2).to_parquet(older / "score" / source.name)
    (tmp_path / "taken").mkdir()
    (tmp_path / "taken" / "file").write_text("x")
    cases = [
        ([str(tmp_path / "none")], "holds no score runs"),
        ([str(old), "--out", str(tmp_path / "o")], "stored without the improvement history"),
        ([str(older), "--out", str(tmp_path / "o")], "1 score run(s) were stored in an older"),
        ([str(scored), "--out", str(tmp_path / "taken")], "folder exists and is not empty"),
    ]
    for argv, needle in cases:
        assert main(["export-ioh", *argv]) == 2
        err = capsys.readouterr().err
        assert needle in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()
    assert pq.read_table(old / "score" / source.name).num_rows == len(frame)
