"""The ``tune`` subcommand of ``formation-bench``: one optimiser's searched settings tuned with
Optuna (the ``tune`` extra) on validation data, resumable, into a tuned-variant file.

Every refusal (a test-split problem, a results-page seed, an optimiser with nothing to
search, a tuned variant, a missing Optuna) is one line, exit code 2, before any work.
"""

from __future__ import annotations

import argparse
import importlib.util
import shlex
import sys
from pathlib import Path

from formation_bench.cli.common import (
    UsageError,
    add_command,
    budget_limit,
    compile_notice,
    positive_int,
    seed,
)
from formation_bench.experiments.sweep import DEFAULT_JOBS
from formation_bench.instances.library import LIBRARY_VERSIONS, SHIPPED_VERSION
from formation_bench.optimizers import OPTIMIZERS, get_optimizer
from formation_bench.pipeline.checks import JOBS_PER_CPU
from formation_bench.pipeline.staging import OutputError, check_output_folder

INSTALL_HINT = 'pip install "formation-bench[tune]"'
"""What installs the tune command's library."""
OPTIONS = {
    "optimizer": "--optimizer",
    "objective": "--objective",
    "trials": "--trials",
    "batch": "--batch",
    "seed": "--seed",
    "max_evaluations": "--max-evaluations",
    "library": "--library",
    "split": "--split",
    "problems": "--problems",
    "suite": "--suite",
    "seeds": "--seeds",
    "metric": "--metric",
}
"""Each setting of :class:`~formation_bench.tuning.settings.TuningSettings` and its option."""


def cmd_tune(args: argparse.Namespace) -> int:
    if importlib.util.find_spec("optuna") is None:
        raise UsageError(f"tune needs Optuna, which is not installed: {INSTALL_HINT}")
    from formation_bench import plugins
    from formation_bench.experiments.errors import StoreError
    from formation_bench.tuning.settings import TuningError, TuningSettings, check_settings
    from formation_bench.tuning.study import TrialFailed, progress_report, run_tuning

    out = Path(args.out)
    try:
        check_output_folder(out, overwrite=True)  # a tuning resumes in its folder, as a sweep
    except OutputError as err:
        raise UsageError(str(err)) from None
    if args.optimizer not in OPTIMIZERS:
        allowed = ", ".join(sorted(OPTIMIZERS))
        raise UsageError(f"--optimizer: unknown name {args.optimizer!r}; allowed: {allowed}")
    given = {name: getattr(args, name) for name in OPTIONS if getattr(args, name) is not None}
    try:
        settings = TuningSettings(**given)
        check_settings(settings)
    except TuningError as err:
        raise UsageError(str(err)) from None
    except ValueError as err:
        raise UsageError(_option_error(str(err))) from None
    compile_notice(
        {args.optimizer: get_optimizer(args.optimizer)},
        harness=settings.objective.value == "loop",
    )
    command = shlex.join(["formation-bench", *sys.argv[1:]])
    try:
        with progress_report(settings.trials, args.progress) as report:
            outcome = run_tuning(
                settings, out, jobs=args.jobs, plugins=plugins.loaded_plugins(),
                command=command, report=report,
            )  # fmt: skip
    except (TuningError, StoreError) as err:
        raise UsageError(str(err)) from None
    except TrialFailed as err:
        print(f"formation-bench tune: error: {err}", file=sys.stderr)
        return 1
    data = outcome.data
    if not outcome.computed:
        print(f"{outcome.path} is finished (nothing computed); it holds:")
    print(f"{data['name']}: {data['base']} with")
    for name, value in data["values"].items():
        print(f"  {name} = {value!r}")
    metric = data["objective"]["metric"]
    print(
        f"{metric}: {data['default_value']:.6g} at the default configuration, "
        f"{data['best_value']:.6g} tuned (best of {data['tuner']['trials']} trials)"
    )
    print(f"wrote {outcome.path}")
    return 0


def _option_error(message: str) -> str:
    """A settings error (``TuningSettings.field must be ...``) named by its option."""
    head, _, rest = message.partition(" must be ")
    field = head.rpartition(".")[2]
    if field in OPTIONS and rest:
        return f"{OPTIONS[field]}: must be {rest}"
    return message


def add_tune_command(sub: argparse._SubParsersAction) -> None:
    """Add ``tune`` to the subcommands."""
    tune = add_command(
        sub,
        "tune",
        f"""Tune one optimiser's searched settings with Optuna on validation data (resumable).

        The settings an optimiser declares with search= are searched by Optuna's seeded TPE
        sampler, trial 0 being the registered configuration. The objective is per solve (the
        median normalised gap over the library's validation split, every solve at
        --max-evaluations) or closed loop (the median of a record column over validation
        seeds, with a suite's scenario and trigger setting); test-split problems and the
        seeds of the shipped suites and score runs are refused. Trials are stored in
        OUT/NAME.journal as their batch finishes, so the same command resumes an
        interrupted tuning with the same result; --jobs changes the speed only. Writes
        OUT/NAME.json (NAME: OPTIMIZER-tuned, or OPTIMIZER-tuned-loop), the tuned variant
        with its provenance, and prints the tuned values. Needs the tune extra
        ({INSTALL_HINT}).""",
        examples=(
            (
                "formation-bench tune --optimizer pso --trials 100 --out results/tune --jobs 2",
                "pso's median normalised gap on the validation split, 100 trials",
            ),
            (
                "formation-bench tune --optimizer pso --objective loop --seeds 1000 1001 1002 "
                "--out results/tune",
                "pso's median steady-state cost over three closed loops of the comparison suite",
            ),
        ),
    )
    tune.add_argument("--optimizer", required=True, help="registered optimizer name (see 'list')")
    tune.add_argument(
        "--objective",
        choices=("solve", "loop"),
        help="solve: median normalised gap on the validation split (default); loop: median of "
        "--metric over closed loops at --seeds",
    )
    tune.add_argument(
        "--trials", type=positive_int, metavar="N", help="trials, trial 0 the default (100)"
    )
    tune.add_argument(
        "--batch",
        type=positive_int,
        metavar="N",
        help="trials asked at once, before any is evaluated (default 4; part of the result, "
        "unlike --jobs)",
    )
    tune.add_argument(
        "--seed",
        type=seed,
        help="seed of the sampler and the solves (default 100; the seeds of the results "
        "pages are refused)",
    )
    tune.add_argument(
        "--max-evaluations",
        type=budget_limit,
        metavar="N",
        help="evaluations per solve (default 1200, the comparison and ablation suites')",
    )
    tune.add_argument(
        "--library",
        choices=LIBRARY_VERSIONS,
        help=f"solve objective: library version (default: the shipped one, {SHIPPED_VERSION})",
    )
    tune.add_argument(
        "--split",
        help="solve objective: the split solved; only validation (the default) is allowed",
    )
    tune.add_argument(
        "--problems",
        type=positive_int,
        metavar="N",
        help="solve objective: only the split's first N problems (quick checks; default all)",
    )
    tune.add_argument(
        "--suite",
        help="loop objective: shipped suite or suite .toml file whose scenario and trigger "
        "setting the closed loops run (default comparison)",
    )
    tune.add_argument(
        "--seeds",
        nargs="+",
        type=seed,
        help="loop objective: closed-loop seeds (default 1000 .. 1009; a shipped suite's "
        "seeds are refused)",
    )
    tune.add_argument(
        "--metric",
        help="loop objective: the record column minimised (default steady_state_cost)",
    )
    tune.add_argument("--out", required=True, help="tuning folder (created; resumed if present)")
    tune.add_argument(
        "--jobs",
        type=positive_int,
        default=DEFAULT_JOBS,
        help=f"worker processes evaluating a batch's trials (default {DEFAULT_JOBS}; at most "
        f"{JOBS_PER_CPU} per CPU)",
    )
    tune.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress bar (default: only on a terminal); --no-progress prints a line per batch",
    )
    tune.set_defaults(func=cmd_tune)
