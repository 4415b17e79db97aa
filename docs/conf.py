"""Sphinx configuration of the documentation site (Markdown pages through MyST, furo theme).

Build: ``python -m sphinx -W --keep-going -b html -d docs/_build/doctrees docs docs/_build/html``
(CI does, with warnings as errors; ``-d`` keeps Sphinx's cache out of the site's folder). The
reference pages under ``reference/_generated/`` are written at the start of every build from
the code's declarations, and the committed ``reference/cli.md`` is checked against the code
(``_ext/formation_reference.py``).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

import formation_bench

project = "formation-bench"
author = "The formation-bench developers"
copyright = "The formation-bench developers"
release = formation_bench.__version__
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx_copybutton",
]

source_suffix = {".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "_ext", "Thumbs.db", ".DS_Store"]

# --- MyST ---
# no $math$ and no definition lists: a dollar sign or a line starting with ":" stays plain text
myst_enable_extensions = ["colon_fence"]
# `page.md#section-title` links resolve to the headings of levels 1 to 4, slugged as GitHub
# slugs them (so the same links work on GitHub); a link to a page or an anchor that does not
# exist, or to a file outside docs/, is a warning, so an error in CI (tests/test_docs_tables.py
# checks the same without building)
myst_heading_anchors = 4

# --- autodoc (reference/api.md); not nitpicky: the type hints name numpy, pandas and standard
# library classes that have no target here (some 300 warnings with -n) ---
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"members": True, "show-inheritance": True}

# --- the copy button (sphinx-copybutton) ---
# a console block shows `$ COMMAND` lines and their output: the button copies the commands
# alone, without the prompt; a block without prompts (bash, sh) is copied whole. A line ending
# in a backslash continues its command.
copybutton_prompt_text = "$ "
copybutton_only_copy_prompt_lines = True
copybutton_remove_prompts = True
copybutton_copy_empty_lines = False
copybutton_line_continuation_character = "\\"

# --- HTML ---
html_theme = "furo"
html_title = "formation-bench"
# the site's own CSS (_static/site.css): how much room tables and code blocks get, checked in a
# browser by perf/site_check.py
html_static_path = ["_static"]
html_css_files = ["site.css"]
html_show_sourcelink = False


def setup(app: Any) -> None:
    """Load the reference generator from ``_ext/`` by its path (it is not an installed
    module)."""
    path = Path(__file__).parent / "_ext" / "formation_reference.py"
    spec = importlib.util.spec_from_file_location("formation_reference", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.setup(app)
