"""The exceptions of a sweep and of its results store, in a module of their own so that the
modules raising them (store, seal, manifest, executors, guard, sweep) import one another one
way only."""

from __future__ import annotations


class StoreError(RuntimeError):
    """A results folder that cannot be used as asked (reported in one line)."""


class StoreBusy(StoreError):
    """Another sweep holds the results folder."""


class IntegrityError(StoreError):
    """A stored file whose bytes or contents do not prove it is the file written under its
    name; the message says why, without the path."""


class ManifestError(StoreError):
    """``manifest.json`` is damaged, or missing beside stored runs."""


class ManifestUnreadable(StoreError):
    """``manifest.json`` could not be read (an I/O error, not damage: rebuilding it would
    throw away a manifest that may be intact)."""


class SweepError(RuntimeError):
    """A sweep that cannot start or go on as asked (reported in one line, exit 2)."""


class SweepStopped(Exception):
    """What stopped a sweep before its end; the finished runs are stored and it resumes.

    ``advice`` ends the one-line message after the count of stored runs.
    """

    def __init__(
        self,
        reason: str,
        advice: str = "run the same command again to finish",
        option: str = "--out",
    ) -> None:
        super().__init__(reason)
        self.reason = reason
        self.advice = advice
        self.option = option
        """The command-line option the stop concerns, which the one-line message names."""
