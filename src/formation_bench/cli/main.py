"""The ``formation-bench`` command line.

Every bad option, unknown name or out-of-range field ends in a one-line
error naming it and what is allowed, exit code 2, no traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import shlex
import signal
import sys
import textwrap
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import Any, NoReturn

# first: Ctrl-C during the imports below ends the command in one line
from formation_bench.cli import command_start  # isort: skip

import formation_bench
from formation_bench import plugins
from formation_bench.analysis.paper import (
    comparison_rows,
    format_seed_table,
    format_table,
)
from formation_bench.cli.common import (
    HELP_WIDTH,
    UsageError,
    add_command,
    assignment,
    budget_limit,
    compile_notice,
    deadline_ms,
    error_message,
    parse_value,
    requested_budget,
    seed,
    set_error,
)
from formation_bench.cli.sweep_commands import add_sweep_commands
from formation_bench.cli.tune_command import add_tune_command
from formation_bench.environment import EnvironmentValueError, check_environment
from formation_bench.fields import member_text
from formation_bench.mpc.loop import ProgressCallback
from formation_bench.mpc.reference import REFERENCE_PATHS
from formation_bench.mpc.scenario import SCENARIOS, Scenario, get_scenario
from formation_bench.optimizers import OPTIMIZERS, Budget, Optimizer, get_optimizer
from formation_bench.pipeline.checks import (
    LimitError,
    check_jobs,
    check_out_path,
    check_run,
    check_seed_count,
)
from formation_bench.pipeline.interrupts import (
    delivered_again,
    interrupt_again_soon,
    is_interrupt,
    raise_keyboard_interrupt,
    unsafe_to_raise,
)
from formation_bench.pipeline.outputs import write_metrics, write_text, write_trace
from formation_bench.pipeline.runner import RunOutcome, execute
from formation_bench.pipeline.spec import RunSpec, flat_fields, solve_budget
from formation_bench.pipeline.staging import OutputError, staged_folder

DEFAULT_OPTIMIZER = "modified-bso"

EXAMPLES = """\
examples:
  formation-bench reproduce                      the paper scenario, metrics beside the paper's
  formation-bench list                           registered optimizers and scenarios
  formation-bench run --optimizer pso --no-trigger --seed 3 --out out/pso
  formation-bench run --optimizer modified-bso --set scenario.reference=s-curve --out out/s
  formation-bench sweep paper --out results/paper --jobs 2
  formation-bench report results/paper
  formation-bench score --optimizer pso --budgets default 1200 --seeds 0 1 --out results/score
  formation-bench --plugin my_search.py run --optimizer my-random-search --out out/mine
"""


START_HINT = (
    "run 'formation-bench COMMAND --help' for a command's options; "
    "start with 'formation-bench reproduce'"
)
"""The last line of the overview printed when no command is given."""


class _Parser(argparse.ArgumentParser):
    commands: argparse._SubParsersAction | None = None
    """The subcommands (on the top-level parser only)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")

    def overview(self) -> str:
        """The usage line, every command with its one-line help, and where to go next."""
        assert self.commands is not None
        helps = {action.dest: action.help for action in self.commands._choices_actions}
        width = max(map(len, helps))
        lines = [self.format_usage().rstrip(), "", "commands:"]
        lines += [f"  {name:<{width}}  {text}" for name, text in helps.items()]
        return "\n".join([*lines, "", START_HINT]) + "\n"


def split_overrides(
    assignments: list[str], scenario: Scenario, optimizer: Optimizer
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Route ``FIELD=VALUE`` pairs to the scenario or the optimiser.

    ``scenario.FIELD`` and ``optimizer.FIELD`` say where explicitly; a bare
    field goes to whichever has it.
    """
    scenario_fields = set(flat_fields(scenario))
    optimizer_fields = set(flat_fields(optimizer))
    to_scenario: dict[str, Any] = {}
    to_optimizer: dict[str, Any] = {}
    for text in assignments:
        name, target, field, raw = assignment(text)
        if target not in ("", "scenario", "optimizer"):
            raise UsageError(f"--set {name}: prefix must be 'scenario.' or 'optimizer.'")
        in_scenario, in_optimizer = field in scenario_fields, field in optimizer_fields
        if target == "scenario" or (not target and in_scenario and not in_optimizer):
            if not in_scenario:
                allowed = ", ".join(sorted(scenario_fields))
                raise UsageError(f"--set {name}: unknown scenario field; fields: {allowed}")
            to_scenario[field] = parse_value(raw)
        elif target == "optimizer" or (not target and in_optimizer and not in_scenario):
            if not in_optimizer:
                allowed = ", ".join(sorted(optimizer_fields))
                raise UsageError(f"--set {name}: unknown optimizer field; fields: {allowed}")
            to_optimizer[field] = parse_value(raw)
        elif in_scenario and in_optimizer:
            raise UsageError(f"--set {name}: ambiguous, write scenario.{name} or optimizer.{name}")
        else:
            raise UsageError(
                f"--set {name}: unknown field; scenario fields: "
                f"{', '.join(sorted(scenario_fields))}; "
                f"optimizer fields: {', '.join(sorted(optimizer_fields))}"
            )
    return to_scenario, to_optimizer


def _build(args: argparse.Namespace) -> tuple[Scenario, Optimizer]:
    if args.optimizer not in OPTIMIZERS:
        allowed = ", ".join(sorted(OPTIMIZERS))
        raise UsageError(f"--optimizer: unknown name {args.optimizer!r}; allowed: {allowed}")
    if args.scenario not in SCENARIOS:
        raise UsageError(
            f"--scenario: unknown name {args.scenario!r}; allowed: {', '.join(sorted(SCENARIOS))}"
        )
    scenario, optimizer = get_scenario(args.scenario), get_optimizer(args.optimizer)
    to_scenario, to_optimizer = split_overrides(args.set or [], scenario, optimizer)
    try:
        return (
            get_scenario(args.scenario, **to_scenario),
            get_optimizer(args.optimizer, **to_optimizer),
        )
    except (ValueError, TypeError, KeyError) as err:
        raise UsageError(set_error(error_message(err), args.set or [])) from None


def _summary(record: dict[str, Any]) -> str:
    pairs = [c for c in record if c.startswith("distance_error_max_m_d")]
    distances = " ".join(
        f"{c.removeprefix('distance_error_max_m_')}={record[c]:.3f}" for c in pairs
    )
    if not pairs:  # a swarm: summarised over the communication graph's pairs
        distances = (
            f"{record['distance_error_max_m_max']:.3f} (RMS {record['distance_error_rms_m']:.3f})"
        )
    solves = [record[c] for c in record if c.startswith("solves_uav")]
    if len(solves) > 5:
        solves = f"{record['solves_total']} over {len(solves)} UAVs"
    extras = []
    if record["collisions"] or record["obstacle_intrusions"]:
        extras.append(
            f"collisions {record['collisions']}, obstacle intrusions "
            f"{record['obstacle_intrusions']}, min separation {record['min_separation_m']:.2f} m"
        )
    if record["plans_lost"] or record["plans_late"]:
        extras.append(
            f"plans lost {record['plans_lost']} and late {record['plans_late']} "
            f"of {record['plans_sent']}"
        )
    return (
        f"{record['optimizer']} {record['scenario']} trigger={record['trigger']} "
        f"seed={record['seed']}: tracking max {record['tracking_error_max_m']:.3f} m, "
        f"distance error max {distances} m, solves {solves}, "
        + "".join(f"{extra}, " for extra in extras)
        + f"median solve {1e3 * record['solve_time_median_s']:.2f} ms, "
        f"wall {record['wall_time_s']:.1f} s"
    )


def cmd_list(args: argparse.Namespace) -> int:
    if args.fields is not None:
        return _list_fields(args.fields)
    print("optimizers:")
    for name in sorted(OPTIMIZERS):
        print(f"  {name:<36} {OPTIMIZERS[name].description}")
    missing = OPTIMIZERS.missing()
    if missing:
        print("optimizers not available here:")
        for name, reason in sorted(missing.items()):
            print(f"  {name:<36} {reason}")
    print("scenarios:")
    for name, scenario in sorted(SCENARIOS.items()):
        print(
            f"  {name:<36} {scenario.n_uav} UAVs, reference '{scenario.reference}', "
            f"{scenario.timing.n_steps} instants of {scenario.timing.period_s:g} s"
        )
    print("reference paths: " + ", ".join(sorted(REFERENCE_PATHS)))
    return 0


def _list_fields(name: str) -> int:
    """The settable fields of a registered optimiser or scenario, as ``--set`` takes them."""
    from formation_bench.fields import describe_fields

    if name in OPTIMIZERS:
        kind, obj = "optimizer", OPTIMIZERS[name].optimizer
    elif name in SCENARIOS:
        kind, obj = "scenario", SCENARIOS[name]
    else:
        allowed = ", ".join([*sorted(OPTIMIZERS), *sorted(SCENARIOS)])
        raise UsageError(f"--fields: unknown optimizer or scenario {name!r}; allowed: {allowed}")
    print(f"{kind} {name} ({type(obj).__name__}); set with --set {kind}.FIELD=VALUE")
    if kind == "optimizer":
        for line in tuned_provenance_lines(name):
            print(f"  {line}")
    _print_fields(obj, describe_fields, tunable=kind == "optimizer")
    return 0


def tuned_provenance_lines(name: str) -> list[str]:
    """Where a tuned variant's values come from (empty for any other optimiser)."""
    from formation_bench.optimizers.tuned import tuned_data

    data = tuned_data(name)
    if data is None:
        return []
    objective, tuner, made = data["objective"], data["tuner"], data["provenance"]
    if objective["kind"] == "solve":
        subset = "" if objective["problems"] is None else f" (first {objective['problems']})"
        on = f"split {objective['split']} of library {objective['library']}{subset}"
    else:
        on = f"suite {objective['suite']}, seeds {', '.join(map(str, objective['seeds']))}"
    tuned = ", ".join(f"{k}={shown_value(v)}" for k, v in data["values"].items())
    measure = objective["metric"]
    if not measure.startswith(objective["statistic"]):
        measure = f"{objective['statistic']} {measure}"
    return [
        f"tuned from {data['base']}: {tuned}",
        f"tuner: {tuner['library']} {tuner['version']} {tuner['sampler']}, {tuner['trials']} "
        f"trials in batches of {tuner['batch']}, seed {tuner['seed']}",
        f"objective: {measure} ({objective['kind']}) on "
        f"{on}, {objective['budget']} evaluations per solve: {data['default_value']:.6g} at "
        f"{data['base']}, {data['best_value']:.6g} tuned",
        f"made: {made['date']}, commit {made['commit']}, formation-bench {made['version']}, "
        f"{made['wall_time_s']:.0f} s on {made['machine']}",
    ]


def _print_fields(obj: Any, describe_fields: Any, tunable: bool) -> None:
    """Each setting of ``obj``, with what a tuner searches of it when ``tunable`` (an
    optimiser's); a group of settings (a field holding a config dataclass) as its settings,
    set by their own names."""
    for info in describe_fields(obj):
        if dataclasses.is_dataclass(info.value) and not isinstance(info.value, type):
            print(f"  [{info.name}] {info.doc}")
            _print_fields(info.value, describe_fields, tunable)
            continue
        search = f"; {info.search}" if tunable else ""
        print(f"  {info.name} = {shown_value(info.value)}  ({info.type}; {info.allowed}{search})")
        print(f"      {info.doc}")


def shown_value(value: Any) -> str:
    """A setting's value as ``list --fields`` and the generated reference show it."""
    import enum

    if isinstance(value, enum.Enum):
        return member_text(value)
    return repr(value)


def cmd_run(args: argparse.Namespace) -> int:
    scenario, optimizer = _build(args)
    budget = requested_budget(args.max_evaluations, args.max_iterations, args.deadline_ms)
    _check(scenario, optimizer, solve_budget(budget, optimizer))
    spec = RunSpec.of(
        args.optimizer, optimizer, args.scenario, scenario,
        trigger=args.trigger, seed=args.seed, budget=budget, plugins=plugins.loaded_plugins(),
    )  # fmt: skip
    with _staged(args) as out:
        compile_notice({args.optimizer: optimizer})
        with _progress_bar(
            spec.optimizer_label, scenario.timing.n_steps, args.progress
        ) as progress:
            outcome = execute(spec, progress=progress)
        record = outcome.record.to_json()
        write_metrics(out / "metrics.json", [record])
        write_trace(out / "trace.parquet", outcome.table)
        if args.figures:
            from formation_bench.analysis import run_figures  # Matplotlib: only when drawing

            suffix = "trigger" if args.trigger else "no_trigger"
            numbers = (5, 6) if args.trigger else (3, 4)
            frame, run_scenario = outcome.frame, outcome.trace.scenario
            run_figures.write_run_figures(frame, run_scenario, out, suffix, numbers)
            run_figures.write_trigger_figure(frame, out, f"fig7_solve_instants_{suffix}.png")
    print(_summary(record))
    print(f"wrote {args.out}/metrics.json, trace.parquet{' and figures' if args.figures else ''}")
    return 0


def _check(scenario: Scenario, optimizer: Optimizer, budget: Budget | None) -> None:
    try:
        check_run(scenario, optimizer, budget)
    except LimitError as err:
        raise UsageError(str(err)) from None


@contextlib.contextmanager
def _staged(args: argparse.Namespace) -> Iterator[Path]:
    """The staged output folder of a command; checked before any work starts."""
    try:
        with staged_folder(Path(args.out), overwrite=args.overwrite) as folder:
            yield folder
    except OutputError as err:
        raise UsageError(str(err)) from None


@contextlib.contextmanager
def _progress_bar(label: str, total: int, show: bool | None) -> Iterator[ProgressCallback]:
    """A progress bar on stderr (by default only on a terminal), fed by the loop's callback."""
    if not (sys.stderr.isatty() if show is None else show):
        yield _no_progress
        return
    from tqdm import tqdm

    with tqdm(
        total=total, desc=label, unit="instant", file=sys.stderr, leave=False,
        disable=None if show is None else not show,
    ) as bar:  # fmt: skip

        def advance(done: int, total: int) -> None:
            bar.update(done - bar.n)

        yield advance


def _no_progress(done: int, total: int) -> None:
    pass


def reproduce_one(
    seed: int, out: Path, *, figures: bool = True, progress: bool | None = None
) -> list[dict[str, Any]]:
    """Both paper runs (without, then with trigger) for one seed; writes outputs to ``out``
    and returns their records."""
    scenario = get_scenario("paper")
    optimizer = get_optimizer(DEFAULT_OPTIMIZER)
    outcomes: list[RunOutcome] = []
    for trigger in (False, True):
        spec = RunSpec.of(
            DEFAULT_OPTIMIZER, optimizer, "paper", scenario, trigger=trigger, seed=seed
        )
        label = f"seed {seed}, {'with' if trigger else 'without'} trigger"
        with _progress_bar(label, scenario.timing.n_steps, progress) as advance:
            outcome = execute(spec, progress=advance)
        outcomes.append(outcome)
        print(_summary(outcome.record.to_json()), flush=True)
    import pyarrow as pa

    records = [o.record.to_json() for o in outcomes]
    write_metrics(out / "metrics.json", records)
    write_trace(out / "trace.parquet", pa.concat_tables([o.table for o in outcomes]))
    if figures:
        from formation_bench.analysis import run_figures  # Matplotlib: only when drawing

        for outcome, suffix, numbers in zip(
            outcomes, ("no_trigger", "trigger"), ((3, 4), (5, 6)), strict=True
        ):
            run_figures.write_run_figures(
                outcome.frame, outcome.trace.scenario, out, suffix, numbers
            )
        run_figures.write_trigger_figure(outcomes[1].frame, out, "fig7_solve_instants.png")
    return records


def cmd_reproduce(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    out = Path(args.out)
    seeds = args.seeds
    settle = get_scenario("paper").evaluation.settle_time_s
    with _staged(args) as staging:
        # after the output checks, so a refused command prints one line
        compile_notice({DEFAULT_OPTIMIZER: get_optimizer(DEFAULT_OPTIMIZER)})
        runs = {
            seed: reproduce_one(
                seed,
                staging if len(seeds) == 1 else staging / f"seed{seed}",
                figures=args.figures,
                progress=args.progress,
            )
            for seed in seeds
        }
        if len(seeds) > 1:
            table = format_seed_table({seed: comparison_rows(m) for seed, m in runs.items()})
            write_text(staging / "summary.md", table + "\n")
    files = ["metrics.json", "trace.parquet"]
    if args.figures:
        files += ["figures fig3-fig7", "separation_*"]
    where = f"{out}/seed*, and summary.md to {out}" if len(seeds) > 1 else str(out)
    print(
        f"wrote {', '.join(files[:-1])} and {files[-1]} to {where} "
        f"({time.perf_counter() - start:.1f} s)"
    )
    print()
    print(
        f"Paper scenario, {DEFAULT_OPTIMIZER}, seed{'s' if len(seeds) > 1 else ''} "
        f"{', '.join(map(str, seeds))} (errors after the {settle:g} s settle time):"
    )
    if len(seeds) == 1:
        rows = comparison_rows(runs[seeds[0]])
        print(format_table(rows))
        held = sum(row["holds"] for row in rows)
        print(f"{held} of {len(rows)} reported figures reached.")
    else:
        print(table)
    from formation_bench.analysis.paper_budget import shipped_line  # pandas

    print()
    print(shipped_line(DEFAULT_OPTIMIZER))  # the last line, as the docs say
    return 0


def add_output_options(command: argparse.ArgumentParser) -> None:
    """``--figures``, ``--overwrite`` and ``--progress``, as ``run`` and ``reproduce`` take them."""
    command.add_argument(
        "--figures",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="draw the figures (default); --no-figures writes metrics and trace only",
    )
    command.add_argument(
        "--overwrite",
        action="store_true",
        help="replace a non-empty output folder (as a whole) instead of refusing",
    )
    command.add_argument(
        "--progress",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="progress bar on stderr (default: only on a terminal)",
    )


def build_parser() -> _Parser:
    parser = _Parser(
        prog="formation-bench",
        description=textwrap.fill(
            "Optimisers inside a distributed MPC of UAV formations: reproduce the paper, run "
            "closed loops, sweep suites and report their statistics.",
            HELP_WIDTH,
        ),
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--version", action="version", version=f"formation-bench {formation_bench.__version__}"
    )
    parser.add_argument(
        "--plugin",
        action="append",
        default=[],
        metavar="MODULE_OR_FILE",
        help="import a module (dotted name) or a .py file that registers optimizers or "
        "scenarios before the command runs (repeatable; sweep workers load it too)",
    )
    # not required: without a command, main() prints the overview of the commands
    sub = parser.add_subparsers(
        dest="command", metavar="COMMAND", title="commands", parser_class=_Parser
    )
    parser.commands = sub

    reproduce = add_command(
        sub,
        "reproduce",
        """Reproduce the paper: its scenario with the modified BSO, without and with the
        trigger. Every figure the paper reports is set beside the measured value.

        Writes metrics.json (one record per run), trace.parquet (every instant of every UAV)
        and the figures (fig3-fig7 like the paper's, separation_*) to --out, which appears
        only when complete. With several seeds: one folder OUT/seedN per seed, and
        OUT/summary.md with every figure over the seeds.

        Prints each run's summary, then the table of the paper's figures, and last the
        evaluation budget the paper's figures need (read from the shipped paper-budget sweep,
        not run again).""",
        examples=(
            ("formation-bench reproduce", "seed 0, into results/reproduce"),
            (
                "formation-bench reproduce --seeds 0 1 2 3 4 --out out/paper",
                "five seeds, and a table of every figure over them",
            ),
        ),
    )
    reproduce.add_argument(
        "--out", default="results/reproduce", help="output folder (default: results/reproduce)"
    )
    reproduce.add_argument(
        "--seed",
        "--seeds",
        dest="seeds",
        type=seed,
        nargs="+",
        default=[0],
        help="run seed(s), integers >= 0 (default 0); several seeds write DIR/seedN/ each "
        "and a table of every figure over the seeds",
    )
    add_output_options(reproduce)
    reproduce.set_defaults(func=cmd_reproduce)

    run = add_command(
        sub,
        "run",
        """Run one closed loop: one optimiser in the distributed MPC of one scenario. With the
        event trigger (default) or solving at every instant (--no-trigger).

        Writes metrics.json (the run's record), trace.parquet (every instant of every UAV)
        and, unless --no-figures, the run's figures to --out, which appears only when
        complete. Prints a one-line summary of the run. 'formation-bench list' names the
        optimisers and scenarios; 'formation-bench list --fields NAME' lists the fields --set
        takes.""",
        examples=(
            (
                "formation-bench run --optimizer pso --no-trigger --seed 3 --out out/pso",
                "PSO on the paper scenario, solving at every instant",
            ),
            (
                "formation-bench run --optimizer modified-bso --set scenario.reference=s-curve "
                "--out out/s",
                "the modified BSO on the S-curve reference path",
            ),
            (
                "formation-bench run --optimizer cma-es --max-evaluations 1200 --out out/cma",
                "CMA-ES with 1200 cost evaluations per solve",
            ),
            (
                "formation-bench --plugin my_search.py run --optimizer my-random-search "
                "--out out/mine",
                "an optimiser registered by a plugin file (--plugin goes before the command)",
            ),
        ),
    )
    run.add_argument("--optimizer", required=True, help="registered optimizer name (see 'list')")
    run.add_argument(
        "--scenario", default="paper", help="registered scenario name (default: paper)"
    )
    run.add_argument(
        "--trigger",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="use the event trigger (default) or solve at every instant",
    )
    run.add_argument("--seed", type=seed, default=0, help="run seed, integer >= 0 (default 0)")
    run.add_argument(
        "--set",
        action="append",
        metavar="FIELD=VALUE",
        help="override a scenario or optimizer field (repeatable); "
        "prefix with scenario. or optimizer. if ambiguous",
    )
    run.add_argument(
        "--max-evaluations",
        type=budget_limit,
        metavar="N",
        help="per-solve evaluation budget (default: the optimizer's own budget)",
    )
    run.add_argument(
        "--max-iterations",
        type=budget_limit,
        metavar="N",
        help="per-solve iteration budget (default: the optimizer's own budget)",
    )
    run.add_argument(
        "--deadline-ms",
        type=deadline_ms,
        metavar="MS",
        help="per-solve wall-clock deadline in milliseconds: a solve returns its best point "
        "so far when it passes (results then depend on the machine's speed); without "
        "--max-evaluations or --max-iterations it caps the optimizer's own budget",
    )
    run.add_argument("--out", required=True, help="output folder")
    add_output_options(run)
    run.set_defaults(func=cmd_run)

    listing = add_command(
        sub,
        "list",
        """List the registered optimisers, scenarios and reference paths.

        With --fields NAME: the settings of one optimiser or scenario, each with its value,
        allowed values and meaning, as --set takes them. Prints to stdout and writes
        nothing.""",
        examples=(
            ("formation-bench list", "every optimiser and scenario"),
            ("formation-bench list --fields pso", "the settings of pso"),
        ),
    )
    listing.add_argument(
        "--fields",
        metavar="NAME",
        help="the settable fields of one optimizer or scenario: value, allowed values, what a "
        "tuner searches (an optimizer's), meaning",
    )
    listing.set_defaults(func=cmd_list)

    add_sweep_commands(sub)
    add_tune_command(sub)
    return parser


STAGED_OUTPUT_COMMANDS = ("run", "reproduce", "report", "export-ioh")
"""Commands whose --out is written whole beside it, then renamed into place (the others
resume into their folder)."""


def _check_arguments(args: argparse.Namespace) -> None:
    """Checks that span a whole option or several (argparse checks each value on its own),
    and the environment variables the package reads."""
    try:
        check_environment()
        out = getattr(args, "out", None)
        if out is not None:
            check_out_path(out, staged=args.command in STAGED_OUTPUT_COMMANDS)
        if getattr(args, "results", None) is not None:
            check_out_path(args.results, "DIR", staged=False)
        if getattr(args, "page", None) is not None:
            check_out_path(args.page, "--page", staged=False)
        if args.command in ("reproduce", "score"):
            check_seed_count(len(set(args.seeds)))
            _check_distinct("--seeds", args.seeds)
        if args.command == "score":
            _check_distinct("--budgets", args.budgets)
        if args.command in ("sweep", "score", "tune") and getattr(args, "scheduler", None) is None:
            check_jobs(args.jobs)
    except (LimitError, EnvironmentValueError) as err:
        raise UsageError(str(err)) from None


def _check_distinct(option: str, values: list[Any]) -> None:
    """Refuse a value given twice: each is a run of its own, and running it once would merge
    the two without a word."""
    seen = set()
    for value in values:
        if value in seen:
            raise UsageError(f"{option}: {value} is given twice; give each value once")
        seen.add(value)


def _take_over_interrupts() -> Any:
    """Make Ctrl-C end the command in one line; returns the handler to restore.

    The first Ctrl-C raises KeyboardInterrupt, as Python's own handler does. A second press
    within :data:`REPEAT_GRACE_S` of it is dropped, so that it cannot cut short the clean-up
    the first one started (removing a half-written folder) nor turn the one line into a
    traceback. A later press raises again: Python runs a signal handler wherever the main
    thread is, and a KeyboardInterrupt raised inside a weakref callback or a ``__del__`` is
    printed and discarded, so ignoring every press after the first could leave the command
    running for good. A process that ignores Ctrl-C (started in the background) keeps
    ignoring it.
    """
    if threading.current_thread() is not threading.main_thread():
        return None
    previous = signal.getsignal(signal.SIGINT)
    if previous in (signal.default_int_handler, command_start.interrupted_while_starting):
        _first_press.clear()
        signal.signal(signal.SIGINT, _interrupt_once)
        return previous
    return None


REPEAT_GRACE_S = 2.0
"""How long after a first Ctrl-C a second one counts as the same request to stop."""
_first_press: list[float] = []


def _interrupt_once(signum: int, frame: FrameType | None) -> None:
    now = time.monotonic()
    if unsafe_to_raise(frame):
        interrupt_again_soon(signum)  # not yet a press: it counts when it is raised
        return
    if not delivered_again() and _first_press and now - _first_press[0] < REPEAT_GRACE_S:
        return
    _first_press[:] = [now]
    raise_keyboard_interrupt(signum)


PLUGIN_OPTION = "--plugin"


def misplaced_plugin(argv: list[str], commands: list[str]) -> str | None:
    """The error for a ``--plugin`` given after the command (which the command's own options
    would refuse as unknown, or take as a value), with the command line in the right order;
    None when every ``--plugin`` comes first."""
    names = set(commands)
    at = 0
    while at < len(argv) and argv[at] not in names:
        at += 2 if argv[at] == PLUGIN_OPTION else 1
    moved: list[str] = []
    rest: list[str] = []
    tail = iter(argv[at + 1 :])
    for token in tail:
        if token == "--":  # what follows is not an option
            rest += [token, *tail]
        elif token == PLUGIN_OPTION:
            value = next(tail, None)
            if value is None or value.startswith("-"):
                rest += [] if value is None else [value]
                value = "MODULE_OR_FILE"
            moved += [token, value]
        elif token.startswith(PLUGIN_OPTION + "="):
            moved.append(token)
        else:
            rest.append(token)
    if at >= len(argv) or not moved:
        return None
    corrected = shlex.join([*argv[:at], *moved, argv[at], *rest])
    return f"{PLUGIN_OPTION} goes before the command: formation-bench {corrected}"


def main(argv: list[str] | None = None) -> int:
    previous = _take_over_interrupts()
    command = "formation-bench"
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        parser = build_parser()
        assert parser.commands is not None  # for the type checker: build_parser sets them
        misplaced = misplaced_plugin(argv, list(parser.commands.choices))
        if misplaced is not None:
            raise UsageError(misplaced)  # before argparse, whose own error would come first
        args = parser.parse_args(argv)
        if args.command is None:
            print(parser.overview(), end="", file=sys.stderr)
            return 2
        command = f"formation-bench {args.command}"
        _check_arguments(args)
        plugins.load_plugins(args.plugin)
        return args.func(args)
    except (UsageError, plugins.PluginError) as err:
        print(f"{command}: error: {err}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into e.g. `head`, which stopped reading
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except BaseException as err:  # C code wraps an interrupt in its own error, of any class
        if not is_interrupt(err):
            raise
        if previous is not None:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        print(f"{command}: interrupted", file=sys.stderr)
        return command_start.INTERRUPTED_EXIT
    finally:
        if previous is not None:
            # the command itself exits next, and a Ctrl-C then must not print a traceback
            # either; a caller of main() in its own process gets its handler back
            signal.signal(
                signal.SIGINT, signal.SIG_IGN if command_start.is_the_command() else previous
            )


if __name__ == "__main__":
    sys.exit(main())
