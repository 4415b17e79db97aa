"""The manifest of a results folder, ``DIR/manifest.json``: the suite file, package versions,
git commit, machine and one entry per sweep session. Read verified (shape and digest), written
sealed, and rebuilt from the verified run rows when it is damaged (the layout, and why a
damaged manifest stops a sweep: :mod:`~formation_bench.experiments.store`)."""

from __future__ import annotations

import json
import shlex
import sys
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, Any

from formation_bench.experiments.errors import (
    IntegrityError,
    ManifestError,
    ManifestUnreadable,
    StoreError,
    SweepError,
)
from formation_bench.experiments.seal import (
    MANIFEST_DIGEST,
    MANIFEST_SEAL,
    manifest_digest_matches,
    read_sealed,
    read_table,
    sealed_manifest,
)
from formation_bench.experiments.store import MANIFEST, RUNS, ResultStore
from formation_bench.pipeline.outputs import atomic_write_bytes
from formation_bench.pipeline.provenance import git_info, machine_info, now, package_versions

if TYPE_CHECKING:
    from formation_bench.experiments.suite import Suite

MANIFEST_FORMAT = 2
"""2: always sealed (format 1 was written both before and after seals were kept)."""
SEALED_FORMAT = 2
"""The first format every manifest of which carries its seal: one without is damaged."""

_MANIFEST_FIELDS: dict[str, type | tuple[type, ...]] = {
    "format": int,
    "created": str,
    "updated": str,
    "suite": dict,
    "sessions": list,
}
"""Top-level manifest fields the sweep reads, and their JSON types."""


def read_manifest(store: ResultStore, suite: Suite | None = None) -> dict[str, Any] | None:
    """The manifest of ``store``, verified; None for a folder that holds no runs yet.

    Raises :class:`ManifestError` (one line naming the file and, given the ``suite``,
    the command that rebuilds it) when it is damaged or missing beside stored runs.
    """
    path = store.manifest_path

    def damaged(reason: str) -> ManifestError:
        return ManifestError(
            f"{path} {reason}; nothing was changed; "
            f"{rebuild_command(suite, store.root)} rebuilds it from the stored runs"
        )

    if not path.exists():
        stored = len(store.keys())
        if stored:
            raise damaged(f"is missing while {store.runs_dir} holds {stored} stored runs")
        return None
    try:
        data = path.read_bytes()
    except OSError as err:
        raise ManifestUnreadable(
            f"{path} could not be read ({err.strerror or type(err).__name__}); nothing was "
            "changed; make it readable (it may be intact) and run the same command again"
        ) from None
    if not data.strip():
        raise damaged("is empty")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as err:
        raise damaged(f"is not UTF-8 text (byte {err.start})") from None
    try:
        manifest = json.loads(text)
    except json.JSONDecodeError as err:
        raise damaged(f"is not valid JSON ({err.msg} at line {err.lineno})") from None
    if not isinstance(manifest, dict):
        raise damaged(f"holds a JSON {type(manifest).__name__}, not an object")
    sealed = MANIFEST_SEAL in manifest or MANIFEST_DIGEST in manifest
    if sealed:
        manifest.pop(MANIFEST_SEAL, None)
        if not manifest_digest_matches(data, manifest.pop(MANIFEST_DIGEST, None)):
            raise damaged("fails its SHA-256 checksum: it changed after it was written")
    problem = _manifest_shape_problem(manifest) or (
        "" if sealed else _unsealed_problem(manifest, store)
    )
    if problem:
        raise damaged(problem)
    return manifest


def _unsealed_problem(manifest: dict[str, Any], store: ResultStore) -> str:
    """Why a manifest without its seal cannot be one written before seals were kept ('' when
    it can): every manifest of :data:`SEALED_FORMAT` on is sealed, and every sweep that
    stored a sealed run wrote a sealed manifest, so a seal missing there was taken away (and
    taking the manifest as it is would let the next sweep seal whatever was edited)."""
    lost = f"has no seal ({MANIFEST_SEAL}, {MANIFEST_DIGEST})"
    if manifest["format"] >= SEALED_FORMAT:
        return f"{lost}, which every manifest of format {SEALED_FORMAT} on carries"
    for key in store.keys():
        try:
            _, seal = read_sealed(store.run_path(key), "run", key)
        except IntegrityError:
            continue
        if seal is not None:
            return (
                f"{lost}, while {store.runs_dir} holds runs stored sealed (every sweep that "
                "stores them seals its manifest)"
            )
    return ""


def write_manifest(store: ResultStore, manifest: dict[str, Any]) -> None:
    """Write ``store``'s ``manifest.json`` atomically, its digest last."""
    atomic_write_bytes(store.inside(store.manifest_path), sealed_manifest(manifest))


def _manifest_shape_problem(manifest: dict[str, Any]) -> str:
    """What is wrong with the fields of a parsed manifest ('' when nothing)."""
    for name, kind in _MANIFEST_FIELDS.items():
        if name not in manifest:
            return f"lacks the field {name!r}"
        if not isinstance(manifest[name], kind) or isinstance(manifest[name], bool):
            return f"has {name!r} of JSON type {type(manifest[name]).__name__}"
    for name in ("name", "sha256"):
        if not isinstance(manifest["suite"].get(name), str):
            return f"has no text 'suite.{name}'"
    for field in ("sessions", "previous_suites"):
        entries = manifest.get(field, [])
        if not isinstance(entries, list) or not all(isinstance(s, dict) for s in entries):
            return f"has {field!r} that is not a list of objects"
    if not all(isinstance(s.get("state"), str) for s in manifest["sessions"]):
        return "has a session without a text 'state'"
    for session in manifest["sessions"]:
        wall = session.get("wall_s")
        if isinstance(wall, int | float) and not isinstance(wall, bool) and wall < 0:
            return (
                f"has a session with a negative duration wall_s={wall:g} s (durations come "
                "from a monotonic clock)"
            )
    return ""


def rebuild_command(suite: Suite | None, root: Path) -> str:
    """The command that rebuilds ``root``'s manifest from its stored runs."""
    if suite is None:
        argument = "SUITE"
    else:
        from formation_bench.experiments.suite import SuiteError, resolve_suite_path

        try:
            shipped = resolve_suite_path(suite.name) == suite.path
        except SuiteError:  # the name is no shipped suite's
            shipped = False
        argument = suite.name if shipped else str(suite.path)
    return (
        f"'formation-bench sweep {shlex.quote(argument)} --out {shlex.quote(str(root))} "
        "--rebuild-manifest'"
    )


def check_suite_matches(
    manifest: dict[str, Any] | None, suite: Suite, root: Path, allow_change: bool
) -> None:
    """Refuse to add ``suite``'s runs to a folder holding another suite file's, unless
    ``allow_change``."""
    if manifest is None or allow_change:
        return
    stored = manifest.get("suite", {})
    if stored.get("sha256") != suite.sha256:
        raise SweepError(
            f"--out: {root} holds results of suite {stored.get('name')!r} from a different suite "
            f"file (sha256 {str(stored.get('sha256'))[:12]}, now {suite.sha256[:12]}); "
            "choose another --out, or add --allow-suite-change to add to it"
        )


def session_entry(jobs: int, scheduler: str | None) -> dict[str, Any]:
    """A new session's entry in the manifest, marked running."""
    return {
        "started": now(),
        "finished": None,
        "state": "running",
        "executor": f"dask {scheduler}" if scheduler else f"joblib loky, {jobs} workers",
        "command": " ".join(sys.argv),
        "versions": package_versions(),
        "git": git_info(),
        "machine": machine_info(),
    }


def mixed_commits(manifest: dict[str, Any] | None, session: dict[str, Any], stored: int) -> str:
    """The notice (one line) for a sweep whose ``session`` runs other code than the earlier
    sessions that stored the folder's ``stored`` runs ("" when it runs the same commit, or
    there is nothing stored to mix with)."""
    if manifest is None or not stored:
        return ""
    here = (session.get("git") or {}).get("commit")
    earlier = {
        (s.get("git") or {}).get("commit")
        for s in manifest.get("sessions", [])
        if isinstance(s.get("git"), dict)
    } - {None}
    if here is None or not earlier or earlier == {here}:
        return ""
    dirty = " (with uncommitted changes)" if (session.get("git") or {}).get("dirty") else ""
    return (
        f"note: the {stored} runs stored in this folder were made at commit "
        f"{', '.join(sorted(c[:10] for c in earlier - {here}))}; this sweep runs commit "
        f"{here[:10]}{dirty}, so the folder now mixes code versions (each run records its own "
        "commit; the report's results page lists them)"
    )


def updated_manifest(
    manifest: dict[str, Any] | None, suite: Suite, total: int, session: dict[str, Any]
) -> dict[str, Any]:
    """``manifest`` (None: a new one) recording ``suite`` and the new ``session``."""
    suite_info = {
        "name": suite.name,
        "file": str(suite.path),
        "sha256": suite.sha256,
        "text": suite.text,
        "runs": total,
        "notes": list(suite.notes),
    }
    if manifest is None:
        manifest = {"format": MANIFEST_FORMAT, "created": session["started"], "sessions": []}
    previous = manifest.get("suite")
    if previous and previous.get("sha256") != suite.sha256:
        manifest.setdefault("previous_suites", []).append(previous)
    manifest["suite"] = suite_info
    manifest["format"] = MANIFEST_FORMAT  # written sealed from now on, whatever it was read as
    manifest["updated"] = session["started"]
    for key in ("versions", "git", "machine"):
        manifest[key] = session[key]
    manifest.setdefault("sessions", []).append(session)
    return manifest


def rebuild_manifest(suite: Suite, root: Path | str) -> str:
    """Write ``root``'s manifest anew from its verified run rows; returns what was done.

    Refuses (:class:`StoreError`) when the manifest is intact, when the folder holds no
    run, or when a verified run came from another suite. The damaged manifest is kept
    beside it as ``manifest.json.damaged``.
    """
    store = ResultStore(root)
    option = "--rebuild-manifest"
    if not store.runs_dir.is_dir():
        raise StoreError(f"{option}: {root} holds no {RUNS}/ folder to rebuild {MANIFEST} from")
    with store.lock():
        try:
            intact = read_manifest(store, suite)
        except ManifestError:
            intact = None
        if intact is not None:
            raise StoreError(
                f"{option}: {store.manifest_path} is intact; nothing to rebuild (rebuilding "
                f"would drop its record of {len(intact['sessions'])} sessions)"
            )
        rows, damaged = [], 0
        for key in store.keys():
            try:
                table, _ = read_table(
                    store.run_path(key), "run", key, ["run_key", "suite", "finished_at"]
                )
            except IntegrityError:
                damaged += 1
                continue
            rows.extend(table.to_pylist())
        if not rows:
            raise StoreError(
                f"{option}: {store.runs_dir} holds no intact run to rebuild {MANIFEST} from "
                f"({damaged} damaged); run the sweep without {option}"
            )
        suites = Counter(str(row["suite"]) for row in rows)
        others = {name: n for name, n in suites.items() if name != suite.name}
        if others:
            found = ", ".join(f"{name!r} ({n} runs)" for name, n in sorted(others.items()))
            raise StoreError(
                f"{option}: {store.runs_dir} holds runs of suite {found}, not of suite "
                f"{suite.name!r}; give the suite those runs came from"
            )
        in_suite = {spec.key for spec in suite.runs()}
        matching = sum(row["run_key"] in in_suite for row in rows)
        session = session_entry(1, None)
        session.update(
            executor=f"none: {MANIFEST} rebuilt from the stored runs",
            finished=now(),
            state="rebuilt",
            total=len(in_suite),
            already=matching,
            rebuilt_from={
                "runs": len(rows),
                "not_in_suite_file": len(rows) - matching,
                "damaged": damaged,
            },
        )
        manifest = updated_manifest(None, suite, len(in_suite), session)
        manifest["created"] = min(str(row["finished_at"]) for row in rows)
        kept = ""
        if store.manifest_path.exists():
            kept_as = store.inside(store.manifest_path.with_name(MANIFEST + ".damaged"))
            store.inside(store.manifest_path).replace(kept_as)
            kept = f"; the damaged one is kept as {MANIFEST}.damaged"
        write_manifest(store, manifest)
    return (
        f"rebuilt {store.manifest_path} from {len(rows)} intact runs of suite {suite.name!r} "
        f"({matching} of its {len(in_suite)} runs; {len(rows) - matching} from another version "
        f"of the suite file; {damaged} damaged run files, which the next sweep redoes); "
        f"earlier sessions are not recorded{kept}; run the sweep again without {option} "
        "to resume"
    )
