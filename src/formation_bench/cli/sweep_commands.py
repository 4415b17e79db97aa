"""The ``sweep``, ``score``, ``report`` and ``export-ioh`` subcommands of ``formation-bench``.

Errors follow the rest of the command line: one line naming the field and the
allowed values, exit code 2, no traceback.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import time
from collections.abc import Callable
from pathlib import Path

from formation_bench.cli.common import (
    add_command,
    budget_limit,
    compile_notice,
    configured_optimizer,
    deadline_ms,
    positive_int,
    requested_budget,
    seed,
)
from formation_bench.experiments.errors import StoreError, SweepError
from formation_bench.experiments.executors import DEFAULT_WORKER_TIMEOUT_S
from formation_bench.experiments.suite import (
    SuiteError,
    load_suite,
    shipped_suites,
)
from formation_bench.experiments.sweep import DEFAULT_JOBS, plan, run_sweep
from formation_bench.instances.library import LIBRARY_VERSIONS, SHIPPED_VERSION
from formation_bench.optimizers import get_optimizer
from formation_bench.optimizers.base import BUDGET_MINIMUM
from formation_bench.pipeline.checks import (
    JOBS_PER_CPU,
    LimitError,
    check_optimizer,
    check_scheduler_address,
)
from formation_bench.pipeline.interrupts import is_interrupt
from formation_bench.pipeline.spec import from_json_value, solve_budget
from formation_bench.pipeline.staging import (
    OutputError,
    check_output_folder,
    confined,
    staged_folder,
    storage_advice,
    storage_problem,
)
from formation_bench.plugins import PluginError


def usage_errors() -> tuple[type[Exception], ...]:
    """The errors a command reports in one line; the module of the last one reads and writes
    Parquet with pandas, so it is imported only when a command fails."""
    from formation_bench.analysis.ioh_export import ExportError

    return (SuiteError, SweepError, StoreError, PluginError, LimitError, OutputError, ExportError)


def _worker_timeout(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a number of seconds > 0, got {text!r}")
    return value


def _scheduler(text: str) -> str:
    try:
        return check_scheduler_address(text)
    except LimitError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _guarded(command: str, func: Callable[[argparse.Namespace], int]):
    def run(args: argparse.Namespace) -> int:
        try:
            return func(args)
        except (KeyboardInterrupt, SystemError):
            raise  # for main(); matching usage_errors() would import pandas mid-interrupt
        except ImportError as err:
            if is_interrupt(err):  # an import cut short by Ctrl-C (pandas fails so)
                raise KeyboardInterrupt from None
            raise
        except usage_errors() as err:
            print(f"formation-bench {command}: error: {err}", file=sys.stderr)
            return 2
        except BrokenPipeError:  # output piped into e.g. `head`, which stopped reading
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return 0
        except OSError as err:  # a write the file system refused, where no caller named more
            problem = storage_problem(err)
            if problem is None:
                raise
            print(
                f"formation-bench {command}: error: {problem}; {storage_advice(err)}",
                file=sys.stderr,
            )
            return 2

    return run


def cmd_sweep(args: argparse.Namespace) -> int:
    out = Path(args.out)
    try:
        # a results folder is resumed, so only its kind and place are checked here
        check_output_folder(out, overwrite=True)
    except OutputError as err:
        raise SweepError(str(err)) from None
    suite = load_suite(args.suite)
    if args.rebuild_manifest:
        from formation_bench.experiments.manifest import rebuild_manifest

        print(rebuild_manifest(suite, out))
        return 0
    if args.dry_run:
        from formation_bench.experiments.store import ResultStore

        pending, summary = plan(suite, ResultStore(args.out))
        print(
            f"suite {suite.name}: {summary.total} runs, {summary.already} stored, "
            f"{len(pending)} to run"
        )
        for spec in pending:
            print(f"  {spec.key}  {spec.describe()}")
            # what repeats this run exactly, on its own
            print(f"    {spec.run_command(out=f'repeat-{spec.key}')}")
        return 0
    compile_notice(
        {
            entry.label: get_optimizer(entry.name, **from_json_value(json.loads(entry.overrides)))
            for entry in suite.optimizers
        },
        workers=1 if args.scheduler else args.jobs,
    )
    summary = run_sweep(
        suite,
        args.out,
        jobs=args.jobs,
        scheduler=args.scheduler,
        worker_timeout_s=args.worker_timeout,
        progress=args.progress,
        allow_suite_change=args.allow_suite_change,
    )
    if not summary.interrupted and summary.already + summary.stored > 0:
        # the sweep's log goes to stderr: this stays its last line
        print(f"write its statistics with: {report_command(out)}", file=sys.stderr)
    return summary.exit_code


def report_command(results: Path) -> str:
    """The command that writes the statistics of a results folder."""
    return f"formation-bench report {shlex.quote(str(results))}"


DEFAULT_BUDGET = "default"
"""A ``score --budgets`` value: the optimizer's own budget."""


def _score_budget(text: str) -> int | str:
    """A ``score --budgets`` value: evaluations per solve, or :data:`DEFAULT_BUDGET`."""
    if text == DEFAULT_BUDGET:
        return text
    try:
        return budget_limit(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(
            f"must be '{DEFAULT_BUDGET}' or a number of evaluations >= {BUDGET_MINIMUM}, "
            f"got {text!r}"
        ) from None


def cmd_score(args: argparse.Namespace) -> int:
    from formation_bench.experiments.score import (
        ScoreError,
        ScoreRunsFailed,
        run_scores,
        score_runs,
        stored_keys,
    )
    from formation_bench.instances.library import LibraryError, load_shipped, shipped
    from formation_bench.plugins import loaded_plugins

    out = Path(args.out)
    try:
        check_output_folder(out, overwrite=True)  # score runs resume, like a sweep
    except OutputError as err:
        raise SweepError(str(err)) from None
    _, overrides = configured_optimizer(args.optimizer, args.set or [])
    budgets = [
        requested_budget(None if evaluations == DEFAULT_BUDGET else evaluations, None,
                         args.deadline_ms)
        for evaluations in args.budgets
    ]  # fmt: skip
    try:
        library = shipped() if args.library is None else load_shipped(args.library)
        runs = score_runs(
            args.optimizer,
            overrides,
            budgets,
            args.seeds,
            library=library,
            split=args.split,
            plugins=loaded_plugins(),
        )
    except LibraryError as err:
        raise SweepError(f"--library: {err}") from None
    except ScoreError as err:
        raise SweepError(str(err)) from None
    optimizer = runs[0].optimizer()
    for budget in budgets:
        check_optimizer(optimizer, solve_budget(budget, optimizer))  # as run and sweep do
    compile_notice({runs[0].optimizer_label: optimizer})
    start = time.perf_counter()
    done = 0
    try:
        for run in run_scores(runs, out, jobs=args.jobs):
            done += 1
            print(f"  stored {run.describe()}", flush=True)
    except ScoreRunsFailed as failures:
        for run, error in failures.failed:
            last = error.strip().splitlines()[-1] if error.strip() else "no error text"
            print(f"failed: {run.describe()}: {last}", file=sys.stderr)
        print(
            f"{len(runs) - len(failures.failed)} of {len(runs)} score runs stored in "
            f"{out / 'score'}; {len(failures.failed)} failed",
            file=sys.stderr,
        )
        return 1
    except OSError as err:
        problem = storage_problem(err, where=out / "score")
        if problem is None:
            raise
        kept = len(stored_keys(out, runs))  # counted from the folder
        raise SweepError(
            f"--out: {problem}; {kept} of {len(runs)} score runs stored in {out / 'score'} and "
            f"intact; {storage_advice(err)}"
        ) from None
    print(
        f"{len(runs)} score runs ({done} new) of {runs[0].optimizer_label} on library "
        f"{runs[0].library_version}, split {runs[0].split}, in {out}/score "
        f"({time.perf_counter() - start:.1f} s); {report_command(out)} writes the statistics"
    )
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    # the statistics and plotting libraries are imported only by the command that uses them
    from formation_bench.analysis.report import ReportError, make_report
    from formation_bench.mpc.families import UnclaimedDisturbanceError

    start = time.perf_counter()
    results = Path(args.results)
    has_runs, has_scores = (results / "runs").is_dir(), (results / "score").is_dir()
    tuned = None if has_runs or has_scores else _tuned_variants(results, args)
    folder = Path(args.out) if args.out is not None else results / "report"
    if args.out is None:  # a folder chosen inside the one the user named
        confined(results, folder, "DIR")
    if args.page is not None:
        # every output is checked before any is written
        from formation_bench.analysis.results_page import check_page, tuning_image

        image = tuning_image(Path(args.page)) if tuned and args.figures else None
        check_page(Path(args.page), results, folder, overwrite=args.overwrite, image=image)
        if has_runs:  # the page's provenance: a damaged manifest stops it before any output
            from formation_bench.experiments.manifest import read_manifest
            from formation_bench.experiments.store import ResultStore

            read_manifest(ResultStore(results))
    written = []
    try:
        with staged_folder(folder, overwrite=args.overwrite) as staging:
            report = None
            if has_runs:
                report, headline, _ = make_report(
                    results,
                    staging,
                    baseline=args.baseline,
                    compare=args.compare,
                    figures=args.figures,
                )
                print(headline)
                written.append(
                    "report.md, summary.csv, wilcoxon.csv, friedman.csv, ranks.csv, nemenyi.csv"
                )
            if has_scores:
                from formation_bench.analysis.score_report import write_score_report
                from formation_bench.experiments.score import load_scores

                print(write_score_report(load_scores(results), staging, figures=args.figures))
                written.append(
                    "score.md, score_summary.csv, score_degenerate.csv, score_phases.csv, "
                    "score_paired.csv, score_ert.csv, score_profile.csv, "
                    "score_rank_change.csv"
                )
            if tuned:
                from formation_bench.analysis.tuning_report import write_tuning_report

                print(write_tuning_report(tuned, staging, figures=args.figures))
                written.append("tuning.md, tuning.csv, tuning_curves.csv")
        if args.page is not None:
            from formation_bench.analysis.results_page import write_results_page

            write_results_page(
                results, args.page, folder,
                report=report, baseline=args.baseline, compare=args.compare, tuned=tuned,
            )  # fmt: skip
    except (ReportError, OutputError, UnclaimedDisturbanceError) as err:
        print(f"formation-bench report: error: {err}", file=sys.stderr)
        return 2
    print(
        f"wrote {folder}/{', '.join(written)}{' and figures/' if args.figures else ''} "
        f"({time.perf_counter() - start:.1f} s)"
    )
    if args.page is not None:
        print(f"wrote the results page {args.page}")
    return 0


def _tuned_variants(results: Path, args: argparse.Namespace) -> list:
    """The checked tuned-variant files of a folder without runs or score runs; refuses a
    folder without any, and the options that compare levels of runs."""
    from formation_bench.analysis.tuning_report import TunedFileError, read_folder, tuned_files

    if not tuned_files(results):
        raise StoreError(
            f"{results} holds no results (no runs/ or score/ folder, no tuned-variant files "
            "NAME-tuned.json or NAME-tuned-loop.json); run a sweep, score or tune into it first"
        )
    for option, value in (("--baseline", args.baseline), ("--compare", args.compare)):
        if value is not None:
            raise StoreError(
                f"{option}: {results} holds tuned-variant files, whose report compares no "
                f"runs; leave {option} out"
            )
    try:
        return read_folder(results)
    except TunedFileError as err:
        raise StoreError(str(err)) from None


def cmd_export_ioh(args: argparse.Namespace) -> int:
    from formation_bench.analysis.ioh_export import ExportError, export_ioh
    from formation_bench.experiments.score import load_scores

    results = Path(args.results)
    if not (results / "score").is_dir():
        raise StoreError(f"{results} holds no score runs (no score/ folder); run 'score' first")
    folder = Path(args.out) if args.out is not None else results / "ioh"
    archive = folder.with_name(folder.name + ".zip")
    if args.out is None:  # folders chosen inside the one the user named
        confined(results, folder, "DIR")
        confined(results, archive, "DIR")
    if args.zip and archive.is_dir():
        raise ExportError(f"--zip: {archive} is a folder, not a file")
    if args.zip and archive.exists() and not args.overwrite:
        raise ExportError(f"--zip: {archive} exists; add --overwrite to replace it")
    # damaged score files are named as they are read; files used unverified once it is written
    notices: list[str] = []
    scores = load_scores(results, notice=notices.append)
    try:
        with staged_folder(folder, overwrite=args.overwrite) as staging:
            written = export_ioh(scores, staging)
    except OutputError as err:
        raise ExportError(str(err)) from None
    if args.zip:
        _zip_folder(folder, archive)
    left_out = int(scores["degenerate"].astype(bool).sum())
    print(
        f"wrote {folder}{' and ' + str(archive) if args.zip else ''}: {len(written)} "
        f"algorithms, {sum(written.values())} runs"
        + (f" ({left_out} solves of degenerate instances left out)" if left_out else "")
        + "; raw_y is the normalised gap (f - J*) / (f_warm - J*); IOHanalyzer reads the "
        "folder (DataSetList) or the zip (upload)"
    )
    for line in notices:
        print(line, file=sys.stderr)
    return 0


def _zip_folder(folder: Path, archive: Path) -> None:
    """The finished export as one zip, which appears whole or not at all."""
    import io
    import zipfile

    from formation_bench.pipeline.outputs import atomic_write_bytes

    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as zipped:
        for path in sorted(p for p in folder.rglob("*") if p.is_file()):
            zipped.write(path, path.relative_to(folder).as_posix())
    atomic_write_bytes(archive, buffer.getvalue())


def add_sweep_commands(sub: argparse._SubParsersAction) -> None:
    """Add ``sweep``, ``score``, ``report`` and ``export-ioh`` to the subcommands."""
    sweep = add_command(
        sub,
        "sweep",
        f"""Run a suite of closed-loop runs into a results folder (resumable).

        A suite (shipped: {", ".join(shipped_suites())}; or a .toml file) crosses optimisers,
        scenarios, trigger settings, budgets and seeds. Every run not yet stored in --out runs
        on --jobs local worker processes (or the workers of a Dask scheduler) and is stored in
        OUT/runs as it finishes, with OUT/manifest.json; the same command resumes an
        interrupted sweep. Prints its progress and a summary to stderr, and last the
        'formation-bench report' command that writes the statistics.""",
        examples=(
            (
                "formation-bench sweep paper --out results/paper --jobs 2",
                "the shipped suite 'paper' on two worker processes",
            ),
            (
                "formation-bench sweep my_suite.toml --out results/mine --dry-run",
                "list the runs still to do, each with the 'run' command that repeats it",
            ),
            ("formation-bench report results/paper", "then: the statistics of the sweep"),
        ),
    )
    sweep.add_argument(
        "suite",
        metavar="SUITE",
        help=f"shipped suite ({', '.join(shipped_suites())}) or path of a suite .toml file",
    )
    sweep.add_argument("--out", required=True, help="results folder (created; resumed if present)")
    sweep.add_argument(
        "--jobs",
        type=positive_int,
        default=DEFAULT_JOBS,
        help=f"local worker processes, one thread each (default {DEFAULT_JOBS}; at most "
        f"{JOBS_PER_CPU} per CPU)",
    )
    sweep.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        type=_scheduler,
        help="send the runs to this Dask distributed scheduler (e.g. tcp://host:8786) "
        "instead of local workers; --jobs is then ignored",
    )
    sweep.add_argument(
        "--worker-timeout",
        metavar="SECONDS",
        type=_worker_timeout,
        default=DEFAULT_WORKER_TIMEOUT_S,
        help="with --scheduler: stop (finished runs stored, resumable) when the scheduler has "
        f"had no live worker for this long (default {DEFAULT_WORKER_TIMEOUT_S:g})",
    )
    sweep.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress bar with ETA (default: only on a terminal)",
    )
    sweep.add_argument(
        "--allow-suite-change",
        action="store_true",
        help="add to a results folder written from a different version of the suite file",
    )
    sweep.add_argument("--dry-run", action="store_true", help="list the runs still to do and exit")
    sweep.add_argument(
        "--rebuild-manifest",
        action="store_true",
        help="write a damaged or missing manifest.json anew from the stored runs (which must "
        "come from SUITE), then exit",
    )
    sweep.set_defaults(func=_guarded("sweep", cmd_sweep))

    score = add_command(
        sub,
        "score",
        """Solve every instance of the instance library with one optimiser (resumable).

        The library holds recorded local problems of the closed loop with best-known optima
        J*. Each instance of the chosen split is solved at each budget and seed, and stored
        in OUT/score; the same command resumes. Prints a line per stored run, and last the
        'formation-bench report OUT' command that writes the leaderboard: median normalised
        gap (f - J*) / (f_warm - J*), relative gap, success rates, ERT, ECDFs, performance
        profiles, per-phase and paired tables.""",
        examples=(
            (
                "formation-bench score --optimizer pso --budgets default 1200 --seeds 0 1 "
                "--out results/score",
                "pso at its own budget and at 1200 evaluations, seeds 0 and 1",
            ),
            ("formation-bench report results/score", "then: the leaderboard"),
        ),
    )
    score.add_argument("--optimizer", required=True, help="registered optimizer name")
    score.add_argument(
        "--set", action="append", metavar="FIELD=VALUE", help="override an optimizer field"
    )
    score.add_argument(
        "--budgets",
        nargs="+",
        type=_score_budget,
        default=[DEFAULT_BUDGET],
        metavar="B",
        help="per-solve budgets: 'default' (the optimizer's own) or evaluations (default: default)",
    )
    score.add_argument("--seeds", nargs="+", type=seed, default=[0], help="seeds (default 0)")
    score.add_argument(
        "--deadline-ms",
        type=deadline_ms,
        metavar="MS",
        help="per-solve wall-clock deadline in milliseconds, at every budget (a 'default' "
        "budget keeps the optimizer's own limits under it)",
    )
    score.add_argument(
        "--library",
        choices=LIBRARY_VERSIONS,
        help=f"library version (default: the shipped one, {SHIPPED_VERSION})",
    )
    score.add_argument(
        "--split",
        choices=("test", "validation", "all"),
        help="instances solved, degenerate ones included: a split of the library or all of "
        "it (default: test; all on v1, which has no splits and allows only all)",
    )
    score.add_argument("--out", required=True, help="results folder (resumed if it exists)")
    score.add_argument(
        "--jobs",
        type=positive_int,
        default=DEFAULT_JOBS,
        help=f"worker processes (default {DEFAULT_JOBS}; at most {JOBS_PER_CPU} per CPU)",
    )
    score.set_defaults(func=_guarded("score", cmd_score))

    report = add_command(
        sub,
        "report",
        """Write the statistics tables and figures of a results folder.

        For the runs of a sweep (DIR/runs): report.md and CSV tables (median, IQR and
        bootstrap CI; Wilcoxon tests against a baseline with Holm's correction and A12;
        Friedman test with average ranks and Nemenyi); for score runs (DIR/score): score.md
        and its tables; for a folder of tuned-variant files (NAME-tuned.json, written by
        'tune'): tuning.md, its tables and the best value found against the trials; with the
        seaborn figures in figures/. Writes to --out (default
        DIR/report), which appears only when complete, and prints the headline. --page FILE also
        writes a dated Markdown results page naming the commands that made the results.""",
        examples=(
            ("formation-bench report results/paper", "into results/paper/report"),
            (
                "formation-bench report results/paper --compare trigger --baseline off",
                "the trigger settings compared, against the runs without it",
            ),
            (
                "formation-bench report results/comparison --page docs/results/comparison.md",
                "and the documentation's dated results page",
            ),
            (
                "formation-bench report results/tuning --page docs/results/tuning.md",
                "the tuned-variant files of 'tune --out results/tuning': the tuning page",
            ),
        ),
    )
    report.add_argument(
        "results",
        metavar="DIR",
        help="results folder written by 'sweep' or 'score', or a folder of tuned-variant files "
        "written by 'tune'",
    )
    report.add_argument(
        "--baseline",
        metavar="NAME",
        nargs="+",
        help="level(s) every other level is compared against, each with its own paired tests "
        "(default: modified-bso when comparing optimizers, 'off' when comparing trigger "
        "settings); e.g. --baseline modified-bso cma-es",
    )
    report.add_argument(
        "--compare",
        choices=("optimizer", "trigger", "budget", "scenario"),
        help="factor compared (default: optimizer if the results hold several, else trigger)",
    )
    report.add_argument("--out", help="report folder (default: DIR/report)")
    report.add_argument(
        "--page",
        metavar="FILE",
        help="also write a dated Markdown results page (the commands that made the results and "
        "this page, date, version, machine, the report's tables); a page it wrote earlier is "
        "rewritten only with --overwrite, keeping the findings written into it between its "
        "findings markers, and any other existing file is refused",
    )
    report.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an existing report folder (as a whole), and an existing --page written "
        "by this command, instead of refusing",
    )
    report.add_argument(
        "--figures",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="write the seaborn figures (default on)",
    )
    report.set_defaults(func=_guarded("report", cmd_report))

    export = add_command(
        sub,
        "export-ioh",
        """Export the score runs of a results folder for IOHanalyzer (IOHprofiler format).

        Every score run of DIR becomes IOHprofiler data: one algorithm per optimiser and
        budget, the library as one function whose instances are its problems, one run per
        non-degenerate instance and seed, raw_y the normalised gap (f - J*) / (f_warm - J*).
        Writes to --out (default DIR/ioh), which appears only when complete, and with --zip
        also OUT.zip, for IOHanalyzer's upload. Prints what it wrote (algorithms and runs) and
        how many solves of degenerate instances it left out.""",
        examples=(("formation-bench export-ioh results/score --zip", "into results/score/ioh"),),
    )
    export.add_argument("results", metavar="DIR", help="results folder written by 'score'")
    export.add_argument("--out", help="export folder (default: DIR/ioh)")
    export.add_argument(
        "--zip", action="store_true", help="also write the folder as OUT.zip (IOHanalyzer upload)"
    )
    export.add_argument(
        "--overwrite",
        action="store_true",
        help="replace an existing export folder (and zip) instead of refusing",
    )
    export.set_defaults(func=_guarded("export-ioh", cmd_export_ioh))
