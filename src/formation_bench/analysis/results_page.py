"""A dated results page (Markdown) for a results folder: what ``formation-bench report DIR
--page FILE`` writes, for the documentation's ``results/`` pages.

The page opens with its title and one paragraph naming the command that made the results
(the sweep, read from the folder's manifest; the score runs, rebuilt from their rows), the
report command that writes the page, the date of the runs, the formation-bench version and
the machine (CPU model). Then come the report's tables: for a suite folder the headline
metrics of every block (:func:`~formation_bench.analysis.report.to_markdown`) and the
sections the report wrote (swarm, robustness, obstacles, paper budget, variant pairs); for a
score folder the leaderboard as ``score.md`` ranks it; for a folder of tuned-variant files the
tuning report (:mod:`~formation_bench.analysis.tuning_report`), its figure copied beside the
page (:func:`tuning_image`). Every table is preceded by
``<!-- produced by: COMMAND -->``, a table with times also by the machine and the date
(the documentation's convention for tables that must not go stale silently).
"""

from __future__ import annotations

import datetime as dt
import json
import os
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pandas as pd

from formation_bench.pipeline.outputs import write_text
from formation_bench.pipeline.provenance import uncommitted

if TYPE_CHECKING:
    from formation_bench.analysis.comparison import Report
    from formation_bench.analysis.tuning_report import TunedVariant

SECTION_FILES = ("paper_budget.md", "swarm.md", "robustness.md", "obstacles.md", "variant_pairs.md")
"""Report files whose tables a suite's page carries after the headline, in this order."""


@dataclass(frozen=True)
class Provenance:
    """Where a folder's results come from, as the page's first paragraph says it."""

    kind: str
    """``suite``, ``score`` or ``tuning``."""
    name: str
    commands: tuple[str, ...]
    """The commands that made the results (one per score optimiser)."""
    dates: tuple[str, ...]
    """``YYYY-MM-DD`` of the runs, first and last (one when they agree)."""
    version: str
    machine: str

    @property
    def date(self) -> str:
        """The runs' last date (the date a timing table carries)."""
        return self.dates[-1] if self.dates else "unknown"


def _day(stamp: object) -> str | None:
    try:
        return dt.datetime.fromisoformat(str(stamp)).date().isoformat()
    except ValueError:
        return None


def _span(days: list[str | None]) -> tuple[str, ...]:
    known = sorted({d for d in days if d})
    return tuple(dict.fromkeys([known[0], known[-1]])) if known else ()


def _shown_command(command: str, folder: Path | None = None) -> str:
    """A recorded command line with the program named ``formation-bench``, not by its path,
    and an absolute ``--out`` that is ``folder`` (the results the page is made from) by another
    path named as the page's own command names it: a reader runs both from one place, and the
    machine's paths mean nothing elsewhere."""
    words = shlex.split(command)
    if words and Path(words[0]).name == "formation-bench":
        words[0] = "formation-bench"
    if folder is not None:
        for k in range(1, len(words)):
            if words[k - 1] == "--out" and _same_folder(words[k], folder):
                words[k] = str(folder)
    return shlex.join(words)


def _same_folder(recorded: str, folder: Path) -> bool:
    """Whether the absolute path ``recorded`` is the folder ``folder`` (links resolved)."""
    try:
        return os.path.isabs(recorded) and os.path.samefile(recorded, folder)
    except OSError:  # gone, or never on this machine
        return False


def suite_provenance(results_dir: Path, results: pd.DataFrame) -> Provenance:
    """A suite folder's provenance: its manifest's sessions (commands, dates, machine,
    versions), else what its run records hold.

    The manifest is read verified (:func:`~formation_bench.experiments.manifest.read_manifest`):
    a damaged one raises its one-line :class:`~formation_bench.experiments.errors.ManifestError`
    rather than lending the page invented provenance."""
    from formation_bench.experiments.manifest import read_manifest
    from formation_bench.experiments.store import ResultStore

    manifest = read_manifest(ResultStore(results_dir)) or {}
    sessions = manifest.get("sessions") or []
    return Provenance(
        "suite",
        _suite_name(manifest, results),
        tuple(
            dict.fromkeys(
                _shown_command(s["command"], results_dir) for s in sessions if "command" in s
            )
        ),
        _span(_run_days(sessions, results)),
        _suite_version(manifest, results),
        _suite_machine(manifest, results),
    )


def _suite_name(manifest: dict[str, Any], results: pd.DataFrame) -> str:
    """The suite the manifest names, else the suites the run rows name."""
    return (manifest.get("suite") or {}).get("name") or ", ".join(
        sorted(results["suite"].astype(str).unique()) if "suite" in results else []
    )


def _run_days(sessions: list[dict[str, Any]], results: pd.DataFrame) -> list[str | None]:
    """The days the sweep sessions started and finished; the days the runs finished when no
    session recorded a date (or there is no manifest)."""
    days = [_day(s.get(k)) for s in sessions for k in ("started", "finished")]
    if not any(days) and "finished_at" in results:
        days = [_day(v) for v in results["finished_at"].dropna()]
    return days


def _suite_version(manifest: dict[str, Any], results: pd.DataFrame) -> str:
    """The formation-bench version the manifest records, else the run rows', with the commits
    the rows record (:func:`commit_text`)."""
    version = (manifest.get("versions") or {}).get("formation-bench")
    if version is None and "version" in results:
        version = _distinct(results, "version")
    if version is None:
        return "not recorded"
    return f"{version}{commit_text(results)}" or "not recorded"


def _suite_machine(manifest: dict[str, Any], results: pd.DataFrame) -> str:
    """The CPU model the manifest records, else the run rows', and the manifest's CPU count."""
    recorded = manifest.get("machine") or {}
    cpu = recorded.get("cpu_model")
    if cpu is None and "cpu_model" in results:
        cpu = ", ".join(sorted(results["cpu_model"].dropna().astype(str).unique()))
    machine = str(cpu or "not recorded")
    if recorded.get("cpu_count"):
        machine += f", {recorded['cpu_count']} CPUs"
    return machine


def _recorded_command(command: str) -> str:
    """:func:`_shown_command`, or the command as recorded when shlex cannot split it."""
    try:
        return _shown_command(command)
    except ValueError:
        return command


def score_commands(scores: pd.DataFrame, results_dir: Path) -> tuple[str, ...]:
    """The ``formation-bench score`` command of every optimiser in ``scores`` (its overrides,
    budgets, seeds, library, split and deadline as its rows record them)."""
    commands = []
    for optimizer, rows in scores.groupby("optimizer_name", sort=True):
        words = ["formation-bench", "score", "--optimizer", str(optimizer)]
        overrides = json.loads(str(rows["optimizer_overrides"].iloc[0]) or "{}")
        for field, value in overrides.items():
            words += [
                "--set",
                f"{field}={json.dumps(value) if not isinstance(value, str) else value}",
            ]
        budgets = [
            "default" if pd.isna(b) else str(int(b))
            for b in dict.fromkeys(rows["budget_max_evaluations"])
        ]
        words += ["--budgets", *budgets, "--seeds", *map(str, sorted(rows["seed"].unique()))]
        deadline = rows["deadline_ms"].dropna()
        if len(deadline):
            words += ["--deadline-ms", f"{float(deadline.iloc[0]):g}"]
        words += [
            "--library",
            str(rows["library"].iloc[0]),
            "--split",
            str(rows["run_split"].iloc[0]),
        ]
        words += ["--out", str(results_dir)]
        commands.append(shlex.join(words))
    return tuple(dict.fromkeys(commands))


def _distinct(rows: pd.DataFrame, column: str, width: int | None = None) -> str:
    """The distinct values of ``column`` in ``rows``, joined ("" when it has none)."""
    if column not in rows:
        return ""
    values = rows[column].dropna().astype(str).str[:width].unique()
    return ", ".join(sorted(values))


COMMIT_WIDTH = 10
"""Hex digits of a commit a page prints."""


def commit_text(rows: pd.DataFrame) -> str:
    """`` (commit abc)`` for rows made at one commit; for rows of several, a sentence saying
    the folder mixes them, with each commit's rows counted and the ones made from a tree
    with uncommitted changes named so ("" when no row recorded its commit)."""
    if "commit" not in rows or rows["commit"].dropna().empty:
        return ""
    made = rows.dropna(subset=["commit"])
    commits = made["commit"].astype(str).str[:COMMIT_WIDTH]
    if commits.nunique() == 1:
        return f" (commit {commits.iloc[0]})"
    versions = made["version"].astype(str) if "version" in made else None
    parts = []
    for commit, count in commits.value_counts().sort_index().items():
        changed = versions is not None and any(map(uncommitted, versions[commits == commit]))
        parts.append(f"{commit}{' with uncommitted changes' if changed else ''} ({count} runs)")
    return (
        f"; the runs were made at {len(parts)} different commits, so this folder mixes code "
        f"versions: {', '.join(parts)}"
    )


def score_provenance(results_dir: Path, scores: pd.DataFrame) -> Provenance:
    """A score folder's provenance: its commands rebuilt from the rows, and the dates,
    version, commit and machine its rows record (the files' dates, for rows stored before
    score runs recorded them)."""
    library = ", ".join(sorted(scores["library"].astype(str).unique()))
    if "finished_at" in scores and scores["finished_at"].notna().all():
        days = [_day(v) for v in scores["finished_at"].unique()]
    else:
        files = list((results_dir / "score").glob("*.parquet"))
        days = [dt.date.fromtimestamp(f.stat().st_mtime).isoformat() for f in files]
    version = _distinct(scores, "version") or "not recorded by these score runs"
    version += commit_text(scores)
    return Provenance(
        "score",
        f"leaderboard on library {library}",
        score_commands(scores, results_dir),
        _span(days),
        version,
        _distinct(scores, "cpu_model") or "not recorded by these score runs",
    )


def tuning_provenance(variants: list[TunedVariant]) -> Provenance:
    """A tuning folder's provenance: the tune commands, dates, versions, commits and machines
    its files record."""
    made = [v.provenance for v in variants]
    commits = sorted({p.commit[:COMMIT_WIDTH] for p in made if p.commit})
    version = ", ".join(sorted({p.version for p in made}))
    version += f" (commit {', '.join(commits)})" if commits else ""
    return Provenance(
        "tuning",
        "tuning",
        tuple(dict.fromkeys(_recorded_command(p.command) for p in made if p.command)),
        _span([_day(p.date) for p in made]),
        version,
        ", ".join(sorted({p.machine for p in made})),
    )


def tuning_image(page: Path) -> Path:
    """Where a tuning page's figure goes: the ``images`` folder beside the page's folder, as
    the documentation keeps its figures (``docs/results/tuning.md`` ->
    ``docs/images/tuning_best_so_far.png``)."""
    return page.parent.parent / "images" / f"{page.stem}_best_so_far.png"


def mark_tables(markdown: str, command: str, provenance: Provenance) -> str:
    """``markdown`` with ``<!-- produced by: COMMAND; machine: ...; date: ... -->`` on the line
    above every table, and its headings one level lower (the page's title is the only level-1
    heading). Every table names the runs' machine and date: most carry times, and the others
    come from the same runs."""
    lines = markdown.splitlines()
    out: list[str] = []
    for k, line in enumerate(lines):
        starts_table = line.startswith("|") and (k == 0 or not lines[k - 1].startswith("|"))
        if starts_table:
            comment = (
                f"<!-- produced by: {command}; machine: {provenance.machine}; "
                f"date: {provenance.date}"
            )
            out += [comment + " -->", ""] if out and out[-1] == "" else ["", comment + " -->", ""]
        out.append("#" + line if line.startswith("#") and not line.startswith("#!") else line)
    return "\n".join(out).rstrip() + "\n"


def report_command(results_dir: Path | str, page: Path | str, options: list[str] = ()) -> str:
    """``formation-bench report DIR [options] --page FILE --overwrite``: the command that
    writes the page anew, as a reader copies it (a page that exists is rewritten only with
    ``--overwrite``)."""
    return shlex.join(
        ["formation-bench", "report", str(results_dir), *options, "--page", str(page),
         "--overwrite"]
    )  # fmt: skip


WRITTEN_BY = "this page is written by `"
"""What the first paragraph of every page this module writes says before the command that
writes it (:func:`report_command`): how a page it wrote is told from a file of the user's,
which ``--page`` never overwrites."""
PAGE_HEAD = 4096
"""Bytes of an existing file read to tell whether it is such a page (the paragraph is near
its top)."""


def check_page(
    page: Path,
    results_dir: Path,
    report_folder: Path,
    *,
    overwrite: bool,
    image: Path | None = None,
) -> None:
    """Refuse a ``--page`` that cannot or must not be written, before anything is: not a
    Markdown file, inside the results folder's store or the report folder (which
    ``--overwrite`` replaces as a whole), in a folder that is not writable (read-only or
    immutable), or an existing file that is not a page this command wrote, or is one and
    ``--overwrite`` is not given; and the page's figure ``image``, when it has one, in a
    folder that is not writable, or existing without ``--overwrite``."""
    from formation_bench.pipeline.staging import OutputError

    problem = _page_place_problem(page, results_dir, report_folder)
    if problem is None and image is not None:
        figure_problem = _figure_problem(image, overwrite=overwrite)
        if figure_problem is not None:
            problem = f"its figure {image}: {figure_problem}"
    if problem is None and os.path.lexists(page):
        problem = _existing_page_problem(Path(os.path.realpath(page)), overwrite=overwrite)
    if problem is not None:
        raise OutputError(f"--page {page}: {problem}")


def _page_place_problem(page: Path, results_dir: Path, report_folder: Path) -> str | None:
    """Why ``page`` cannot be written where it is (None when it can): not a Markdown file,
    inside a folder that the store or ``--overwrite`` of the report folder may replace, or in
    a folder that is not writable."""
    from formation_bench.experiments.store import RUNS, SCORE, TRACES
    from formation_bench.pipeline.staging import unwritable_parent

    if page.suffix != ".md" or page.is_dir():
        return "give a Markdown file (.md), not a folder"
    where = Path(os.path.realpath(page))
    owned = [Path(os.path.realpath(results_dir / name)) for name in (RUNS, TRACES, SCORE)]
    for folder in (*owned, Path(os.path.realpath(report_folder))):
        if where.is_relative_to(folder):
            return (
                f"is inside {folder}, which belongs to the results folder's store or to the "
                "report folder (replaced as a whole by --overwrite); give a file outside them"
            )
    return unwritable_parent(where)


def _figure_problem(image: Path, *, overwrite: bool) -> str | None:
    """Why the page's figure ``image`` cannot be written (None when it can)."""
    from formation_bench.pipeline.staging import unwritable_parent

    problem = unwritable_parent(Path(os.path.realpath(image)))
    if problem is not None or not os.path.lexists(image):
        return problem
    if not overwrite:
        return "exists; add --overwrite to write it anew"
    if not Path(image).is_file():
        return "exists and is not a regular file"
    return None


def _existing_page_problem(where: Path, *, overwrite: bool) -> str | None:
    """Why the existing file ``where`` (the page, links resolved) must not be overwritten
    (None when it may): only a page this command wrote is, and only with ``--overwrite``."""
    if not where.is_file():
        return "exists and is not a regular file"
    if not os.access(where, os.W_OK):
        return "exists and is not writable (read-only or immutable)"
    try:
        ours = is_results_page(where)
    except OSError as err:
        return f"exists and cannot be read ({err.strerror})"
    if not ours:
        return (
            "exists and is not a results page written by 'formation-bench report' (its first "
            "paragraph does not say so), so it is not overwritten; give another file"
        )
    if not overwrite:
        return (
            "exists; add --overwrite to write it anew (the findings between its markers are kept)"
        )
    return None


def is_results_page(path: Path) -> bool:
    """Whether the file ``path`` is a page :func:`write_results_page` wrote."""
    with open(path, "rb") as handle:
        head = handle.read(PAGE_HEAD).decode("utf-8", errors="replace")
    return head.startswith("# Results: ") and f"{WRITTEN_BY}formation-bench report " in head


FINDINGS_START = "<!-- findings: kept when the page is regenerated -->"
"""Opens the hand-written part of a page, which a regeneration keeps (up to
:data:`FINDINGS_END`) and puts back under the page's first paragraph."""
FINDINGS_END = "<!-- end of findings -->"
"""Closes the hand-written part of a page."""


def kept_findings(page: Path) -> str:
    """The hand-written findings of an existing ``page``, markers included ("" if none)."""
    if not page.is_file():
        return ""
    text = page.read_text()
    start = text.find(FINDINGS_START)
    end = text.find(FINDINGS_END, start)
    if start < 0 or end < 0:
        return ""
    return text[start : end + len(FINDINGS_END)]


def page_text(
    provenance: Provenance,
    body: str,
    command: str,
    *,
    today: dt.date | None = None,
    findings: str = "",
) -> str:
    """The page: title, the paragraph naming the commands, date, version and machine, the
    hand-written ``findings`` (if any), then ``body`` with its tables marked
    (:func:`mark_tables`)."""
    today = today or dt.date.today()
    dates = " to ".join(provenance.dates) or "not recorded"
    several = len(provenance.commands) > 1
    made_by = (
        "the commands listed at the end of this page"
        if several
        else "".join(f"`{c}`" for c in provenance.commands) or "a command not recorded"
    )
    kind, title, made = {
        "score": ("Score runs", provenance.name, "Runs"),
        "tuning": ("Tuned variants", provenance.name, "Tunings"),
    }.get(provenance.kind, (f"Suite `{provenance.name}`", f"suite {provenance.name}", "Runs"))
    intro = (
        f"{kind}, made by {made_by}; {WRITTEN_BY}{command}` (on "
        f"{today.isoformat()}). {made} dated {dates}; formation-bench {provenance.version}; "
        f"machine: {provenance.machine}."
    )
    # many commands (one per optimiser scored) would push the findings below the fold
    commands = (
        "\n\n## How this page was made\n\n```text\n" + "\n".join(provenance.commands) + "\n```\n"
        if several
        else ""
    )
    kept = f"{findings}\n\n" if findings else ""
    page = f"# Results: {title} ({provenance.date})\n\n{intro}\n\n{kept}"
    tables = mark_tables(body, command, provenance)
    return page + (tables.rstrip("\n") + commands if several else tables)


def write_results_page(
    results_dir: Path | str,
    page: Path | str,
    report_folder: Path | str,
    *,
    report: Report | None = None,
    baseline: list[str] | None = None,
    compare: str | None = None,
    today: dt.date | None = None,
    tuned: list[TunedVariant] | None = None,
) -> Path:
    """Write the results page of ``results_dir`` to ``page`` from the report that
    ``formation-bench report`` has written into ``report_folder``: its sections, and the
    headline tables of ``report`` (the analysis the command made; analysed afresh when not
    given, with ``baseline`` and ``compare``, which the page's command names too); for a
    folder of ``tuned`` variants (no runs, no score runs), the tuning report, its figure
    copied to :func:`tuning_image` when the report folder has it. The findings
    written by hand into an existing page, between :data:`FINDINGS_START` and
    :data:`FINDINGS_END`, are kept."""
    results_dir, page, folder = Path(results_dir), Path(page), Path(report_folder)
    options = [*(["--baseline", *baseline] if baseline else []),
               *(["--compare", compare] if compare else [])]  # fmt: skip
    command = report_command(results_dir, page, options)
    parts = []
    provenances = []
    if (results_dir / "runs").is_dir():
        from formation_bench.analysis.comparison import analyse
        from formation_bench.analysis.report import to_markdown
        from formation_bench.experiments.store import load_results
        from formation_bench.mpc.metrics import headline_metrics

        results = load_results(results_dir)
        headline = list(headline_metrics())
        if report is None:
            report = analyse(results, baseline=baseline, compare=compare, metrics=headline)
        parts.append(to_markdown(report, results, metrics=headline, title="Headline metrics"))
        parts.append("Every metric of every block: `report.md` of the report folder.\n")
        parts += [(folder / f).read_text() for f in SECTION_FILES if (folder / f).is_file()]
        provenances.append(suite_provenance(results_dir, results))
    if (results_dir / "score").is_dir():
        from formation_bench.experiments.score import load_scores

        parts.append((folder / "score.md").read_text())
        provenances.append(score_provenance(results_dir, load_scores(results_dir)))
    if not provenances and tuned is not None:
        parts.append(_tuning_part(tuned, page, folder))
        provenances.append(tuning_provenance(tuned))
    if not provenances:
        raise FileNotFoundError(f"{results_dir} holds no runs/ or score/ folder")
    provenance = provenances[0] if len(provenances) == 1 else _merged(provenances)
    text = page_text(
        provenance, "\n".join(parts), command, today=today, findings=kept_findings(page)
    )
    write_text(page, text)  # written beside it and renamed over it: never left half-written
    return page


def _merged(provenances: list[Provenance]) -> Provenance:
    suite = provenances[0]
    return Provenance(
        suite.kind,
        " and ".join(p.name for p in provenances),
        tuple(c for p in provenances for c in p.commands),
        _span([d for p in provenances for d in p.dates]),
        suite.version,
        suite.machine,
    )


def _tuning_part(tuned: list[TunedVariant], page: Path, folder: Path) -> str:
    """The tuning report for the page, its figure (if the report drew one) copied beside the
    page (:func:`tuning_image`) and linked relative to it."""
    from formation_bench.analysis.tuning_report import FIGURE, to_markdown
    from formation_bench.pipeline.outputs import atomic_write_bytes

    drawn = folder / "figures" / FIGURE
    if not drawn.is_file():
        return to_markdown(tuned)
    image = tuning_image(page)
    atomic_write_bytes(image, drawn.read_bytes())
    return to_markdown(tuned, Path(os.path.relpath(image, page.parent)).as_posix())
