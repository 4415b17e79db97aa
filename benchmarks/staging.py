"""Output folders that appear only when complete.

A command writes into a temporary sibling of ``--out`` and renames it into place at
the end, so an interrupted or failed command leaves nothing that looks finished,
and ``--overwrite`` replaces an old folder as a whole (no stale figures survive).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path


class OutputError(ValueError):
    """An output path that cannot be used as asked (one line naming it)."""


def check_output_folder(out: Path, *, overwrite: bool, option: str = "--out") -> None:
    """Refuse an output path that is a file, under a file, not writable, or non-empty."""
    if out.exists() and not out.is_dir():
        raise OutputError(f"{option} {out}: is a file, not a folder")
    parent = out.parent if out.parent != Path("") else Path(".")
    ancestor = parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise OutputError(f"{option} {out}: {ancestor} is a file, not a folder")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise OutputError(f"{option} {out}: {ancestor} is not writable")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise OutputError(
            f"{option} {out}: folder exists and is not empty; choose another folder or add "
            "--overwrite to replace it"
        )


@contextlib.contextmanager
def staged_folder(out: Path, *, overwrite: bool, option: str = "--out") -> Iterator[Path]:
    """A temporary folder beside ``out``, renamed to ``out`` when the block ends normally."""
    check_output_folder(out, overwrite=overwrite, option=option)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=out.parent))
    umask = os.umask(0)
    os.umask(umask)
    staging.chmod(0o777 & ~umask)  # mkdtemp makes it private; a result folder is not
    try:
        yield staging
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    old = None
    if out.exists():
        old = out.with_name(f".{out.name}.old-{os.getpid()}")
        out.rename(old)
    staging.rename(out)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
