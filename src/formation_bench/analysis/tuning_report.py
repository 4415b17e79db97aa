"""The report of a folder of tuned-variant files: what each tuning found, what it cost, and
the curves that chose the trial count.

A tuned-variant file (``<NAME>.json``, NAME ``<base>-tuned`` for the per-solve objective,
``<base>-tuned-loop`` for the closed-loop one) is what ``formation-bench tune`` writes and
what the package ships in ``formation_bench/optimizers/tuned/``. A folder is a tuning folder
by its files: it holds such files (and no ``runs/`` or ``score/``). :func:`read_folder`
reads and checks every one before anything is written; a file that is not JSON, or lacks a
field, or holds one of the wrong type, stops the report with one line naming the file and
the field.

The report, ``tuning.md`` with ``tuning.csv`` (one row per variant) and
``tuning_curves.csv`` (each variant's best value found so far against the trial count) and,
with figures, ``figures/tuning_best_so_far.png``:

- per variant: its base, objective (kind, metric, evaluation budget), the tuner's trials,
  batch and seed, the objective at the base configuration (trial 0) and at the tuned one,
  the tuned settings and the wall time (in tables of the same rows where one table would not
  fit the documentation's content column:
  :func:`~formation_bench.analysis.score_report.fitted_table`), and the total wall time of
  the tunings;
- the best value found so far (the running minimum of the trials' values) against the trial
  count, divided by the variant's default value so that every family shares an axis, one
  panel per objective kind;
- the flattening point of each variant (:func:`flattening_trials`): the trial count after
  which the best value found so far improved by less than :data:`FLAT_SHARE` of the default
  value, and the largest of them over the variants.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from formation_bench.analysis.comparison import ReportError
from formation_bench.analysis.score_report import Column, fitted_table
from formation_bench.optimizers.tuned import TUNED_FORMAT

FORMAT = TUNED_FORMAT
"""The tuned-variant file format this report reads."""
KIND_SUFFIXES = {"solve": "-tuned", "loop": "-tuned-loop"}
"""Objective kind -> the ending of the name of the variant tuned on it."""
FLAT_SHARE = 0.01
"""The flattening point: the best value found so far improves by less than this share of the
default value after it."""
FLAT_TRIALS = 25
"""A curve has flattened when its flattening point lies at least this many trials before its
last trial: that many trials in a row found no gain of :data:`FLAT_SHARE` (six batches of the
tuner's default four, and an eighth of the per-solve count)."""
FIGURE = "tuning_best_so_far.png"
"""The figure's file name in the report folder's ``figures/``."""


class TunedFileError(ReportError):
    """A tuned-variant file the report cannot read (one line naming the file and the field)."""


@dataclass(frozen=True)
class Objective:
    """What a tuning minimised."""

    kind: str
    """``solve`` (a statistic of the normalised gap over library problems) or ``loop`` (a
    statistic of a closed-loop metric over suite seeds)."""
    budget: int
    """Objective evaluations per solve."""
    metric: str
    statistic: str
    split: str | None
    library: str | None
    suite: str | None
    seeds: tuple[int, ...] | None
    problems: int | None


@dataclass(frozen=True)
class Tuner:
    """The tuner and its settings."""

    library: str
    version: str
    sampler: str
    trials: int
    batch: int
    seed: int


@dataclass(frozen=True)
class TuningProvenance:
    """Where and when a tuning ran."""

    date: str
    commit: str | None
    """None when the tuning's code had no known commit."""
    version: str
    command: str
    """The command line (empty for a tuning not started from the command line)."""
    wall_time_s: float
    machine: str


@dataclass(frozen=True)
class TunedVariant:
    """One tuned-variant file, checked."""

    path: Path
    name: str
    base: str
    values: dict[str, Any]
    objective: Objective
    tuner: Tuner
    provenance: TuningProvenance
    default_value: float
    best_value: float
    history: tuple[float, ...]
    """The objective value of each trial, in trial order (trial 0: the base configuration)."""

    @property
    def best_so_far(self) -> np.ndarray:
        """The best value found after each trial: the running minimum of :attr:`history`."""
        return np.minimum.accumulate(np.asarray(self.history, dtype=float))


# --- reading --------------------------------------------------------------------------------


def tuned_files(folder: Path) -> list[Path]:
    """The tuned-variant files of ``folder`` (``*-tuned.json``, ``*-tuned-loop.json``, not in
    subfolders), sorted by name."""
    return sorted(
        p for p in Path(folder).glob("*.json") if p.stem.endswith(tuple(KIND_SUFFIXES.values()))
    )


def read_folder(folder: Path) -> list[TunedVariant]:
    """Every tuned-variant file of ``folder``, checked (:func:`read_tuned`)."""
    return [read_tuned(path) for path in tuned_files(folder)]


class _Fields:
    """The checks of one JSON object of a file, naming the field (``tuner.trials``) and what
    it must be."""

    def __init__(self, path: Path, data: Any, prefix: str = "") -> None:
        self.path, self.prefix = path, prefix
        if not isinstance(data, dict):
            raise self.fail(prefix.rstrip(".") or "the file", "must be a JSON object", data)
        self.data = data

    def fail(self, field: str, what: str, got: Any) -> TunedFileError:
        shown = json.dumps(got) if not isinstance(got, _Missing) else "nothing"
        if len(shown) > 60:
            shown = shown[:57] + "..."
        return TunedFileError(f"{self.path}: {field}: {what}, got {shown}")

    def get(self, key: str, what: str, ok: Any, *, optional: bool = False) -> Any:
        value = self.data.get(key, _MISSING)
        if optional and value is None:
            return None
        if isinstance(value, _Missing) or not ok(value):
            raise self.fail(self.prefix + key, what + (" or null" if optional else ""), value)
        return value

    def text(self, key: str, *, optional: bool = False) -> str | None:
        return self.get(key, "must be a non-empty string", _is_text, optional=optional)

    def integer(self, key: str, low: int | None = None, *, optional: bool = False) -> int | None:
        what = "must be an integer" + (f" >= {low}" if low is not None else "")
        return self.get(
            key, what, lambda v: _is_int(v) and (low is None or v >= low), optional=optional
        )

    def number(self, key: str, low: float | None = None) -> float:
        what = "must be a finite number" + (f" >= {low:g}" if low is not None else "")
        return float(self.get(key, what, lambda v: _is_number(v) and (low is None or v >= low)))

    def choice(self, key: str, allowed: tuple[str, ...]) -> str:
        return self.get(key, f"must be one of {', '.join(allowed)}", lambda v: v in allowed)

    def child(self, key: str) -> _Fields:
        return _Fields(self.path, self.data.get(key, _MISSING), f"{self.prefix}{key}.")


class _Missing:
    pass


_MISSING = _Missing()


def _is_text(value: Any) -> bool:
    return isinstance(value, str) and bool(value.strip())


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _is_setting(value: Any) -> bool:
    return isinstance(value, bool | str) or _is_number(value)


def read_tuned(path: Path) -> TunedVariant:
    """The tuned-variant file ``path``, checked against the format; raises
    :class:`TunedFileError` naming the file and the first field that is wrong."""
    path = Path(path)
    try:
        data = json.loads(path.read_text(), parse_constant=_no_constant)
    except (OSError, UnicodeDecodeError) as err:
        raise TunedFileError(f"{path}: cannot be read ({err})") from None
    except (json.JSONDecodeError, ValueError) as err:
        raise TunedFileError(f"{path}: not a JSON file ({err})") from None
    top = _Fields(path, data)
    if data.get("format") != FORMAT:
        raise top.fail("format", f"must be {FORMAT} (the format this report reads)",
                       data.get("format", _MISSING))  # fmt: skip
    goal = top.child("objective")
    kind = goal.choice("kind", tuple(KIND_SUFFIXES))
    objective = Objective(
        kind=kind,
        budget=goal.integer("budget", 1),
        metric=goal.text("metric"),
        statistic=goal.text("statistic"),
        split=goal.text("split", optional=True),
        library=goal.text("library", optional=True),
        suite=goal.text("suite", optional=True),
        seeds=_seeds(goal),
        problems=goal.integer("problems", 1, optional=True),
    )
    base = top.text("base")
    name = top.get(
        "name",
        f"must be the base's name with {KIND_SUFFIXES[kind]!r} ({kind} objective) and the file's "
        f"name without .json, {path.stem!r}",
        lambda v: v == path.stem == f"{base}{KIND_SUFFIXES[kind]}",
    )
    values = top.get(
        "values",
        "must be an object of setting names and numbers, strings or true/false",
        lambda v: isinstance(v, dict) and all(_is_setting(x) for x in v.values()),
    )
    tuner_fields = top.child("tuner")
    tuner = Tuner(
        library=tuner_fields.text("library"),
        version=tuner_fields.text("version"),
        sampler=tuner_fields.text("sampler"),
        trials=tuner_fields.integer("trials", 1),
        batch=tuner_fields.integer("batch", 1),
        seed=tuner_fields.integer("seed", 0),
    )
    made = top.child("provenance")
    provenance = TuningProvenance(
        date=made.get("date", "must be an ISO date and time", _is_iso),
        commit=made.text("commit", optional=True),
        version=made.text("version"),
        command=made.get("command", "must be a string", lambda v: isinstance(v, str)),
        wall_time_s=made.number("wall_time_s", 0.0),
        machine=made.text("machine"),
    )
    history = top.get(
        "history",
        f"must be a list of {tuner.trials} finite numbers (tuner.trials), one per trial",
        lambda v: isinstance(v, list) and len(v) == tuner.trials and all(_is_number(x) for x in v),
    )
    return TunedVariant(
        path=path,
        name=name,
        base=base,
        values=dict(values),
        objective=objective,
        tuner=tuner,
        provenance=provenance,
        default_value=top.number("default_value"),
        best_value=top.number("best_value"),
        history=tuple(float(x) for x in history),
    )


def _no_constant(name: str) -> None:
    raise ValueError(f"{name} is not a JSON number")


def _seeds(fields: _Fields) -> tuple[int, ...] | None:
    seeds = fields.get(
        "seeds",
        "must be a non-empty list of integers >= 0",
        lambda v: isinstance(v, list) and v and all(_is_int(s) and s >= 0 for s in v),
        optional=True,
    )
    return None if seeds is None else tuple(seeds)


def _is_iso(value: Any) -> bool:
    import datetime as dt

    if not _is_text(value):
        return False
    try:
        dt.datetime.fromisoformat(value)
    except ValueError:
        return False
    return True


# --- the tables -----------------------------------------------------------------------------


def flattening_trials(variant: TunedVariant, share: float = FLAT_SHARE) -> int | None:
    """The trial count after which the best value found so far improved, to the last trial,
    by less than ``share`` of the default value (absolute); None when the default value is 0
    (no relative measure)."""
    threshold = share * abs(variant.default_value)
    if threshold == 0:
        return None
    best = variant.best_so_far
    left = best - best[-1]  # what the trials after each one still gained
    return int(np.flatnonzero(left < threshold)[0]) + 1


def settings_text(values: dict[str, Any]) -> str:
    """The tuned settings as ``k=v`` (as ``--set`` takes them), floats to 4 digits."""

    def shown(value: Any) -> str:
        if isinstance(value, bool):
            return json.dumps(value)
        if isinstance(value, float):
            return f"{value:.4g}"
        return str(value)

    return ", ".join(f"{k}={shown(v)}" for k, v in values.items())


def variants_table(variants: list[TunedVariant]) -> pd.DataFrame:
    """One row per tuned variant (as ``tuning.csv`` holds it)."""
    columns = [
        "variant", "base", "objective", "metric", "statistic", "budget", "trials", "batch",
        "seed", "default_value", "tuned_value", "flattening_trials", "settings",
        "wall_time_s", "split", "library", "problems", "suite", "seeds", "tuner", "date",
        "commit",
    ]  # fmt: skip
    rows = [
        {
            "variant": v.name,
            "base": v.base,
            "objective": v.objective.kind,
            "metric": v.objective.metric,
            "statistic": v.objective.statistic,
            "budget": v.objective.budget,
            "trials": v.tuner.trials,
            "batch": v.tuner.batch,
            "seed": v.tuner.seed,
            "default_value": v.default_value,
            "tuned_value": v.best_value,
            "flattening_trials": flattening_trials(v),
            "settings": settings_text(v.values),
            "wall_time_s": v.provenance.wall_time_s,
            "split": v.objective.split,
            "library": v.objective.library,
            "problems": v.objective.problems,
            "suite": v.objective.suite,
            "seeds": " ".join(map(str, v.objective.seeds or ())),
            "tuner": f"{v.tuner.library} {v.tuner.version} {v.tuner.sampler}",
            "date": v.provenance.date,
            "commit": v.provenance.commit or "",
        }
        for v in variants
    ]
    return pd.DataFrame(rows, columns=columns)


def curves_table(variants: list[TunedVariant]) -> pd.DataFrame:
    """Each variant's trials: the value of each, the best found so far and that divided by
    the default value (NaN when it is 0), against the trial count (1 = the base
    configuration alone), and whether the count is the variant's flattening point."""
    frames = []
    for v in variants:
        best = v.best_so_far
        scale = v.default_value if v.default_value != 0 else math.nan
        frames.append(
            pd.DataFrame(
                {
                    "variant": v.name,
                    "objective": v.objective.kind,
                    "trials": np.arange(1, len(best) + 1),
                    "value": v.history,
                    "best_so_far": best,
                    "best_so_far_relative": best / scale,
                    "flattening_point": np.arange(1, len(best) + 1) == flattening_trials(v),
                }
            )
        )
    columns = [
        "variant", "objective", "trials", "value", "best_so_far", "best_so_far_relative",
        "flattening_point",
    ]  # fmt: skip
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=columns)


# --- Markdown -------------------------------------------------------------------------------


def _number(value: float) -> str:
    return f"{value:.4g}"


def _duration(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.1f} s"
    minutes = seconds / 60
    return f"{minutes:.1f} min" if minutes < 120 else f"{minutes / 60:.2f} h"


def flattening_sentence(variants: list[TunedVariant]) -> str:
    """Each variant's flattening point and the largest of them, as a sentence."""
    counts = {v.name: (flattening_trials(v), v.tuner.trials) for v in variants}
    known = {name: c for name, c in counts.items() if c[0] is not None}
    parts = [
        f"{name} {'-' if t is None else t} of {n}" + (" (default value 0)" if t is None else "")
        for name, (t, n) in counts.items()
    ]
    sentence = (
        f"Flattening point (the trial count after which the best value found so far improved "
        f"by less than {FLAT_SHARE * 100:g} % of the variant's default value, to its last trial): "
        + "; ".join(parts)
        + "."
    )
    if known:
        largest = max(t for t, _ in known.values())
        which = ", ".join(name for name, (t, _) in known.items() if t == largest)
        sentence += f" The largest: {largest} trials ({which})."
        still = [name for name, (t, n) in known.items() if t == n and n > 1]
        if still:
            sentence += (
                f" Still improving by {FLAT_SHARE * 100:g} % or more at its last trial: "
                f"{', '.join(still)}."
            )
        short = [name for name, (t, n) in known.items() if n - t < FLAT_TRIALS]
        rule = f"no such gain in the last {FLAT_TRIALS} trials or more"
        if short:
            sentence += f" Not flattened ({rule}): {', '.join(short)}."
        else:
            sentence += f" Every curve has flattened ({rule})."
    return sentence


def _objective_data(variants: list[TunedVariant]) -> list[str]:
    """One line per distinct tuning data set: the split and library, or the suite and seeds."""
    lines = []
    for v in variants:
        o = v.objective
        if o.kind == "solve":
            line = f"per solve: split {o.split or '-'} of library {o.library or '-'}" + (
                f", {o.problems} problems" if o.problems else ""
            )
        else:
            seeds = ", ".join(map(str, o.seeds)) if o.seeds else "-"
            line = f"closed loop: suite {o.suite or '-'}, seeds {seeds}"
        lines.append(line)
    return list(dict.fromkeys(lines))


def to_markdown(variants: list[TunedVariant], figure: str | None = None) -> str:
    """The tuning report as Markdown; ``figure`` is the path of the best-so-far figure
    relative to where the text is written (no figure when None)."""
    table = variants_table(variants)
    total = float(table["wall_time_s"].sum())
    lines = [
        "# Tuned variants",
        "",
        f"{len(variants)} tuned variants. Each tuning ran its trials with the same tuner; trial "
        "0 is the base configuration (its value: the default value), the tuned value is the "
        "objective of the configuration the variant keeps. Objective: the statistic of the "
        "metric at the stated evaluation budget per solve, on data no results page uses ("
        + "; ".join(_objective_data(variants))
        + ").",
        "",
    ]
    lines += _variants_lines(table)
    lines += [
        f"Total tuning wall time: {_duration(total)}"
        + (f" ({total:.0f} s)" if total >= 120 else "")
        + f" over {len(variants)} variants.",
        "",
        "## Best value found against the trial count",
        "",
    ]
    if figure is not None:
        lines += [
            f"![best value found so far / default value, against the trials]({figure})",
            "",
        ]
    lines += [flattening_sentence(variants), ""]
    return "\n".join(lines)


def _variants_lines(table: pd.DataFrame) -> list[str]:
    """The table of the variants (a :func:`variants_table`), split where it does not fit the
    page in one: what each tuning was, then what it found, beside the variant's name."""

    def column(header: str, cell: Callable[[pd.Series], str], text: bool = False) -> Column:
        return Column(header, [cell(r) for _, r in table.iterrows()], text)

    def metric(r: pd.Series) -> str:
        # "median steady_state_cost", but not "median median normalised gap"
        return r["metric"] if r["statistic"] in r["metric"] else f"{r['statistic']} {r['metric']}"

    sections = [
        [
            column("base", lambda r: f"{r['base']}", text=True),
            column("objective", lambda r: f"{r['objective']}", text=True),
            column("metric", metric, text=True),
            column("budget", lambda r: f"{r['budget']}"),
        ],
        [column(name, lambda r, name=name: f"{r[name]}") for name in ("trials", "batch", "seed")],
        [
            column("default value", lambda r: _number(r["default_value"])),
            column("tuned value", lambda r: _number(r["tuned_value"])),
        ],
        [column("tuned settings", lambda r: r["settings"] or "-", text=True)],
        [column("wall time", lambda r: _duration(r["wall_time_s"]))],
    ]
    lead = [column("variant", lambda r: f"{r['variant']}", text=True)]
    return fitted_table(lead, sections)


def write_tuning_report(variants: list[TunedVariant], folder: Path, *, figures: bool = True) -> str:
    """Write ``tuning.md``, ``tuning.csv``, ``tuning_curves.csv`` and, with ``figures``,
    ``figures/`` :data:`FIGURE` into ``folder``; returns the Markdown."""
    folder.mkdir(parents=True, exist_ok=True)
    markdown = to_markdown(variants, f"figures/{FIGURE}" if figures else None)
    (folder / "tuning.md").write_text(markdown)
    variants_table(variants).to_csv(folder / "tuning.csv", index=False)
    curves = curves_table(variants)
    curves.to_csv(folder / "tuning_curves.csv", index=False)
    if figures:
        from formation_bench.analysis.figures import save_report_figure, tuning_figure

        (folder / "figures").mkdir(exist_ok=True)
        save_report_figure(tuning_figure(curves), folder / "figures" / FIGURE)
    return markdown
