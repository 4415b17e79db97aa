"""Small stored results of every kind of results page, for tests/test_page_numbers.py.

Each builder makes a results folder in a few seconds with the command line, as a user does:
a sweep of the paper scenario (headline tables, the paper's budget, variant pairs), a sweep
of the swarm, robustness and obstacles scenarios (their sections), score runs over the
library's test split (the leaderboard, with the rank change of a tuned variant), and a folder
of two small tunings (the tuning report). Everything is seeded, so the values of the pages are
the same on every run of the same code.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

from test_suite_sections import SUITE as SECTIONS_SUITE

from formation_bench.cli.main import main

PAPER_SUITE = """\
name = "page-numbers-paper"
seeds = 3
triggers = [true, false]
# two budgets of the unmodified paper scenario with and without the trigger: the report adds
# the budget the paper needs; pso-warm beside pso: the variant pairs
budgets = [{ max_evaluations = 600 }, { max_evaluations = 1200 }]
trace = false

[[optimizers]]
name = "modified-bso"

[[optimizers]]
name = "pso"

[[optimizers]]
name = "pso-warm"

[[scenarios]]
name = "paper"
"""


SCORED = ("pso", "pso-tuned", "pso-warm", "modified-bso")
"""Optimisers scored at 1200 evaluations, the tuned variants' tuning budget: the leaderboard,
its paired comparisons (warm start, against the modified BSO) and the rank change of
``pso-tuned``."""


def cli(*argv: str) -> None:
    """Run ``formation-bench ARGV`` in this process; a failure stops the test."""
    code = main(list(argv))
    if code != 0:
        raise RuntimeError(f"formation-bench {' '.join(argv)} exited with {code}")


def sweep(root: Path, name: str, suite: str) -> Path:
    """The results folder of ``suite`` (TOML text), run under ``root``."""
    path = root / f"{name}.toml"
    path.write_text(suite)
    out = root / name
    cli("sweep", str(path), "--out", str(out), "--jobs", "1", "--no-progress")
    return out


def paper_results(root: Path) -> Path:
    """A sweep of the paper scenario: headline tables, the paper's budget, variant pairs."""
    return sweep(root, "paper", PAPER_SUITE)


def sections_results(root: Path) -> Path:
    """A sweep with the swarm, robustness and obstacles sections."""
    return sweep(root, "sections", SECTIONS_SUITE)


def score_results(root: Path) -> Path:
    """Score runs of :data:`SCORED` over the shipped library's test split."""
    out = root / "score"
    for optimizer in SCORED:
        cli("score", "--optimizer", optimizer, "--budgets", "1200", "--out", str(out),
            "--jobs", "1")  # fmt: skip
    return out


def tuning_results(root: Path) -> Path:
    """A folder of two tuned variants of PSO, per solve and in the closed loop, from tunings
    of a few trials (needs optuna)."""
    tunings = {
        "solve": ["--trials", "4", "--batch", "2", "--problems", "8"],
        "loop": ["--objective", "loop", "--seeds", "1000", "--trials", "3", "--batch", "1"],
    }
    folder = root / "tuning"
    folder.mkdir()
    for kind, options in tunings.items():
        out = root / f"tune-{kind}"
        cli("tune", "--optimizer", "pso", *options, "--max-evaluations", "300",
            "--out", str(out), "--jobs", "1", "--no-progress")  # fmt: skip
        # the report reads a folder of tuned files, as results/tuning holds them
        for tuned in out.glob("*.json"):
            shutil.copyfile(tuned, folder / tuned.name)
    return folder


BUILDERS: dict[str, Callable[[Path], Path]] = {
    "paper": paper_results,
    "sections": sections_results,
    "leaderboard": score_results,
    "tuning": tuning_results,
}
"""Each kind of results page and the builder of its results folder."""


def render(results: Path, work: Path) -> tuple[Path, Path]:
    """``formation-bench report RESULTS --page PAGE --out REPORT``; returns the page and the
    report folder. The page is in a folder of its own: a tuning page's figure goes beside
    that folder, as the documentation keeps it (none is drawn here)."""
    page = work / "pages" / f"{results.name}.md"
    page.parent.mkdir(parents=True, exist_ok=True)
    report = work / f"{results.name}-report"
    cli("report", str(results), "--page", str(page), "--out", str(report), "--no-figures")
    return page, report
