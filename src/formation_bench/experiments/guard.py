"""A sweep's check that the results folder it locked is still there before every write
(:class:`FolderGuard`)."""

from __future__ import annotations

import os
from pathlib import Path

from formation_bench.experiments.errors import SweepStopped


def _identity(status: os.stat_result) -> tuple[int, int]:
    return (status.st_dev, status.st_ino)


class FolderGuard:
    """Tells whether a sweep's folder and lock file are still the ones it started with.

    The lock is an ``flock`` on ``DIR/.lock``; it excludes a second sweep only while that
    file stays at that path. Deleting the folder or the lock file (or moving the folder)
    would let a second sweep lock a new file and write beside this one, and this sweep's
    next write would silently recreate the folder. So before every write the sweep
    compares the folder and the lock file at their paths with the ones it opened, and stops
    at the first difference instead of writing.
    """

    def __init__(self, root: Path) -> None:
        """Call while holding the lock: the lock file at its path is then the one locked."""
        # the store module imports pandas; a guard is made only by a sweep that loaded it
        from formation_bench.experiments.store import LOCK

        self.root = root
        self.lock_path = root / LOCK
        self.lock_id = _identity(os.stat(self.lock_path))
        self.root_fd = os.open(root, os.O_RDONLY | os.O_DIRECTORY)
        self.root_id = _identity(os.fstat(self.root_fd))

    def problem(self) -> str | None:
        """Why the sweep must not write any more, or None while its folder is intact."""
        try:
            root_now = _identity(os.stat(self.root))
        except FileNotFoundError:
            root_now = None
        if root_now != self.root_id:
            return f"{self.root} was {self._whereabouts()} while the sweep ran"
        try:
            lock_now = _identity(os.stat(self.lock_path))
        except FileNotFoundError:
            lock_now = None
        if lock_now != self.lock_id:
            change = "deleted" if lock_now is None else "replaced"
            return (
                f"its lock file {self.lock_path} was {change} while the sweep ran, so another "
                "sweep could write into the folder unseen"
            )
        return None

    def check(self) -> None:
        """Stop the sweep (:class:`SweepStopped`) if its folder or lock is gone."""
        problem = self.problem()
        if problem is not None:
            raise SweepStopped(problem, "nothing was recreated; run the same command again")

    def _whereabouts(self) -> str:
        try:  # Linux: the descriptor follows the folder
            target = os.readlink(f"/proc/self/fd/{self.root_fd}")
        except OSError:
            return "deleted or moved"
        if target.endswith(" (deleted)"):
            return "deleted"
        return f"moved to {target}"

    def close(self) -> None:
        os.close(self.root_fd)
