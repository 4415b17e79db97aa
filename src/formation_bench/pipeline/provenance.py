"""Where and by what a run was made: package versions, the installed code's commit, the
machine and the time. Recorded with every run and in a results folder's manifest."""

from __future__ import annotations

import contextlib
import datetime as dt
import functools
import json
import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any

PACKAGES = (
    "formation-bench",
    "numpy",
    "numba",
    "scipy",
    "scikit-learn",
    "pandas",
    "pyarrow",
    "joblib",
    "dask",
    "distributed",
    "scikit-posthocs",
    "statsmodels",
    "seaborn",
    "matplotlib",
    # the derivative-based baselines (IPOPT inside casadi, OSQP), the QP they are checked
    # against, the IOH export's logger, and the adapted libraries
    "casadi",
    "osqp",
    "cvxpy",
    "ioh",
    "nevergrad",
    "cma",
    "mealpy",
)
"""Packages whose installed versions every manifest records (None: not installed)."""


def package_versions() -> dict[str, str | None]:
    """Python's and every package's version in :data:`PACKAGES` (None: not installed)."""
    return dict(_package_versions())


@functools.cache
def _package_versions() -> dict[str, str | None]:
    # what is installed does not change while a process runs; a sweep asks once per run
    versions: dict[str, str | None] = {"python": platform.python_version()}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


@functools.cache
def git_info() -> dict[str, Any]:
    """The commit of the installed formation-bench code, never of the current directory.

    A regular install carries the commit it was built from (stamped by
    setuptools-scm; ``dirty`` when built from a tree with uncommitted changes).
    An editable install runs the source folder as it is now, so its HEAD and
    dirty flag are read from that folder.
    """
    import formation_bench

    try:
        from formation_bench import _version

        built: str | None = getattr(_version, "__commit_id__", None)
    except ImportError:
        built = None
    version = formation_bench.__version__
    info: dict[str, Any] = {
        "version": version,
        "commit": built.removeprefix("g") if built else None,
        "dirty": uncommitted(version) if built else None,
        "source": "built",
    }
    source = _editable_source()
    if source is None:
        return info
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=source, capture_output=True, text=True,
            timeout=10, check=True,
        ).stdout.strip()  # fmt: skip
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"], cwd=source,
            capture_output=True, text=True, timeout=10, check=True,
        ).stdout.strip()  # fmt: skip
    except (OSError, subprocess.SubprocessError):
        return {**info, "commit": None, "dirty": None, "source": str(source)}
    return {**info, "commit": commit, "dirty": bool(dirty), "source": str(source)}


def uncommitted(version: str) -> bool:
    """Whether a version string setuptools-scm stamped says it was built from a tree with
    uncommitted changes (a ``.dYYYYMMDD`` in its local part)."""
    return ".d" in version.partition("+")[2]


def _editable_source() -> Path | None:
    """The source folder of an editable install (PEP 610's direct_url.json), else None."""
    try:
        text = metadata.distribution("formation-bench").read_text("direct_url.json")
    except metadata.PackageNotFoundError:
        return None
    if not text:
        return None
    try:
        direct = json.loads(text)
    except json.JSONDecodeError:
        return None
    if not direct.get("dir_info", {}).get("editable"):
        return None
    url = str(direct.get("url", ""))
    return Path(url.removeprefix("file://")) if url.startswith("file://") else None


@functools.cache
def cpu_model() -> str | None:
    """The processor's model name (Linux's /proc/cpuinfo, macOS's sysctl), None if unknown."""
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            # "model name" on x86 Linux, "Model" on some ARM boards
            key, _, value = line.partition(":")
            if key.strip() in ("model name", "Model") and value.strip():
                return value.strip()
    if platform.system() == "Darwin":
        with contextlib.suppress(OSError, subprocess.SubprocessError):
            done = subprocess.run(
                ["sysctl", "-n", "machdep.cpu.brand_string"], capture_output=True, text=True,
                timeout=10, check=True,
            )  # fmt: skip
            if done.stdout.strip():
                return done.stdout.strip()
    return platform.processor() or None


def machine_info() -> dict[str, Any]:
    info: dict[str, Any] = {
        "hostname": platform.node(),
        "platform": platform.platform(),
        "machine": platform.machine(),
        "processor": platform.processor() or None,
        "cpu_model": cpu_model(),
        "cpu_count": os.cpu_count(),
    }
    if hasattr(os, "sched_getaffinity"):
        info["cpus_available"] = len(os.sched_getaffinity(0))
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                info["memory_gib"] = round(int(line.split()[1]) / 2**20, 1)
                break
    return info


def now() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
