"""What a tuning is (:class:`TuningSettings`), and the data it may not touch.

A tuning searches the settings an optimiser declares with ``search=`` for the configuration
that minimises one objective, on data that no results page uses: the per-solve objective
solves the library's validation split only (the leaderboard scores the test split), and the
closed-loop objective runs seeds that no shipped suite runs (the results pages come from the
shipped suites). :func:`check_settings` refuses anything else before any work starts.
"""

from __future__ import annotations

import enum
import functools
from dataclasses import dataclass

from formation_bench.experiments.score import SPLITS
from formation_bench.experiments.suite import Suite, SuiteError, load_suite, shipped_suites
from formation_bench.fields import Validated, check_int, setting
from formation_bench.instances.library import LIBRARY_VERSIONS, SHIPPED_VERSION
from formation_bench.mpc.metrics import Better, Per, metric_infos
from formation_bench.optimizers import OPTIMIZERS, optimizer_names
from formation_bench.optimizers.base import BUDGET_MINIMUM
from formation_bench.optimizers.tuned import is_tuned
from formation_bench.pipeline.checks import MAX_SEED


class TuningError(ValueError):
    """A tuning that cannot be made as asked (one line, naming the option)."""


class Objective(enum.Enum):
    """What a trial's configuration is scored by."""

    SOLVE = "solve"
    """The median normalised gap over the library's validation split (non-degenerate)."""
    LOOP = "loop"
    """The median of a record column over closed loops at validation seeds."""


TUNING_SPLIT = "validation"
"""The only split a tuning may solve: the leaderboard scores the others."""
SCORE_RUN_SEEDS = (0,)
"""Seeds of the leaderboard's score runs (on the test split)."""
DEFAULT_LOOP_SEEDS = tuple(range(1000, 1010))
"""Closed-loop validation seeds: far above every shipped suite's (0 .. 29)."""


def loop_metrics() -> tuple[str, ...]:
    """Record columns a closed-loop tuning may minimise: one value per run, lower is better,
    not a timing (a timing depends on the machine)."""
    return tuple(
        info.name
        for info in metric_infos()
        if info.per is Per.RUN and info.better is Better.LOWER and not info.timing
    )


def _seed_list(owner: str, name: str, value: object) -> tuple[int, ...]:
    if not isinstance(value, list | tuple) or not value:
        raise ValueError(f"{owner}.{name} must be a non-empty list of seeds, got {value!r}")
    seeds = tuple(check_int(owner, name, s, 0, MAX_SEED) for s in value)
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"{owner}.{name} must be distinct seeds, got {list(seeds)}")
    return seeds


@dataclass(frozen=True)
class TuningSettings(Validated):
    """One tuning: which optimiser, by which objective, with how many trials and seeds."""

    optimizer: str = setting(
        "pso", choices=optimizer_names, doc="Registered optimiser whose searched settings are tuned"
    )
    objective: Objective = setting(
        Objective.SOLVE, doc="solve: median normalised gap per solve; loop: closed-loop metric"
    )
    trials: int = setting(100, low=1, doc="Configurations evaluated (trial 0: the base one)")
    batch: int = setting(
        4, low=1, doc="Trials asked at once, before any of them is evaluated (not the workers)"
    )
    seed: int = setting(100, low=0, high=MAX_SEED, doc="Seed of the sampler and of the solves")
    max_evaluations: int = setting(
        1200, low=BUDGET_MINIMUM, doc="Evaluation budget of every solve (the suites' 1200)"
    )
    library: str = setting(
        SHIPPED_VERSION, choices=LIBRARY_VERSIONS, doc="Instance library (solve objective)"
    )
    split: str = setting(
        TUNING_SPLIT, choices=SPLITS, doc="Library split solved; only validation is allowed"
    )
    problems: int | None = setting(
        None, low=1, kind=int, optional=True,
        doc="Solve only the split's first N problems (quick checks; None: all)",
    )  # fmt: skip
    suite: str = setting(
        "comparison",
        allowed="a shipped suite or a suite .toml file",
        doc="Suite whose scenario and trigger the closed loops run (loop objective)",
    )
    seeds: tuple[int, ...] = setting(
        DEFAULT_LOOP_SEEDS,
        check=_seed_list,
        allowed="distinct integers >= 0 that no shipped suite uses",
        doc="Closed-loop validation seeds (loop objective)",
    )
    metric: str = setting(
        "steady_state_cost", choices=loop_metrics,
        doc="Record column minimised (loop objective; lower is better)",
    )  # fmt: skip

    @property
    def variant_name(self) -> str:
        """The tuned variant's registered name: ``NAME-tuned`` or ``NAME-tuned-loop``."""
        suffix = "-tuned" if self.objective is Objective.SOLVE else "-tuned-loop"
        return self.optimizer + suffix


@functools.cache
def shipped_suite_seeds() -> frozenset[int]:
    """Every seed a shipped suite runs: the seeds of the results pages."""
    seeds: set[int] = set()
    for name in shipped_suites():
        seeds.update(load_suite(name).seeds)
    return frozenset(seeds)


def check_settings(settings: TuningSettings) -> Suite | None:
    """Refuse, naming the option, what a tuning may not do (the data first, then the
    optimiser); returns the loop objective's suite (None for the solve objective)."""
    suite = check_data(settings)
    check_optimizer(settings.optimizer)
    return suite


def check_optimizer(name: str) -> None:
    """Refuse a tuned variant, and an optimiser with nothing to search."""
    from formation_bench.tuning.space import search_space

    if is_tuned(name):
        raise TuningError(
            f"--optimizer: {name!r} is itself a tuned variant; tune its base "
            "optimizer instead"
        )
    if not search_space(OPTIMIZERS[name].optimizer):
        raise TuningError(
            f"--optimizer: {name!r} has no searched settings; declare search= on "
            "the settings of its configuration (formation_bench.fields.Search) to tune it"
        )


def check_data(settings: TuningSettings) -> Suite | None:
    """Refuse a test-split problem and a seed of the results pages."""
    used = shipped_suite_seeds() | set(SCORE_RUN_SEEDS)
    if settings.seed in used:
        raise TuningError(
            f"--seed: {settings.seed} is a seed of the results pages (shipped suites' seeds "
            f"{_ranges(shipped_suite_seeds())} and the score runs' seed 0); choose another"
        )
    if settings.objective is Objective.SOLVE:
        if settings.split != TUNING_SPLIT:
            raise TuningError(
                f"--split: {settings.split!r} holds problems the leaderboard scores; a tuning "
                f"solves the {TUNING_SPLIT} split only"
            )
        return None
    try:
        suite = load_suite(settings.suite)
    except SuiteError as err:
        raise TuningError(f"--suite: {err}") from None
    if len(suite.scenarios) != 1 or len(suite.triggers) != 1:
        raise TuningError(
            f"--suite: {suite.name} runs {len(suite.scenarios)} scenario(s) and "
            f"{len(suite.triggers)} trigger setting(s); the loop objective takes a suite with "
            "one of each"
        )
    clash = sorted((shipped_suite_seeds() | set(suite.seeds)) & set(settings.seeds))
    if clash:
        raise TuningError(
            f"--seeds: {', '.join(map(str, clash[:5]))} are seeds of the results pages (the "
            f"shipped suites run {_ranges(shipped_suite_seeds())}); choose seeds no suite uses"
        )
    return suite


def _ranges(seeds: frozenset[int]) -> str:
    """``0..29`` for a run of consecutive seeds, else the list."""
    ordered = sorted(seeds)
    if ordered == list(range(ordered[0], ordered[-1] + 1)):
        return f"{ordered[0]}..{ordered[-1]}"
    return ", ".join(map(str, ordered))
