"""The tune command: its search space, its determinism (resume after SIGKILL, any --jobs), the
data it may not touch, and the tuned variants it writes and registers."""

from __future__ import annotations

import importlib.util
import json
import os
import random
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from formation_bench.cli.main import main
from formation_bench.experiments import score
from formation_bench.fields import Search, setting
from formation_bench.instances.library import Library
from formation_bench.optimizers import OPTIMIZERS, get_optimizer
from formation_bench.optimizers.registry import RegisteredOptimizer
from formation_bench.optimizers.tuned import _TUNED, register_tuned, tuned_optimizer
from formation_bench.tuning import objectives
from formation_bench.tuning.settings import TuningSettings, shipped_suite_seeds
from formation_bench.tuning.space import numeric_range, search_space, suggest
from formation_bench.tuning.study import run_tuning

optuna = pytest.importorskip("optuna")

TUNABLE = Path(__file__).parent / "data" / "tunable_pso.py"
QUICK = {"trials": 6, "batch": 2, "max_evaluations": 300, "problems": 8, "seed": 100}
"""A tuning of a second or so: few trials, a small budget, the split's first problems."""


def _tunable_module():
    spec = importlib.util.spec_from_file_location("tunable_pso_for_tests", TUNABLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


TUNABLE_MODULE = _tunable_module()


@pytest.fixture
def tunable(monkeypatch):
    """``tunable-pso`` in the registry for the test's duration."""
    name = TUNABLE_MODULE.NAME
    entry = RegisteredOptimizer(name, TUNABLE_MODULE.TunablePSO(), TUNABLE_MODULE.DESCRIPTION)
    monkeypatch.setitem(OPTIMIZERS, name, entry)
    return name


def quick(**changes) -> TuningSettings:
    return TuningSettings(**{"optimizer": "tunable-pso", **QUICK, **changes})


def result_of(path: Path) -> tuple[dict, list]:
    data = json.loads(path.read_text())
    return data["values"], data["history"]


# --- the search space ----------------------------------------------------------------------


def searched_names() -> list[str]:
    """Every registered optimiser with searched settings (the families' own, once declared)."""
    return [
        name for name in sorted(OPTIMIZERS) if search_space(OPTIMIZERS[name].optimizer)
    ] + [TUNABLE_MODULE.NAME]


@pytest.mark.parametrize("name", searched_names())
def test_every_sampled_configuration_is_valid(name, tunable):
    base = get_optimizer(name)
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=7))
    for _ in range(5):
        trial = study.ask()
        values = suggest(trial, name, base)
        configured = get_optimizer(name, **values)  # valid, or this raises
        assert set(values) == {field.name for field in search_space(base)}
        study.tell(trial, 0.0)
        if name == tunable:  # a limit naming an earlier field reads the suggested value
            assert configured.inertia_end <= configured.inertia_start


def test_a_searched_range_is_clipped_into_the_valid_one():
    class Config:
        wide: float = setting(
            0.5, low=0.0, high=1.0, low_open=True, doc="x", search=Search(-3.0, 7.0)
        )

    import dataclasses

    config = dataclasses.dataclass(frozen=True)(Config)()
    (field,) = search_space(config)
    low, high = numeric_range(field, type("P", (), {})())
    assert 0.0 < low and high == 1.0


# --- determinism: resume and workers ---------------------------------------------------------


def test_a_tuning_stopped_within_a_batch_resumes_to_the_uninterrupted_result(tunable, tmp_path):
    # past TPE's 10 random start-up trials, so that the trials before a batch matter
    whole = run_tuning(quick(trials=13), tmp_path / "whole")
    # trials 0-10 stored, then trial 11 (the second of batch 10-11) is asked again on resume
    run_tuning(quick(trials=11), tmp_path / "resumed")
    resumed = run_tuning(quick(trials=13), tmp_path / "resumed")
    assert resumed.computed
    assert result_of(resumed.path) == result_of(whole.path)
    assert whole.data["history"][0] == whole.data["default_value"]
    assert len(set(whole.data["history"])) > 1  # the trials differ: the check could fail


def test_a_finished_tuning_is_printed_again_without_computing(tunable, tmp_path, capsys):
    out = tmp_path / "t"
    args = ["tune", "--optimizer", tunable, "--trials", "2", "--batch", "2", "--problems", "4",
            "--max-evaluations", "300", "--out", str(out), "--jobs", "1", "--no-progress"]  # fmt: skip  # noqa: E501
    assert main(args) == 0
    first = (out / "tunable-pso-tuned.json").read_bytes()
    capsys.readouterr()
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "nothing computed" in printed and "inertia_start" in printed
    assert (out / "tunable-pso-tuned.json").read_bytes() == first


def test_a_folder_holding_other_settings_is_refused(tunable, tmp_path, capsys):
    out = tmp_path / "t"
    run_tuning(quick(trials=2), out)
    args = ["tune", "--optimizer", tunable, "--trials", "2", "--batch", "2", "--problems", "4",
            "--max-evaluations", "400", "--out", str(out), "--jobs", "1"]  # fmt: skip
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--out" in err and "other settings" in err


@pytest.mark.slow
def test_the_same_result_with_one_and_two_workers(tunable, tmp_path):
    one = run_tuning(quick(trials=12), tmp_path / "one", jobs=1)
    two = run_tuning(quick(trials=12), tmp_path / "two", jobs=2, plugins=(str(TUNABLE),))
    assert result_of(one.path) == result_of(two.path)


def _tune_command(out: Path) -> list[str]:
    return [
        sys.executable, "-m", "formation_bench.cli", "--plugin", str(TUNABLE), "tune",
        "--optimizer", "tunable-pso", "--trials", "14", "--batch", "2", "--problems", "40",
        "--max-evaluations", "300", "--seed", "100", "--jobs", "1", "--no-progress",
        "--out", str(out),
    ]  # fmt: skip


def _killed_after(out: Path, stored: int) -> None:
    """Start the tuning and SIGKILL it as soon as it says ``stored`` trials are stored (in the
    middle of the next batch: asking, evaluating or storing); it must not have finished."""
    process = subprocess.Popen(_tune_command(out), stderr=subprocess.PIPE, text=True)
    assert process.stderr is not None
    for line in process.stderr:
        if line.startswith(f"trials {stored}/"):
            process.send_signal(signal.SIGKILL)
            break
    process.wait()
    assert process.returncode == -signal.SIGKILL
    assert not (out / "tunable-pso-tuned.json").exists()


@pytest.mark.slow
def test_a_tuning_killed_at_several_points_ends_as_an_uninterrupted_one(tmp_path):
    whole = tmp_path / "whole"
    subprocess.run(_tune_command(whole), check=True, capture_output=True)
    resumed = tmp_path / "resumed"
    # a kill point among TPE's random start-up trials, then one where it models the trials
    first = random.Random(3).choice((4, 6))
    for stored in (first, first + 6):
        _killed_after(resumed, stored)
    done = subprocess.run(_tune_command(resumed), check=True, capture_output=True, text=True)
    assert "tunable-pso-tuned" in done.stdout
    name = "tunable-pso-tuned.json"
    assert result_of(resumed / name) == result_of(whole / name)


# --- the data a tuning may not touch --------------------------------------------------------


def test_a_tuning_solves_validation_problems_only(tunable, tmp_path, monkeypatch):
    asked, solved = [], []
    instances = Library.instances

    def spied_instances(self, split=None, **kwargs):
        asked.append(split)
        return instances(self, split, **kwargs)

    def spied_solve(optimizer, instance, entropy, budget):
        solved.append(instance.split)
        return score.solve_instance(optimizer, instance, entropy, budget)

    monkeypatch.setattr(Library, "instances", spied_instances)
    monkeypatch.setattr(objectives, "solve_instance", spied_solve)
    objectives.validation_instances.cache_clear()
    run_tuning(quick(trials=2), tmp_path / "t")
    objectives.validation_instances.cache_clear()
    assert asked and set(asked) == {"validation"}
    assert solved and set(solved) == {"validation"}


@pytest.mark.slow
def test_a_loop_tuning_runs_no_seed_of_a_results_page(tunable, tmp_path, monkeypatch):
    seeds = []
    execute = objectives.execute

    def spied(spec, **kwargs):
        seeds.append(spec.seed)
        return execute(spec, **kwargs)

    monkeypatch.setattr(objectives, "execute", spied)
    settings = quick(trials=1, objective="loop", seeds=(1000,))
    run_tuning(settings, tmp_path / "t")
    assert seeds == [1000]
    assert not set(seeds) & shipped_suite_seeds()


REFUSED = [
    (["--split", "test"], "--split"),
    (["--split", "all"], "--split"),
    (["--seed", "0"], "--seed"),
    (["--seed", "29"], "--seed"),
    (["--objective", "loop", "--seeds", "1000", "7"], "--seeds"),
    (["--objective", "loop", "--suite", "trigger"], "--suite"),
    (["--objective", "loop", "--metric", "wall_time_s"], "--metric"),
]


def _id(value: object) -> str | None:
    return " ".join(value) if isinstance(value, list) else None


@pytest.mark.parametrize(("extra", "needle"), REFUSED, ids=_id)
def test_test_problems_and_results_seeds_are_refused_before_any_work(
    extra, needle, tunable, tmp_path, capsys
):
    out = tmp_path / "t"
    assert main(["tune", "--optimizer", tunable, *extra, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert err.startswith("formation-bench tune: error: " + needle), err
    assert not out.exists()


def test_an_optimizer_with_nothing_to_search_is_refused(tmp_path, capsys):
    plain = next(n for n in sorted(OPTIMIZERS) if not search_space(OPTIMIZERS[n].optimizer))
    assert main(["tune", "--optimizer", plain, "--out", str(tmp_path / "t")]) == 2
    assert "declare search=" in capsys.readouterr().err


def test_without_optuna_the_command_names_the_extra(monkeypatch, tmp_path, capsys):
    from formation_bench.cli import tune_command

    real = importlib.util.find_spec
    monkeypatch.setattr(
        tune_command.importlib.util, "find_spec", lambda n: None if n == "optuna" else real(n)
    )
    assert main(["tune", "--optimizer", "pso", "--out", str(tmp_path / "t")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'pip install "formation-bench[tune]"' in err


def test_importing_the_package_imports_no_optuna():
    code = (
        "import sys, formation_bench, formation_bench.optimizers, formation_bench.cli.main\n"
        "print('optuna' in sys.modules)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "False"


# --- the tuned variant ------------------------------------------------------------------------


def test_a_tuned_file_registers_and_lists_its_values_and_provenance(
    tunable, tmp_path, monkeypatch, capsys
):
    outcome = run_tuning(quick(trials=4), tmp_path / "t", command="formation-bench tune ...")
    data = outcome.data
    assert data["name"] == "tunable-pso-tuned" and data["base"] == tunable
    assert data["history"][0] == data["default_value"]
    assert data["best_value"] == min(data["history"])
    assert data["values"]["max_iterations"] == (300 - 30) // 30  # the budget, in iterations
    monkeypatch.setattr(OPTIMIZERS, "_entries", dict(OPTIMIZERS._entries))
    monkeypatch.setattr("formation_bench.optimizers.tuned._TUNED", dict(_TUNED))
    tuned = register_tuned(outcome.path)
    assert tuned == tuned_optimizer(data)
    assert main(["list", "--fields", "tunable-pso-tuned"]) == 0
    listed = capsys.readouterr().out
    value = data["values"]["inertia_start"]
    assert f"inertia_start = {value!r}" in listed
    for needle in ("tuner: optuna", "seed 100", "split validation", "300 evaluations", "commit"):
        assert needle in listed, listed
    # a tuned variant is not tuned again
    assert main(["tune", "--optimizer", "tunable-pso-tuned", "--out", str(tmp_path / "u")]) == 2
    assert "tuned variant" in capsys.readouterr().err


def test_a_tuned_file_of_an_unknown_base_is_refused(tmp_path):
    path = tmp_path / "x-tuned.json"
    path.write_text(json.dumps({"format": 1, "name": "x-tuned", "base": "no-such", "values": {}}))
    with pytest.raises(ValueError, match="no-such"):
        register_tuned(path)


@pytest.mark.skipif(os.name != "posix", reason="the journal's file lock")
def test_trial_zero_is_the_base_configuration(tunable, tmp_path):
    outcome = run_tuning(quick(trials=1), tmp_path / "t")
    journal = optuna.storages.journal.JournalFileBackend(
        str(tmp_path / "t" / "tunable-pso-tuned.journal")
    )
    study = optuna.load_study(
        study_name="tunable-pso-tuned", storage=optuna.storages.JournalStorage(journal)
    )
    base = get_optimizer(tunable)
    params = study.trials[0].params
    assert params["inertia_start"] == base.inertia_start
    assert params["bound_handling"] == "clip"
    assert outcome.data["best_value"] == outcome.data["default_value"]
