"""Output folders that appear only when complete.

A command writes into a temporary sibling of ``--out`` and renames it into place at
the end, so an interrupted or failed command leaves nothing that looks finished,
and ``--overwrite`` replaces an old folder as a whole (no stale figures survive).

The temporary sibling, ``.OUT.<pid>.<random>.partial``, is held with ``flock`` for as
long as its command writes it. The kernel drops that lock when the process dies, even by
SIGKILL, so the next command writing to the same place tells a folder left by a killed
command (lock free: removed) from one another command is writing now (lock held:
refused), without trusting a pid that may have been reused.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import glob
import os
import re
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from formation_bench.pipeline.interrupts import interrupts_deferred

STORAGE_PROBLEMS = {
    errno.ENOSPC: "disk full",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "permission denied",
}
"""Write errors that say where a result cannot be stored, not that a command went wrong."""


class OutputError(ValueError):
    """An output path that cannot be used as asked (one line naming it)."""


class StorageError(OutputError):
    """A write refused by the file system: full, over quota, read-only or not permitted."""


class LinkError(OutputError):
    """A path inside a folder the user named that goes through a symbolic link."""


def confined(root: Path, path: Path, option: str = "--out") -> Path:
    """``path`` (inside ``root``), checked to go through no symbolic link below ``root``.

    Every file and folder a command writes or deletes inside a folder the user named (a
    results folder's ``runs/``, ``traces/``, ``report/``, its manifest, ...) goes through
    here first: a link there would send the write, or an ``--overwrite``'s deletion, to
    wherever it points, outside the folder named. ``root`` itself may be a link: the user
    named it. Raises :class:`LinkError` naming the link.
    """
    step = root
    for part in path.relative_to(root).parts:
        step = step / part
        if step.is_symlink():
            raise LinkError(
                f"{option} {root}: {step} is a symbolic link (to {os.readlink(step)}); nothing "
                f"is written or deleted through a link inside {root}; remove the link (or "
                "put what it points to in its place)"
            )
    return path


def storage_problem(err: BaseException, where: Path | str | None = None) -> str | None:
    """``"disk full writing PATH"`` (or read-only, ...) for a refused write, else None.

    ``where`` names the place when the error does not (a failed ``write`` names no file).
    """
    if not isinstance(err, OSError) or err.errno not in STORAGE_PROBLEMS:
        return None
    path = err.filename or where
    return STORAGE_PROBLEMS[err.errno] + (f" writing {path}" if path else "")


def storage_advice(err: OSError) -> str:
    """What to do about a refused write, to end its one-line message."""
    if err.errno in (errno.ENOSPC, errno.EDQUOT):
        return "run the same command again when there is room"
    return "make it writable or choose another folder, then run the same command again"


def unwritable_parent(path: Path) -> str | None:
    """Why nothing can be created at ``path``: its nearest existing ancestor is a file, or is
    not writable (read-only or immutable, which ``os.access`` sees even as root); None if it
    can be."""
    ancestor = path.parent if path.parent != Path("") else Path(".")
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        return f"{ancestor} is a file, not a folder"
    if not os.access(ancestor, os.W_OK | os.X_OK):
        return f"{ancestor} is not writable (read-only or immutable)"
    return None


def check_output_folder(out: Path, *, overwrite: bool, option: str = "--out") -> None:
    """Refuse an output path that is a file, under a file, not writable, or non-empty."""
    if out.is_symlink() and not out.exists():
        raise OutputError(
            f"{option} {out}: is a broken symbolic link (to {os.readlink(out)}); remove it or "
            "choose another folder"
        )
    if out.exists() and not out.is_dir():
        raise OutputError(f"{option} {out}: is a file, not a folder")
    problem = unwritable_parent(out)
    if problem is not None:
        raise OutputError(f"{option} {out}: {problem}")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise OutputError(
            f"{option} {out}: folder exists and is not empty; choose another folder or add "
            "--overwrite to replace it"
        )


def _partial_name(out: Path) -> re.Pattern[str]:
    """Names of the staging folders of ``out``: ``.OUT.<pid>.<random>.partial`` (and the
    older ``.OUT.<random>.partial``); the random part never holds a dot, so the folders of
    ``OUT.b`` are not taken for those of ``OUT``."""
    return re.compile(rf"\.{re.escape(out.name)}\.(?:(?P<pid>\d+)\.)?[a-z0-9_]+\.partial")


def _hold(folder: Path) -> int | None:
    """An open descriptor of ``folder`` holding its lock, or None if another process holds it."""
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return None
    return fd


def clear_partials(out: Path, *, option: str = "--out", own: Path | None = None) -> int:
    """Remove the staging folders of ``out`` left by killed commands; refuse if one is live.

    Returns how many were removed. A staging folder whose lock is held belongs to a command
    writing ``out`` now: two commands writing one folder would silently replace each other.
    """
    pattern = _partial_name(out)
    removed = 0
    for path in sorted(out.parent.glob(f".{glob.escape(out.name)}.*.partial")):
        match = pattern.fullmatch(path.name)
        if match is None or path == own or not path.is_dir():
            continue
        try:
            fd = _hold(path)
        except FileNotFoundError:  # its owner finished meanwhile
            continue
        if fd is None:
            owner = f" (pid {match['pid']})" if match["pid"] else ""
            raise OutputError(
                f"{option} {out}: another command{owner} is writing it now; wait for it to "
                "finish or choose another folder"
            )
        try:
            shutil.rmtree(path, ignore_errors=True)
            removed += 1
        finally:
            os.close(fd)
    # an old folder set aside by a replace that was killed before deleting it
    set_aside = re.compile(rf"\.{re.escape(out.name)}\.old-(?P<pid>\d+)")
    for path in out.parent.glob(f".{glob.escape(out.name)}.old-*"):
        match = set_aside.fullmatch(path.name)
        if match is not None and not _alive(int(match["pid"])):
            shutil.rmtree(path, ignore_errors=True)
            removed += 1
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return pid != os.getpid()


@contextlib.contextmanager
def staged_folder(out: Path, *, overwrite: bool, option: str = "--out") -> Iterator[Path]:
    """A temporary folder beside ``out``, renamed to ``out`` when the block ends normally.

    A write the file system refuses (disk full, read-only, ...) is reported as a
    :class:`StorageError` naming the path it was meant for; nothing of the command is kept
    and ``out`` is left as it was. An ``out`` the user named may be a link, and is written
    where it points; one the command chose inside a folder the user named (a results
    folder's ``report/``) is checked by :func:`confined` first.
    """
    if out.is_symlink() and out.is_dir():
        out = out.resolve()  # write where the link points; renaming onto a link fails
    check_output_folder(out, overwrite=overwrite, option=option)
    staging: Path | None = None
    fd: int | None = None
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(
            tempfile.mkdtemp(
                prefix=f".{out.name}.{os.getpid()}.", suffix=".partial", dir=out.parent
            )
        )
        fd = _hold(staging)
        clear_partials(out, option=option, own=staging)
        umask = os.umask(0)
        os.umask(umask)
        staging.chmod(0o777 & ~umask)  # mkdtemp makes it private; a result folder is not
        yield staging
        if out.is_dir() and any(out.iterdir()) and not overwrite:
            raise OutputError(
                f"{option} {out}: another command wrote this folder while this one ran; its "
                "files are kept and this command's output is discarded (add --overwrite to "
                "replace them)"
            )
        old = None
        if out.exists():
            old = out.with_name(f".{out.name}.old-{os.getpid()}")
            out.rename(old)
        staging.rename(out)
        staging = None
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except OSError as err:
        problem = storage_problem(err, where=staging or out)
        if problem is None:
            raise
        if staging is not None:
            problem = problem.replace(str(staging), str(out))
        raise StorageError(
            f"{option} {out}: {problem}; nothing of this command was kept and {out} is as it "
            f"was; {storage_advice(err)}"
        ) from None
    finally:
        with interrupts_deferred():  # a second Ctrl-C must not leave the staging folder
            if staging is not None:
                shutil.rmtree(staging, ignore_errors=True)
            if fd is not None:
                os.close(fd)
