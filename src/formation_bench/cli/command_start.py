"""Ctrl-C while the command line is still importing its modules.

Importing the command line takes about half a second (numpy, numba, the registries); a
Ctrl-C then would print a traceback from whatever import it hit. Imported before those
modules, this installs a handler that leaves at once with the command's one line and exit
code 130: nothing has started, so there is nothing to clean up. :func:`formation_bench.
cli.main.main` replaces it when it starts.

Only when this process is the command itself (the ``formation-bench`` script or ``python -m
formation_bench.cli``): a test or a notebook importing the module keeps its own
Ctrl-C.
"""

from __future__ import annotations

import os
import signal
import sys

INTERRUPTED_EXIT = 130
"""Exit code of an interrupted command (128 + SIGINT), as shells report it."""


def interrupted_while_starting(signum: int, frame: object) -> None:
    """Leave at once: the command has not started anything."""
    os.write(2, b"formation-bench: interrupted\n")
    os._exit(INTERRUPTED_EXIT)


def is_the_command() -> bool:
    """Whether this process was started as the ``formation-bench`` command: its script, or
    ``python -m`` of the command line's module (which may be a source tree's copy of it, not
    the installed one this module belongs to)."""
    started_as = os.path.abspath(sys.argv[0]) if sys.argv and sys.argv[0] else ""
    parts = started_as.split(os.sep)
    return parts[-1] == "formation-bench" or parts[-2:] in (
        ["cli", "__main__.py"],
        ["cli", "main.py"],
    )


if is_the_command() and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
    signal.signal(signal.SIGINT, interrupted_while_starting)
