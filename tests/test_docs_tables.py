"""The documentation's tables name the command that produced them, and its links resolve.

The convention for tables, in every Markdown page of ``docs/`` (but the build output and the
generated reference) and in ``README.md``: **every table is preceded, within the 3 lines
above it, by one of two HTML comments**:

- ``<!-- produced by: COMMAND -->`` for a table of results or timings, where ``COMMAND`` is
  the command line that prints it: ``formation-bench ...`` (checked against the command
  line's own parser, without running it) or ``python -m perf.NAME ...`` (checked against that
  script's parser: its ``main(argv)`` is called with ``parse_args`` stopped right after
  parsing). Several commands run one after the other are joined with ``&&``. A **timing
  table** (one whose command is a ``python -m perf.`` script, or whose header names a time:
  a cell with "time", "ms", "µs", "(s)", "seconds", "wall" or "speed") also names the machine
  and the date it was measured on:
  ``<!-- produced by: COMMAND; machine: 2-core Xeon 2.2 GHz; date: 2026-11-27 -->``;
- ``<!-- reference table -->`` for any other table (settings, columns, options, a
  comparison with the paper's figures...).

A table with neither fails the test, so a new table of results cannot slip in without the
command that regenerates it.

The commands: every ``formation-bench ...`` command a reader would copy must be one the
command line's parser accepts, required options included (parsed, not run). That is every
command of a ``bash``/``sh``/``shell`` code block, every ``$ `` line of a ``console`` block
(the other lines are its output), and every inline code span that starts with
``formation-bench`` and gives the command arguments, unless it elides some with ``...``.
A command of a shell line is what lies between ``&&``, ``||``, ``;`` and ``|``; ``$(...)``
stands for one argument, and an upper-case word (``NAME``, ``DIR``) for a value to fill in.

The links: a relative link of a page must name an existing file; a link to a Markdown page
with ``#anchor`` must match a heading's slug as MyST computes it (GitHub's slugs, headings of
the levels ``myst_heading_anchors`` in ``docs/conf.py`` gives anchors to); a page of the site
must not link to a file outside ``docs/`` (it is not part of the site: link to the repository
instead). The slow test builds the site with Sphinx, warnings as errors.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import importlib
import io
import itertools
import os
import re
import runpy
import shlex
import shutil
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
LEFT_OUT = (DOCS / "_build", DOCS / "reference" / "_generated")
COMMENT_LINES_ABOVE = 3

PRODUCED = re.compile(r"<!--\s*produced by:\s*(?P<body>.*?)\s*-->", re.DOTALL)
REFERENCE = re.compile(r"<!--\s*reference table\s*-->")
TIME_HEADER = re.compile(r"time|\bms\b|µs|\(s\)|seconds|\bwall\b|speed", re.IGNORECASE)
DATE = re.compile(r"\d{4}-\d{2}-\d{2}")
EXTERNAL = re.compile(r"^[a-z][a-z0-9+.-]*:", re.IGNORECASE)


def markdown_files() -> list[Path]:
    """The pages the conventions apply to."""
    pages = [
        path
        for path in sorted(DOCS.rglob("*.md"))
        if not any(path.is_relative_to(folder) for folder in LEFT_OUT)
    ]
    return [*pages, ROOT / "README.md"]


def _parser() -> Any:
    from markdown_it import MarkdownIt

    return MarkdownIt("commonmark").enable("table")


# --- tables ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Table:
    path: Path
    line: int
    """1-based line of its header row."""
    header: str
    comment: str
    """The lines above it that may hold its comment."""

    @property
    def where(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


def tables(path: Path) -> Iterator[Table]:
    lines = path.read_text(encoding="utf-8").splitlines()
    for token in _parser().parse("\n".join(lines)):
        if token.type == "table_open" and token.map is not None:
            start = token.map[0]
            first = max(0, start - COMMENT_LINES_ABOVE)
            # a comment that ends within those lines counts from its start
            while first > 0 and _opens_after_close("\n".join(lines[first:start])):
                first -= 1
            yield Table(path, start + 1, lines[start], "\n".join(lines[first:start]))


def _opens_after_close(block: str) -> bool:
    """Whether ``block`` closes a comment (``-->``) it does not open."""
    close = block.find("-->")
    return close >= 0 and not 0 <= block.find("<!--") < close


def all_tables() -> list[Table]:
    return [table for path in markdown_files() for table in tables(path)]


@dataclass(frozen=True)
class Produced:
    commands: list[list[str]]
    machine: str | None
    date: str | None


def produced(comment_body: str) -> Produced:
    """The commands, machine and date of a ``produced by:`` comment's text."""
    command, *fields = re.split(r";\s*(?=(?:machine|date)\s*:)", comment_body)
    values = dict(field.split(":", 1) for field in fields)
    commands = [shlex.split(part) for part in command.split("&&")]
    return Produced(
        commands,
        values["machine"].strip() if "machine" in values else None,
        values["date"].strip() if "date" in values else None,
    )


class _Parsed(Exception):
    """Raised in place of returning from ``parse_args``: the script stops there."""


def command_problem(argv: list[str], monkeypatch: pytest.MonkeyPatch) -> str | None:
    """Why ``argv`` is not a command its program's parser accepts; None if it is."""
    while argv and re.fullmatch(r"[A-Z_][A-Z0-9_]*=\S*", argv[0]):  # MPLBACKEND=Agg ...
        argv = argv[1:]
    if argv[:1] == ["formation-bench"]:
        from formation_bench.cli.main import build_parser

        return _parse_problem(lambda: build_parser().parse_args(argv[1:]))
    if len(argv) >= 3 and argv[0] in ("python", "python3") and argv[1] == "-m":
        if not argv[2].startswith("perf."):
            return f"python -m {argv[2]}: not a perf script"
        return _perf_problem(argv[2], argv[3:], monkeypatch)
    return "neither a formation-bench nor a python -m perf.NAME command"


def _parse_problem(parse: Any) -> str | None:
    error = io.StringIO()
    try:
        with contextlib.redirect_stderr(error), contextlib.redirect_stdout(io.StringIO()):
            parse()
    except _Parsed:
        return None
    except SystemExit as exit_:
        if exit_.code in (0, None):  # --help, --version
            return None
        return error.getvalue().strip() or f"exit {exit_.code}"
    return None


def _perf_problem(name: str, argv: list[str], monkeypatch: pytest.MonkeyPatch) -> str | None:
    try:
        module = importlib.import_module(name)
    except ModuleNotFoundError:
        return f"no module {name}"
    main = getattr(module, "main", None)
    if main is None:  # no command line of its own: its options must at least appear in it
        source = Path(module.__file__ or "").read_text(encoding="utf-8")
        unknown = [a for a in argv if a.startswith("-") and a.split("=")[0] not in source]
        return f"{name} has no option {', '.join(unknown)}" if unknown else None
    parse_args = argparse.ArgumentParser.parse_args

    def parse_then_stop(self: argparse.ArgumentParser, *args: Any, **kwargs: Any) -> Any:
        parse_args(self, *args, **kwargs)
        raise _Parsed

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_then_stop)
    try:
        problem = _parse_problem(lambda: main(argv))
    finally:
        monkeypatch.undo()
    return problem


def _is_timing(table: Table, found: Produced) -> bool:
    by_perf = any(len(argv) >= 3 and argv[2].startswith("perf.") for argv in found.commands)
    return by_perf or bool(TIME_HEADER.search(table.header))


def test_every_table_says_what_it_is() -> None:
    unmarked = [
        table.where
        for table in all_tables()
        if not PRODUCED.search(table.comment) and not REFERENCE.search(table.comment)
    ]
    assert not unmarked, (
        "tables without '<!-- produced by: COMMAND -->' (results, timings) or "
        f"'<!-- reference table -->' (anything else) in the {COMMENT_LINES_ABOVE} lines "
        "above them: " + ", ".join(unmarked)
    )


def test_produced_tables_name_a_command_that_parses(monkeypatch: pytest.MonkeyPatch) -> None:
    problems = []
    for table in all_tables():
        match = PRODUCED.search(table.comment)
        if match is None:
            continue
        found = produced(match.group("body"))
        for argv in found.commands:
            problem = command_problem(argv, monkeypatch) if argv else "empty command"
            if problem is not None:
                problems.append(f"{table.where}: {shlex.join(argv)}: {problem}")
        if _is_timing(table, found):
            if not found.machine:
                problems.append(f"{table.where}: a timing table names no 'machine: ...'")
            if found.date is None or not DATE.fullmatch(found.date):
                problems.append(f"{table.where}: a timing table needs 'date: YYYY-MM-DD'")
            else:
                try:
                    datetime.date.fromisoformat(found.date)
                except ValueError:
                    problems.append(f"{table.where}: no such date {found.date}")
    assert not problems, "\n".join(problems)


def test_the_checks_catch_a_bad_command(monkeypatch: pytest.MonkeyPatch) -> None:
    assert command_problem(["formation-bench", "list"], monkeypatch) is None
    assert command_problem(["formation-bench", "lists"], monkeypatch) is not None
    assert command_problem(["formation-bench", "run", "--optimiser", "x"], monkeypatch)
    assert command_problem(["python", "-m", "perf.no_such_script"], monkeypatch)
    assert command_problem(["python", "-m", "perf.speed", "--quick"], monkeypatch) is None
    assert command_problem(["python", "-m", "perf.speed", "--quik"], monkeypatch)
    found = produced("python -m perf.speed --quick; machine: a laptop; date: 2026-11-27")
    assert (found.commands, found.machine, found.date) == (
        [["python", "-m", "perf.speed", "--quick"]], "a laptop", "2026-11-27",
    )  # fmt: skip


# --- commands ----------------------------------------------------------------------------------

SHELL_BLOCKS = ("bash", "sh", "shell")
CONSOLE_BLOCKS = ("console",)
PROMPT = "$ "
SUBSTITUTION = re.compile(r"\$\([^)]*\)")
PLACEHOLDER = re.compile(r"^[A-Z][A-Z0-9_]*$")
OPERATORS = frozenset({"&&", "||", ";", "|", "&"})
REDIRECTIONS = frozenset({">", ">>", "<", "2>", "&>"})


@dataclass(frozen=True)
class Command:
    path: Path
    line: int
    argv: list[str]
    inline: bool
    """From an inline code span (a placeholder stands for a value) rather than a block."""

    @property
    def where(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


def shell_lines(block: str, console: bool) -> Iterator[tuple[int, str]]:
    """``(offset, line)`` of each command line of a code block: a backslash at a line's end
    continues it; in a console block only the lines after a ``$ `` prompt."""
    pending: list[str] = []
    start = 0
    for offset, raw in enumerate(block.splitlines()):
        line = raw.strip()
        if not pending:
            start = offset
            if console:
                if not line.startswith(PROMPT):
                    continue
                line = line[len(PROMPT) :]
        if line.endswith("\\"):
            pending.append(line[:-1])
            continue
        yield start, " ".join([*pending, line])
        pending = []
    if pending:
        yield start, " ".join(pending)


def simple_commands(line: str) -> Iterator[list[str]]:
    """The words of each command of a shell line, without comments and redirections."""
    lexer = shlex.shlex(SUBSTITUTION.sub("0", line), posix=True, punctuation_chars=True)
    lexer.whitespace_split = True
    words: list[str] = []
    skip_next = False
    for token in lexer:
        if skip_next:
            skip_next = False
        elif token in OPERATORS:
            if words:
                yield words
            words = []
        elif token in REDIRECTIONS:
            skip_next = True
        else:
            words.append(token)
    if words:
        yield words


def commands(path: Path) -> Iterator[Command]:
    """Every ``formation-bench`` command of the page ``path`` a reader would copy."""
    for token in _parser().parse(path.read_text(encoding="utf-8")):
        if token.map is None:
            continue
        if token.type == "fence" and token.info.strip() in SHELL_BLOCKS + CONSOLE_BLOCKS:
            console = token.info.strip() in CONSOLE_BLOCKS
            for offset, line in shell_lines(token.content, console):
                for argv in simple_commands(line):
                    yield Command(path, token.map[0] + 2 + offset, argv, inline=False)
        for child in token.children or []:
            if child.type != "code_inline" or not child.content.startswith("formation-bench "):
                continue
            if "..." in child.content:
                continue
            for argv in simple_commands(child.content):
                if len(argv) > 2:  # `formation-bench run` names the command: nothing to copy
                    yield Command(path, token.map[0] + 1, argv, inline=True)


def command_line_problems(command: Command) -> str | None:
    from formation_bench.cli.main import build_parser

    argv = command.argv
    while argv and re.fullmatch(r"[A-Z_][A-Z0-9_]*=\S*", argv[0]):  # MPLBACKEND=Agg ...
        argv = argv[1:]
    if argv[:1] != ["formation-bench"]:
        return None
    if command.inline:
        argv = ["0" if PLACEHOLDER.match(word) else word for word in argv]
    return _parse_problem(lambda: build_parser().parse_args(argv[1:]))


def all_commands() -> list[Command]:
    return [command for path in markdown_files() for command in commands(path)]


def test_every_command_in_the_docs_parses() -> None:
    found = all_commands()
    assert sum(c.argv[0] == "formation-bench" for c in found) > 100  # the extraction works
    problems = [
        f"{command.where}: {shlex.join(command.argv)}: {problem.splitlines()[-1]}"
        for command in found
        if (problem := command_line_problems(command)) is not None
    ]
    assert not problems, "commands a reader would copy that do not parse:\n" + "\n".join(problems)


def test_the_command_check_reads_blocks_as_a_shell_does(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text(
        "Run `formation-bench sweep comparison --jobs 2` or `formation-bench run`.\n\n"
        "```console\n$ formation-bench list --fields paper | head -5\nname  paper\n"
        "$ formation-bench run --optimizer pso \\\n    --out out/x  # a comment\n```\n\n"
        "```bash\npip install . && formation-bench reproduce --seeds $(seq 0 3) > log\n```\n\n"
        "```text\nformation-bench sweep SUITE --out DIR [--jobs N]\n```\n"
    )
    found = [(c.line, c.argv, c.inline) for c in commands(page)]
    assert found == [
        (1, ["formation-bench", "sweep", "comparison", "--jobs", "2"], True),
        (4, ["formation-bench", "list", "--fields", "paper"], False),
        (4, ["head", "-5"], False),
        (6, ["formation-bench", "run", "--optimizer", "pso", "--out", "out/x"], False),
        (11, ["pip", "install", "."], False),
        (11, ["formation-bench", "reproduce", "--seeds", "0"], False),
    ]
    problems = [command_line_problems(c) for c in commands(page)]
    assert "required: --out" in (problems[0] or "")
    assert problems[1:] == [None] * 5
    console = Command(page, 1, ["formation-bench", "run", "--optimizer", "NAME"], inline=False)
    assert "required: --out" in (command_line_problems(console) or "")
    inline = Command(page, 1, ["formation-bench", "run", "--optimizer", "X", "--out", "D"], True)
    assert command_line_problems(inline) is None


# --- links -------------------------------------------------------------------------------------


def heading_anchors() -> int:
    return runpy.run_path(str(DOCS / "conf.py"))["myst_heading_anchors"]


def anchors(path: Path, depth: int) -> set[str]:
    """The ``#anchors`` MyST gives the headings of the page ``path``."""
    slugs_module = pytest.importorskip("myst_parser.slugs")
    found: set[str] = set()
    tokens = _parser().parse(path.read_text(encoding="utf-8"))
    for heading, inline in itertools.pairwise(tokens):
        if heading.type != "heading_open" or int(heading.tag[1:]) > depth:
            continue
        title = "".join(
            child.content
            for child in inline.children or []
            if child.type in ("text", "code_inline")
        )
        slug = slugs_module.github_slugify(title)
        if slug:
            found.add(slugs_module.unique_slug(slug, found))
    return found


def links(path: Path) -> Iterator[str]:
    """Every link and image target of the page ``path`` (not those inside code)."""
    for token in _parser().parse(path.read_text(encoding="utf-8")):
        for child in token.children or []:
            if child.type == "link_open":
                yield str(child.attrs.get("href", ""))
            elif child.type == "image":
                yield str(child.attrs.get("src", ""))


def link_problems(path: Path, depth: int) -> Iterator[str]:
    from urllib.parse import unquote

    in_site = path.is_relative_to(DOCS)
    for target in links(path):
        if not target or EXTERNAL.match(target):
            continue
        file_part, _, anchor = unquote(target).partition("#")
        linked = (path.parent / file_part).resolve() if file_part else path
        where = f"{path.relative_to(ROOT)}: {target}"
        if not linked.exists():
            yield f"{where}: no such file"
            continue
        if in_site and not linked.is_relative_to(DOCS):
            yield f"{where}: outside docs/, not part of the site (link to the repository)"
            continue
        if anchor and linked.suffix == ".md" and anchor not in anchors(linked, depth):
            yield f"{where}: no heading with the anchor #{anchor}"


def test_links_and_anchors_resolve() -> None:
    depth = heading_anchors()
    problems = [problem for path in markdown_files() for problem in link_problems(path, depth)]
    assert not problems, "\n".join(problems)


def test_the_link_check_catches_a_broken_anchor(tmp_path: Path) -> None:
    pytest.importorskip("myst_parser")
    page = tmp_path / "page.md"
    page.write_text("# A page\n\n## Its `first` section\n\n## Its first section\n")
    assert anchors(page, 3) == {"a-page", "its-first-section", "its-first-section-1"}
    assert anchors(page, 1) == {"a-page"}


def test_a_comment_over_several_lines_counts(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text(
        "Text.\n\n<!-- produced by: formation-bench list\n  && formation-bench list\n"
        "  && formation-bench list -->\n\n| a | b |\n|---|---|\n| 1 | 2 |\n"
    )
    (table,) = tables(page)
    match = PRODUCED.search(table.comment)
    assert match is not None
    assert len(produced(match.group("body")).commands) == 3


# --- the site ----------------------------------------------------------------------------------


def sphinx_build(source: Path, out: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
         "-d", str(out / "doctrees"), str(source), str(out / "html")],
        capture_output=True, text=True, env={**os.environ, "MPLBACKEND": "Agg"},
    )  # fmt: skip


TYPOGRAPHIC = re.compile("[\u2013\u2014\u2018\u2019\u201c\u201d]")
"""En and em dashes, curly quotes: what smart quotes make of ``--`` and ``'``."""


def article_text(page: Path) -> str:
    """The text of a built page's article (without the theme's navigation), tags stripped."""
    import html

    body = page.read_text(encoding="utf-8")
    body = body[body.index("<article") : body.index("</article>")]
    return html.unescape(re.sub(r"<[^>]+>", "", body))


@pytest.mark.slow
def test_the_site_builds_without_warnings(built_site: Path) -> None:
    from formation_bench.cli.main import build_parser

    site = built_site
    # the command line's page copies as written: --out, 'list' and "x" stay as typed
    cli = article_text(site / "reference" / "cli.html")
    assert TYPOGRAPHIC.findall(cli) == []
    assert "--no-figures writes metrics" in cli and "(see 'list')" in cli
    parsers, flags = [build_parser()], set()
    while parsers:
        parser = parsers.pop()
        for action in parser._actions:
            flags.update(action.option_strings)
            if isinstance(action, argparse._SubParsersAction):
                parsers += action.choices.values()
    assert len(flags) > 30 and all(flag in cli for flag in flags)
    # the adapters' libraries are installed with the docs: their settings are documented
    optimizers = article_text(site / "reference" / "_generated" / "optimizers.html")
    assert "Not available where this page was built" not in optimizers
    assert "NevergradOptimizer" in optimizers


@pytest.mark.slow
def test_the_build_fails_on_a_broken_link(tmp_path: Path) -> None:
    """A site of this configuration whose home page links to a missing page, a missing
    anchor and a file outside the site, and whose command-line page is stale."""
    pytest.importorskip("sphinx")
    source = tmp_path / "site"
    shutil.copytree(DOCS / "_ext", source / "_ext")
    shutil.copy(DOCS / "conf.py", source)
    (source / "reference").mkdir()
    for page in ("index.md", "api.md", "cli.md"):
        shutil.copy(DOCS / "reference" / page, source / "reference")
    stale_cli = source / "reference" / "cli.md"  # an option the parser no longer has
    stale_cli.write_text(stale_cli.read_text().replace("`--out OUT`", "`--output OUT`"))
    (source / "page.md").write_text("# Page\n\n## Its section\n")
    (source / "index.md").write_text(
        "# Home\n\n[fine](page.md#its-section) [gone](no-page.md) [nowhere](page.md#nowhere)"
        " [outside](../outside.md)\n\n```{toctree}\npage\nreference/index\n```\n"
    )
    (tmp_path / "outside.md").write_text("# Outside\n")
    result = sphinx_build(source, tmp_path / "out")
    assert result.returncode != 0
    assert "no-page.md" in result.stderr
    assert "'nowhere'" in result.stderr
    assert "outside" in result.stderr
    assert "its-section" not in result.stderr
    assert "reference/cli.md differs from the command line's parser" in result.stderr
