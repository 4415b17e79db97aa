"""Checks of the built documentation site in a real browser (headless Chromium).

Run ``python -m perf.site_check`` (it builds ``docs/`` into a temporary folder first, as CI
does: warnings as errors) or ``python -m perf.site_check --site DIR`` on a site already built.
Every page of the site is opened in Chromium at a window width of 1280 px, and checked:

- **wide tables and code blocks**: a ``<table>`` or a code block (``<pre>``) wider than the
  box it is shown in, so that a reader must scroll it sideways. The box is the content column
  (furo's ``<article role="main">``, its padding excluded), or a narrower scrolling box inside
  it: furo's ``.table-wrapper`` around a table, the ``<pre>`` itself for code. One pixel of
  rounding is allowed;
- **images**: every ``<img>`` of the page has loaded (``complete`` and a ``naturalWidth``);
- **internal links**: every relative ``<a href>`` names a file of the site and, with
  ``#anchor``, an ``id`` (or ``name``) on that page. This is read from the HTML files, without
  the browser.

It prints one line per page (how many of each were checked, how many fail), the failures,
the totals and the time taken, and exits 1 if anything fails (2 if the site does not build or
Chromium cannot be run). The browser is Debian's ``chromium``, driven by Playwright (a
development dependency; its own browser downloads are not needed);
``tests/test_site_in_browser.py`` runs the same checks.
"""

from __future__ import annotations

import argparse
import html.parser
import os
import posixpath
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any
from urllib.parse import unquote, urlsplit

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
CHROMIUM = Path("/usr/bin/chromium")
WIDTH = 1280
"""Window width, in CSS pixels: a laptop's screen."""
HEIGHT = 900
TOLERANCE_PX = 1
"""Layout widths are fractional and scrollWidth is rounded: one pixel is rounding."""
TIMEOUT_S = 30.0
"""Longest wait for one reply or event of the browser (a page, with its images)."""
NOT_PAGES = ("_static", "_sources", "_images", "_downloads")
"""Folders of the built site that hold no page of it."""

CHROMIUM_FLAGS = (
    "--no-sandbox",  # the sandbox refuses to start as root, as in a CI container
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-extensions",
)
"""Beside Playwright's own (headless, its pipe): the flags a CI container needs, and no
connections to the network the machine does not have."""

# Run in each page once it has loaded: waits (up to a deadline) for its images, which lazy
# loading would otherwise leave unloaded below the fold, then measures. Returns plain JSON.
MEASURE = """
(async () => {
  const images = [...document.images];
  for (const image of images) image.loading = "eager";
  const settled = Promise.all(images.map((image) => image.complete ? null : new Promise(
    (done) => { image.addEventListener("load", done); image.addEventListener("error", done); })));
  await Promise.race([settled, new Promise((done) => setTimeout(done, %(deadline_ms)d))]);
  await document.fonts.ready;
  const found = {
    column: null,
    page: {needed: document.documentElement.scrollWidth,
           available: document.documentElement.clientWidth},
    boxes: [],
    images: images.map((image) => ({src: image.getAttribute("src") || "",
                                    loaded: image.complete && image.naturalWidth > 0})),
  };
  const article = document.querySelector("article[role=main]");
  if (article === null) return found;
  const style = getComputedStyle(article);
  const columnLeft = article.getBoundingClientRect().left + article.clientLeft
    + parseFloat(style.paddingLeft);
  found.column = article.clientWidth - parseFloat(style.paddingLeft)
    - parseFloat(style.paddingRight);
  const contentWidth = (box) => {
    const boxStyle = getComputedStyle(box);
    return box.clientWidth - parseFloat(boxStyle.paddingLeft) - parseFloat(boxStyle.paddingRight);
  };
  const section = (element) => element.closest("section[id]")?.id || "";
  const label = (text) => text.replace(/\\s+/g, " ").trim().slice(0, 80).trim();
  for (const table of article.querySelectorAll("table")) {
    // furo's wrapper is the column's width plus its padding (room for the table's shadow):
    // its content box, not its border box, is the room the table has
    const wrapper = table.closest(".table-wrapper");
    const row = table.querySelector("tr");
    const cells = row === null ? [] : [...row.cells].map((cell) => cell.textContent.trim());
    found.boxes.push({kind: "table", section: section(table), label: label(cells.join(" | ")),
      needed: table.scrollWidth,
      available: wrapper === null ? found.column : Math.min(found.column, contentWidth(wrapper))});
  }
  for (const pre of article.querySelectorAll("pre")) {
    // a <pre> scrolls itself: its text is wider than its box, or its box than the column
    const room = columnLeft + found.column - pre.getBoundingClientRect().left;
    found.boxes.push({kind: "code block", section: section(pre),
      label: label(pre.textContent.split("\\n")[0]), needed: pre.scrollWidth,
      available: Math.min(pre.clientWidth, room)});
  }
  return found;
})()
"""


class BrowserError(RuntimeError):
    """Chromium could not be started, stopped answering, or failed on a page."""


class Chromium:
    """Debian's headless Chromium driven by Playwright (its own browser downloads are not
    used: ``executable_path`` names the system's), with one tab for the pages."""

    def __init__(self, executable: Path = CHROMIUM, width: int = WIDTH) -> None:
        self.executable = executable
        self.width = width
        self._playwright: Any = None
        self._browser: Any = None
        self._page: Any = None

    def __enter__(self) -> Chromium:
        from playwright.sync_api import Error, sync_playwright

        self._playwright = sync_playwright().start()
        try:
            # a desktop browser's scrollbar takes its width from the page (Playwright hides it)
            self._browser = self._playwright.chromium.launch(
                executable_path=str(self.executable),
                args=list(CHROMIUM_FLAGS),
                ignore_default_args=["--hide-scrollbars"],
            )
            self._page = self._browser.new_page(viewport={"width": self.width, "height": HEIGHT})
        except Error as error:
            self.__exit__(None, None, None)
            raise BrowserError(f"{self.executable} could not be started: {error}") from error
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if self._browser is not None:
            self._browser.close()
            self._browser = None
        if self._playwright is not None:
            self._playwright.stop()
            self._playwright = None

    def measure(self, url: str) -> dict[str, Any]:
        """Open ``url`` in the tab, wait for its load event, and run ``MEASURE`` in it."""
        from playwright.sync_api import Error

        try:
            self._page.goto(url, wait_until="load", timeout=TIMEOUT_S * 1000)
            return self._page.evaluate(MEASURE % {"deadline_ms": int(TIMEOUT_S * 1000 / 2)})
        except Error as error:
            raise BrowserError(f"{url}: {error}") from error


# --- the checks ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Wide:
    """A table or code block wider than the box it is shown in, or a page wider than the
    window."""

    kind: str
    """``table``, ``code block`` or ``page``."""
    section: str
    """The ``id`` of the section it is in (the anchor of its heading), if any."""
    label: str
    """A table's first row, a code block's first line."""
    needed: float
    """Its width in CSS pixels (its ``scrollWidth``)."""
    available: float
    """The width of the box it is shown in."""

    def __str__(self) -> str:
        if self.kind == "page":
            return f"the page is {self.needed:.0f} px wide in a {self.available:.0f} px window"
        where = f"#{self.section}: " if self.section else ""
        size = f"{self.needed:.0f} px wide in {self.available:.0f} px"
        return f"{where}{self.kind} {size}: {self.label!r}"


@dataclass
class PageReport:
    """What was checked on one page, and what failed."""

    page: str
    """Its path in the site, ``/``-separated."""
    column: float | None = None
    tables: int = 0
    code_blocks: int = 0
    images: int = 0
    links: int = 0
    wide: list[Wide] = field(default_factory=list)
    broken_images: list[str] = field(default_factory=list)
    broken_links: list[str] = field(default_factory=list)

    @property
    def wide_tables(self) -> list[Wide]:
        return [w for w in self.wide if w.kind == "table"]

    @property
    def wide_code(self) -> list[Wide]:
        return [w for w in self.wide if w.kind == "code block"]

    @property
    def wide_page(self) -> list[Wide]:
        return [w for w in self.wide if w.kind == "page"]

    def failures(self) -> list[str]:
        """One line per failure, naming the page."""
        return [
            *(f"{self.page}{'' if wide.section else ': '}{wide}" for wide in self.wide),
            *(f"{self.page}: image not loaded: {src}" for src in self.broken_images),
            *(f"{self.page}: {problem}" for problem in self.broken_links),
        ]


def pages(site: Path) -> list[Path]:
    """The HTML pages of the built site ``site``."""
    return sorted(
        path for path in site.rglob("*.html") if path.relative_to(site).parts[0] not in NOT_PAGES
    )


class _Links(html.parser.HTMLParser):
    """The ``href`` of every ``<a>`` and every ``id``/``name`` of an HTML page."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.hrefs: list[str] = []
        self.ids: set[str] = set()

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        values = dict(attrs)
        for name in ("id", "name") if tag == "a" else ("id",):
            if values.get(name):
                self.ids.add(str(values[name]))
        if tag == "a" and values.get("href") is not None:
            self.hrefs.append(str(values["href"]))


def _parse(path: Path) -> _Links:
    parser = _Links()
    parser.feed(path.read_text(encoding="utf-8"))
    parser.close()
    return parser


def link_problems(site: Path, page: Path, cache: dict[Path, _Links]) -> tuple[int, list[str]]:
    """How many internal links ``page`` has, and why each broken one is broken."""
    if page not in cache:
        cache[page] = _parse(page)
    problems = []
    internal = 0
    page_path = page.relative_to(site).as_posix()
    for href in cache[page].hrefs:
        parts = urlsplit(href)
        if parts.scheme or parts.netloc:  # https:, mailto:, //host: not this site's
            continue
        internal += 1
        path, anchor = unquote(parts.path), unquote(parts.fragment)
        if path.startswith("/"):
            problems.append(f"{href}: an absolute path, broken wherever the site is not at /")
            continue
        joined = posixpath.normpath(posixpath.join(posixpath.dirname(page_path), path))
        if path and (joined == ".." or joined.startswith("../")):
            problems.append(f"{href}: outside the site")
            continue
        target = site / joined if path else page
        if target.is_dir():
            target = target / "index.html"
        if not target.is_file():
            problems.append(f"{href}: no such file")
            continue
        if anchor and target.suffix == ".html":
            if target not in cache:
                cache[target] = _parse(target)
            if anchor not in cache[target].ids:
                problems.append(f"{href}: no id {anchor!r} on {target.relative_to(site)}")
    return internal, problems


def check_site(site: Path, chromium: Path = CHROMIUM, width: int = WIDTH) -> Iterator[PageReport]:
    """Check every page of the built site ``site``, yielding each page's report as it is done.

    Raises ``BrowserError`` if Chromium cannot be run or fails on a page.
    """
    parsed: dict[Path, _Links] = {}
    with Chromium(chromium, width) as browser:
        for page in pages(site):
            report = PageReport(page.relative_to(site).as_posix())
            found = browser.measure(page.resolve().as_uri())
            report.column = found["column"]
            page_width = found["page"]
            if page_width["needed"] > page_width["available"] + TOLERANCE_PX:  # sideways scroll
                report.wide.append(
                    Wide("page", "", "", page_width["needed"], page_width["available"])
                )
            for box in found["boxes"]:
                if box["kind"] == "table":
                    report.tables += 1
                else:
                    report.code_blocks += 1
                if box["needed"] > box["available"] + TOLERANCE_PX:
                    fields = ("kind", "section", "label", "needed", "available")
                    report.wide.append(Wide(*(box[name] for name in fields)))
            report.images = len(found["images"])
            report.broken_images = [i["src"] for i in found["images"] if not i["loaded"]]
            report.links, report.broken_links = link_problems(site, page, parsed)
            yield report


def build_site(out: Path) -> None:
    """Build ``docs/`` into ``out`` as CI does (warnings as errors); Sphinx's cache beside it.

    Raises ``RuntimeError`` with Sphinx's messages if the build fails.
    """
    result = subprocess.run(
        [sys.executable, "-m", "sphinx", "-q", "-W", "--keep-going", "-b", "html",
         "-d", str(out.parent / f"{out.name}-doctrees"), str(DOCS), str(out)],
        capture_output=True, text=True, env={**os.environ, "MPLBACKEND": "Agg"},
    )  # fmt: skip
    if result.returncode != 0:
        raise RuntimeError(f"the site does not build:\n{result.stderr}")


# --- the report -----------------------------------------------------------------------------


def _count(failed: int, checked: int) -> str:
    return f"{failed}/{checked}"


def format_line(report: PageReport) -> str:
    """One page's summary: failed/checked of each check."""
    column = f"{report.column:.0f} px" if report.column is not None else "none"
    return (
        f"{report.page:<45} column {column:>7}  "
        f"tables too wide {_count(len(report.wide_tables), report.tables):>6}  "
        f"code too wide {_count(len(report.wide_code), report.code_blocks):>6}  "
        f"images broken {_count(len(report.broken_images), report.images):>5}  "
        f"links broken {_count(len(report.broken_links), report.links):>8}"
    )


def format_totals(reports: list[PageReport]) -> str:
    """The totals over the pages, as failed/checked."""

    def total(attribute: str) -> int:
        return sum(getattr(r, attribute) for r in reports)

    def failed(attribute: str) -> int:
        return sum(len(getattr(r, attribute)) for r in reports)

    return "\n".join(
        [
            f"pages: {len(reports)}, wider than the window: {failed('wide_page')}",
            f"tables too wide: {_count(failed('wide_tables'), total('tables'))}",
            f"code blocks too wide: {_count(failed('wide_code'), total('code_blocks'))}",
            f"images broken: {_count(failed('broken_images'), total('images'))}",
            f"internal links broken: {_count(failed('broken_links'), total('links'))}",
        ]
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m perf.site_check",
        description="Open every page of the documentation site in headless Chromium: tables "
        "and code blocks wider than the content column, images that do not load, internal "
        "links and anchors that do not resolve. Exit 1 if any.",
    )
    parser.add_argument(
        "--site",
        type=Path,
        help="a built site (its folder of index.html); default: build docs/ into a temporary "
        "folder first",
    )
    parser.add_argument(
        "--chromium", type=Path, default=CHROMIUM, help=f"the browser (default {CHROMIUM})"
    )
    parser.add_argument(
        "--width", type=int, default=WIDTH, help=f"window width in px (default {WIDTH})"
    )
    args = parser.parse_args(argv)
    if args.site is not None and not (args.site / "index.html").is_file():
        parser.error(f"{args.site} holds no index.html: not a built site")
    if not args.chromium.exists():
        print(f"no browser at {args.chromium} (Debian: apt-get install chromium)", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="site-check-") as folder:
        build_s = None
        site = args.site
        if site is None:
            site = Path(folder) / "html"
            started = time.perf_counter()
            try:
                build_site(site)
            except RuntimeError as error:
                print(error, file=sys.stderr)
                return 2
            build_s = time.perf_counter() - started
        started = time.perf_counter()
        reports = []
        try:
            for report in check_site(site, args.chromium, args.width):
                print(format_line(report), flush=True)
                reports.append(report)
        except BrowserError as error:
            print(f"the browser failed: {error}", file=sys.stderr)
            return 2
        check_s = time.perf_counter() - started
    failures = [line for report in reports for line in report.failures()]
    if failures:
        print("\nfailures:")
        print("\n".join(f"  {line}" for line in failures))
    print()
    print(format_totals(reports))
    timing = f"check: {check_s:.1f} s"
    if build_s is not None:
        timing = f"build: {build_s:.1f} s, {timing}, total: {build_s + check_s:.1f} s"
    print(timing)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
