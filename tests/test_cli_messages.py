"""What the command line says to a reader: the overview, each command's help, the misplaced
``--plugin``, the way from ``sweep`` to ``report``, ``reproduce``'s table and last line, and the
compile notice. Each test runs the real entry point and reads the text a user sees."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from formation_bench.analysis.paper import PAPER_FIGURES
from formation_bench.analysis.paper_budget import shipped_line
from formation_bench.cli.common import first_sentence
from formation_bench.cli.main import START_HINT, build_parser, main

COMMANDS = ("reproduce", "run", "list", "sweep", "score", "report", "export-ioh", "tune")


def command_line(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``python -m formation_bench.cli.main ARGS`` in a process of its own."""
    return subprocess.run(
        [sys.executable, "-m", "formation_bench.cli.main", *args],
        capture_output=True, text=True, timeout=600, env=env,
    )  # fmt: skip


def descriptions() -> dict[str, str]:
    parser = build_parser()
    assert parser.commands is not None
    return {name: command.description for name, command in parser.commands.choices.items()}


# --- no command: the overview ----------------------------------------------------------------


def test_without_a_command_the_overview_goes_to_stderr_with_exit_2():
    done = command_line()
    assert done.returncode == 2 and done.stdout == ""
    lines = done.stderr.splitlines()
    assert (
        lines[0] == "usage: formation-bench [-h] [--version] [--plugin MODULE_OR_FILE] COMMAND ..."
    )
    hint = "run 'formation-bench COMMAND --help' for a command's options; start with"
    assert lines[-1] == START_HINT == f"{hint} 'formation-bench reproduce'"
    assert "required" not in done.stderr and "error" not in done.stderr
    listed = {}
    for line in lines[lines.index("commands:") + 1 :]:
        if not line.strip():
            break
        name, text = line.split(maxsplit=1)
        listed[name] = text
    assert tuple(listed) == COMMANDS
    for name, description in descriptions().items():
        assert listed[name] == first_sentence(description)


def test_without_a_command_after_a_plugin_the_overview_still_comes(capsys, tmp_path):
    assert main(["--plugin", str(tmp_path / "never_loaded.py")]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.endswith(START_HINT + "\n")


# --- each command's help ---------------------------------------------------------------------


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_has_a_description_and_its_help_is_its_first_sentence(command, capsys):
    with pytest.raises(SystemExit) as stop:
        main([command, "--help"])
    assert stop.value.code == 0
    text = capsys.readouterr().out
    description = descriptions()[command]
    usage, after_usage = text.split("\n\n", 1)
    assert usage.startswith(f"usage: formation-bench {command} ")
    assert after_usage.startswith(description + "\n\n")
    # what it does, then what it writes or prints, and where
    assert len(description.split("\n\n")) >= 2
    assert re.search(r"\bprints\b", description, re.IGNORECASE)
    assert "examples:\n  formation-bench " in text
    with pytest.raises(SystemExit):
        main(["--help"])
    overview = capsys.readouterr().out
    help_line = next(line for line in overview.splitlines() if line.split()[:1] == [command])
    one_line = first_sentence(description)
    assert "\n" not in one_line and not one_line.endswith(".")
    assert " ".join(help_line.split()[1:]) in one_line


def test_commands_that_write_say_where(capsys):
    for command in ("reproduce", "run", "report", "export-ioh"):
        assert "appears only when complete" in " ".join(descriptions()[command].split())
    assert "OUT/runs" in descriptions()["sweep"] and "OUT/score" in descriptions()["score"]


# --- --plugin after the command --------------------------------------------------------------


def test_a_plugin_after_the_command_is_one_line_with_the_right_order(tmp_path, capsys):
    out = tmp_path / "o"
    code = main(["run", "--plugin", "my.py", "--optimizer", "x", "--out", str(out)])
    assert code == 2
    assert capsys.readouterr().err == (
        "formation-bench: error: --plugin goes before the command: "
        f"formation-bench --plugin my.py run --optimizer x --out {shlex.quote(str(out))}\n"
    )
    assert not out.exists()


def test_a_misplaced_plugin_comes_before_any_other_parse_error(tmp_path, capsys):
    # without --optimizer and --out, and --plugin=... and a --plugin without its value
    assert main(["run", "--plugin=a.py", "--seed", "-1", "--plugin"]) == 2
    assert capsys.readouterr().err == (
        "formation-bench: error: --plugin goes before the command: "
        "formation-bench --plugin=a.py --plugin MODULE_OR_FILE run --seed -1\n"
    )


def test_a_misplaced_plugin_writes_nothing_in_the_process(tmp_path):
    out = tmp_path / "sweep out"
    done = command_line("--plugin", "a.py", "sweep", "paper", "--plugin", "b.py", "--out", str(out))
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr == (
        "formation-bench: error: --plugin goes before the command: formation-bench --plugin "
        f"a.py --plugin b.py sweep paper --out {shlex.quote(str(out))}\n"
    )
    assert not out.exists()


def test_a_plugin_before_the_command_is_loaded_as_before(tmp_path, capsys):
    missing = tmp_path / "missing.py"
    assert main(["--plugin", str(missing), "list"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("formation-bench list: error: ") and "goes before" not in err
    assert str(missing) in err and len(err.splitlines()) == 1


# --- sweep points to report ------------------------------------------------------------------

TINY_SUITE = """\
name = "tiny"
seeds = 1
triggers = [false]
[[optimizers]]
name = "modified-bso"
label = "small-bso"
overrides = { population_size = 12, max_iterations = 2 }
[[scenarios]]
name = "paper"
overrides = { n_steps = 3, settle_time_s = 0.2 }
"""


def test_a_finished_sweep_names_the_report_command_last(tmp_path, capsys):
    suite = tmp_path / "tiny.toml"
    suite.write_text(TINY_SUITE)
    out = tmp_path / "my results"
    args = ["sweep", str(suite), "--out", str(out), "--jobs", "1", "--no-progress"]
    assert main(args) == 0
    last = capsys.readouterr().err.splitlines()[-1]
    assert last == f"write its statistics with: formation-bench report {shlex.quote(str(out))}"
    assert main(args) == 0  # resumed with nothing to do: the runs are there to report on
    assert capsys.readouterr().err.splitlines()[-1] == last


# --- reproduce -------------------------------------------------------------------------------


def fake_records(seed: int, out: Path, **_: object) -> list[dict[str, object]]:
    """Two runs' records as ``reproduce_one`` returns them (nothing is run)."""
    pairs = ("d12", "d23", "d31")
    distances = {f"distance_error_max_m_{p}": 0.1 + 0.1 * k for k, p in enumerate(pairs)}
    return [
        {"trigger": False, "tracking_error_max_m": 0.395, **distances},
        {
            "trigger": True,
            "tracking_error_max_m": 1.5,
            **distances,
            **{f"solves_uav{k}": n for k, n in enumerate((97, 161, 160), start=1)},
        },
    ]


def reproduce_table(printed: str) -> list[str]:
    lines = printed.splitlines()
    start = next(k for k, line in enumerate(lines) if line.startswith("run "))
    return lines[start : start + 2 + len(PAPER_FIGURES)]


def check_reproduce_output(printed: str) -> None:
    lines = printed.splitlines()
    assert lines[-1] == shipped_line("modified-bso")  # the budget line comes last
    assert lines.index(next(x for x in lines if x.startswith("wrote "))) < len(lines) - 3
    header, rule, *rows = reproduce_table(printed)
    assert header.split() == ["run", "figure", "paper", "measured", "holds"]
    assert set(rule) == {"-"}
    for row in rows:
        # the yes/NO column ends each row: no unit after it
        assert row.split()[-1] in ("yes", "NO"), row
        measured = row.split()[-2]
        if "solves" in row:
            assert re.fullmatch(r"\d+", measured), row  # a count, not 97.000
            assert "(of 240; paper: " in row
        else:
            assert re.fullmatch(r"\d+\.\d{3}", measured), row
            assert " max (m) " in row


def test_reproduce_prints_counts_as_integers_units_with_names_and_the_budget_last(
    tmp_path, capsys, monkeypatch
):
    monkeypatch.setattr("formation_bench.cli.main.reproduce_one", fake_records)
    monkeypatch.setattr("formation_bench.pipeline.runner.kernels_cached", lambda: True)
    assert main(["reproduce", "--no-figures", "--out", str(tmp_path / "r")]) == 0
    printed = capsys.readouterr().out
    check_reproduce_output(printed)
    rows = reproduce_table(printed)[2:]
    assert rows[8].split()[-2:] == ["97", "yes"] and rows[9].split()[-2:] == ["161", "NO"]
    assert rows[0].split()[-2:] == ["0.395", "yes"] and rows[4].split()[-2:] == ["1.500", "NO"]
    # bounds aligned on their decimal point
    columns = {row.index(".", row.index("<=")) for row in rows if "solves" not in row}
    assert len(columns) == 1


@pytest.mark.slow
def test_reproduce_for_real_ends_with_the_budget_line(tmp_path, capsys):
    assert main(["reproduce", "--no-figures", "--out", str(tmp_path / "r")]) == 0
    check_reproduce_output(capsys.readouterr().out)


# --- the compile notice ----------------------------------------------------------------------

NOTICE = "compiling numba kernels"
SHORT_PSO = ["run", "--optimizer", "pso", "--no-trigger", "--no-figures", "--no-progress",
             "--set", "n_steps=3", "--set", "settle_time_s=0"]  # fmt: skip


def test_a_run_whose_optimizer_is_not_compiled_says_so(tmp_path, monkeypatch, capsys):
    """The harness's kernels cached, pso's not (pso after modified-bso runs): the notice."""
    monkeypatch.setattr("formation_bench.pipeline.runner.kernels_cached", lambda: True)
    checked = []

    def pso_cold(optimizer: object) -> bool:
        checked.append(type(optimizer).__name__)
        return False

    monkeypatch.setattr("formation_bench.pipeline.runner.optimizer_kernels_cached", pso_cold)
    assert main([*SHORT_PSO, "--out", str(tmp_path / "a")]) == 0
    assert capsys.readouterr().err.startswith(NOTICE)
    assert checked == ["PSO"]
    monkeypatch.setattr("formation_bench.pipeline.runner.optimizer_kernels_cached", lambda _: True)
    assert main([*SHORT_PSO, "--out", str(tmp_path / "b")]) == 0
    assert capsys.readouterr().err == ""


def test_reproduce_checks_the_modified_bso(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr("formation_bench.cli.main.reproduce_one", fake_records)
    monkeypatch.setattr("formation_bench.pipeline.runner.kernels_cached", lambda: True)
    checked = []
    monkeypatch.setattr(
        "formation_bench.pipeline.runner.optimizer_kernels_cached",
        lambda optimizer: checked.append(type(optimizer).__name__) or False,
    )
    assert main(["reproduce", "--no-figures", "--out", str(tmp_path / "r")]) == 0
    assert capsys.readouterr().err.startswith(NOTICE) and checked == ["ModifiedBSO"]


CACHE_PROBE = """
import json
from formation_bench.optimizers import get_optimizer
from formation_bench.pipeline.runner import kernels_cached, optimizer_kernels_cached
names = ("pso", "modified-bso", "cma-es")
print(json.dumps([kernels_cached(), *(optimizer_kernels_cached(get_optimizer(n)) for n in names)]))
"""


def test_an_empty_numba_cache_is_seen_for_the_harness_and_each_optimizer(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}
    done = subprocess.run(
        [sys.executable, "-c", CACHE_PROBE], capture_output=True, text=True, env=env, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[false, false, false, false]"


def test_the_kernels_are_found_cached_after_a_run(tmp_path, capsys):
    from formation_bench.optimizers import get_optimizer
    from formation_bench.pipeline.runner import kernels_cached, optimizer_kernels_cached

    assert main([*SHORT_PSO, "--out", str(tmp_path / "r")]) == 0
    assert kernels_cached() and optimizer_kernels_cached(get_optimizer("pso"))


@pytest.mark.slow
def test_a_first_pso_run_on_a_cold_cache_shows_the_notice(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}
    done = command_line(*SHORT_PSO, "--out", str(tmp_path / "r"), env=env)
    assert done.returncode == 0, done.stderr
    assert done.stderr.startswith(NOTICE)
    again = command_line(*SHORT_PSO, "--out", str(tmp_path / "r2"), env=env)
    assert again.returncode == 0 and NOTICE not in again.stderr


def test_report_refuses_a_page_that_is_not_a_markdown_file_before_any_work(tmp_path, capsys):
    results = tmp_path / "results"
    (results / "runs").mkdir(parents=True)
    assert main(["report", str(results), "--page", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"formation-bench report: error: --page {tmp_path}: give a Markdown file (.md), not a "
        "folder"
    )
    assert not (results / "report").exists()


def test_a_text_valued_choice_is_listed_and_refused_as_it_is_written(tmp_path, capsys):
    assert main(["list", "--fields", "paper"]) == 0
    listing = capsys.readouterr().out
    assert "graph = complete  (CommunicationGraph; one of complete, ring, k-nearest, range)" in (
        listing
    )
    argv = ["run", "--optimizer", "pso", "--set", "scenario.graph=star", "--out", str(tmp_path)]
    assert main(argv) == 2
    assert (
        capsys.readouterr()
        .err.strip()
        .endswith("expected one of complete, ring, k-nearest, range, got 'star'")
    )
