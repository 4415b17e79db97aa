"""The checksums that prove a results-store file intact: the seal of each Parquet file and
the digest of ``manifest.json`` (what they cover, and who checks them:
:mod:`~formation_bench.experiments.store`)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from formation_bench.experiments.errors import IntegrityError
from formation_bench.pipeline.outputs import ARROW_THREADS

SEAL_KEY = b"formation_bench.seal"
"""Footer key-value metadata entry holding a store file's seal (see
:mod:`~formation_bench.experiments.store`)."""
SEAL_FORMAT = 1
MANIFEST_SEAL = "manifest_seal"
"""First field of ``manifest.json`` (the seal's format): with the digest, the last field, a
manifest that lost either one is told from one written before checksums were kept."""
MANIFEST_DIGEST = "manifest_sha256"
"""Last field of ``manifest.json``: the SHA-256 of the file with this value zeroed."""

_DIGEST_FIELD = b',"sha256":"'
_ZERO_DIGEST = b"0" * 64

_WRITER_OPTIONS: dict[str, dict[str, Any]] = {
    # A run file holds one row: dictionaries, min/max statistics and zstd (a fresh
    # compression context per page, so per column) buy it nothing, yet took two thirds of the
    # CPU of encoding it, in a sweep's main process. It reads back with the same columns and
    # types, and the readers take run files written either way.
    "run": {"compression": "snappy", "use_dictionary": False, "write_statistics": False},
}
_DEFAULT_WRITER_OPTIONS: dict[str, Any] = {"compression": "zstd"}


def sealed_parquet(table: pa.Table, kind: str, key: str, **fields: Any) -> tuple[bytes, str]:
    """``table`` as Parquet bytes with page checksums and a seal; returns the bytes and
    their digest."""
    seal = json.dumps(
        {"format": SEAL_FORMAT, "kind": kind, "key": key, **fields}, separators=(",", ":")
    )
    seal = seal[:-1] + _DIGEST_FIELD.decode() + _ZERO_DIGEST.decode() + '"}'
    sink = pa.BufferOutputStream()
    options = _WRITER_OPTIONS.get(kind, _DEFAULT_WRITER_OPTIONS)
    with pq.ParquetWriter(sink, table.schema, write_page_checksum=True, **options) as writer:
        writer.write_table(table)
        writer.add_key_value_metadata({SEAL_KEY: seal})
    data = bytearray(sink.getvalue().to_pybytes())
    start = data.rfind(seal.encode()) + len(seal) - len(_ZERO_DIGEST) - 2
    digest = hashlib.sha256(data).hexdigest()
    data[start : start + len(_ZERO_DIGEST)] = digest.encode()
    return bytes(data), digest


def unseal(data: bytes) -> dict[str, Any] | None:
    """The seal of a store file's bytes, verified; None for a file written before seals.

    Raises :class:`IntegrityError` when any byte differs from what was written.
    """
    at = data.rfind(_DIGEST_FIELD)
    if at < 0:
        if SEAL_KEY in _footer_metadata(data):
            raise IntegrityError("its seal is damaged (no digest)")
        return None
    start = at + len(_DIGEST_FIELD)
    end = start + len(_ZERO_DIGEST)
    digest = bytes(data[start:end])
    if data[end : end + 2] != b'"}':
        raise IntegrityError("its seal is damaged (digest cut short)")
    view = memoryview(data)
    actual = hashlib.sha256(view[:start])
    actual.update(_ZERO_DIGEST)
    actual.update(view[end:])
    if actual.hexdigest().encode() != digest:
        raise IntegrityError("SHA-256 mismatch: the file changed after it was written")
    try:
        seal = json.loads(_footer_metadata(data)[SEAL_KEY])
    except (KeyError, ValueError) as err:
        raise IntegrityError(f"its seal cannot be read ({type(err).__name__})") from None
    if not isinstance(seal, dict):
        raise IntegrityError("its seal is not a JSON object")
    return seal


def _footer_metadata(data: bytes) -> dict[bytes, bytes]:
    try:
        return pq.read_metadata(pa.BufferReader(data)).metadata or {}
    except Exception as err:  # whatever the footer parser makes of the bytes, they are no result
        raise IntegrityError(f"not a readable Parquet file ({_reason(err)})") from None


def read_sealed(path: Path, kind: str, key: str) -> tuple[bytes, dict[str, Any] | None]:
    """The bytes of the store file ``path`` and its seal (None: written before seals),
    checked to be a ``kind`` file of ``key``; raises :class:`IntegrityError`."""
    try:
        data = path.read_bytes()
    except OSError as err:
        raise IntegrityError(f"cannot be read ({err.strerror})") from None
    seal = unseal(data)
    if seal is not None:
        if seal.get("kind") != kind:
            raise IntegrityError(f"holds a {seal.get('kind')} file, not a {kind} file")
        if seal.get("key") != key:
            raise IntegrityError(
                f"holds {kind} {seal.get('key')!r}: a file stored under another run's name"
            )
    return data, seal


def decode(data: bytes, columns: list[str] | None = None) -> pa.Table:
    """Parquet bytes as a table, every page checked against its checksum; with ``columns``,
    those of them the file holds (a file stored before a column existed lacks it)."""
    try:
        if columns is not None:
            held = set(pq.read_schema(pa.BufferReader(data)).names)
            columns = [c for c in columns if c in held]
        return pq.read_table(
            pa.BufferReader(data),
            columns=columns,
            page_checksum_verification=True,
            use_threads=ARROW_THREADS,
        )
    except Exception as err:  # a page that fails its CRC or cannot be decoded
        raise IntegrityError(f"cannot be decoded ({_reason(err)})") from None


def check_run_keys(table: pa.Table, key: str) -> None:
    """Every row of ``table`` belongs to run ``key`` (an unsealed file's only key check)."""
    if "run_key" not in table.column_names:
        raise IntegrityError("holds no run_key column")
    found = set(table.column("run_key").to_pylist())
    if found != {key}:
        other = sorted(str(k) for k in found - {key}) or ["none"]
        raise IntegrityError(
            f"holds run {', '.join(other)}: a file stored under another run's name"
        )


def read_table(
    path: Path, kind: str, key: str, columns: list[str] | None = None
) -> tuple[pa.Table, dict[str, Any] | None]:
    """The table of the store file ``path`` and its seal, checked whole: seal, page
    checksums and every row's run key; raises :class:`IntegrityError`."""
    data, seal = read_sealed(path, kind, key)
    table = decode(data, columns)
    check_run_keys(table, key)
    return table, seal


def _reason(err: BaseException) -> str:
    return " ".join(f"{type(err).__name__}: {err}".split())[:200]


def sealed_manifest(manifest: dict[str, Any]) -> bytes:
    """``manifest`` as the bytes of ``manifest.json``: :data:`MANIFEST_SEAL` first, its
    digest (:data:`MANIFEST_DIGEST`) last."""
    body = {MANIFEST_SEAL: SEAL_FORMAT}
    body.update((k, v) for k, v in manifest.items() if k not in (MANIFEST_SEAL, MANIFEST_DIGEST))
    body[MANIFEST_DIGEST] = _ZERO_DIGEST.decode()
    data = (json.dumps(body, indent=2, default=str) + "\n").encode()
    field = f'"{MANIFEST_DIGEST}": "'.encode()
    start = data.rfind(field) + len(field)
    digest = hashlib.sha256(data).hexdigest().encode()
    return data[:start] + digest + data[start + len(_ZERO_DIGEST) :]


def manifest_digest_matches(data: bytes, digest: object) -> bool:
    """Whether ``digest`` is the SHA-256 of the manifest bytes ``data`` with it zeroed."""
    if not isinstance(digest, str) or len(digest) != len(_ZERO_DIGEST):
        return False
    field = f'"{MANIFEST_DIGEST}": "{digest}"'.encode()
    at = data.rfind(field)
    if at < 0:  # written otherwise than by write_manifest
        return False
    start = at + len(field) - len(_ZERO_DIGEST) - 1
    actual = hashlib.sha256(data[:start] + _ZERO_DIGEST + data[start + len(_ZERO_DIGEST) :])
    return actual.hexdigest() == digest
