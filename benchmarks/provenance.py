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
)


def package_versions() -> dict[str, str | None]:
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
        "dirty": ".d" in version.partition("+")[2] if built else None,
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


def machine_info() -> dict[str, Any]:
    info: dict[str, Any] = {
        "hostname": platform.node(),
        "platform": platform.platform(),
        "machine": platform.machine(),
        "processor": platform.processor() or None,
        "cpu_count": os.cpu_count(),
    }
    if hasattr(os, "sched_getaffinity"):
        info["cpus_available"] = len(os.sched_getaffinity(0))
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                info["cpu_model"] = line.split(":", 1)[1].strip()
                break
    with contextlib.suppress(OSError, ValueError):
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal"):
                info["memory_gib"] = round(int(line.split()[1]) / 2**20, 1)
                break
    return info


def now() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="seconds")
