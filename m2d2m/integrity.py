"""Files checked against the sizes and checksums their manifest records, every time they are read.

A manifest lists each shard as ``{name, bytes, sha256}`` (docs/data.md). A reader checks the size
of every file on every read (one ``stat``) and its sha256 once: the digest is cached in
``.verified.json`` beside the files, keyed by the file's size, mtime and ctime, so a file written
or modified since (or a copy of the directory) is hashed again. The cache is only an
optimisation: it is replaced atomically (several readers at once are safe, the last one wins),
an unreadable one counts as empty, and a read-only directory simply goes uncached.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from m2d2m.atomic import atomic_path

VERIFIED = ".verified.json"
_STAMP = ("bytes", "mtime_ns", "ctime_ns")


def sha256_of(path: str | Path) -> str:
    digest = hashlib.sha256()
    with Path(path).open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _read_cache(directory: Path) -> dict[str, dict[str, Any]]:
    try:
        cache = json.loads((directory / VERIFIED).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return cache if isinstance(cache, dict) else {}


def _write_cache(directory: Path, cache: dict[str, dict[str, Any]]) -> None:
    """Replace the cache in one rename (each process writes its own temporary file); give up
    quietly where the directory cannot be written."""
    try:
        with atomic_path(directory / VERIFIED) as partial:
            partial.write_text(json.dumps(cache, sort_keys=True), encoding="utf-8")
    except OSError:
        pass


def verified_paths(directory: str | Path, records: list[dict[str, Any]], remedy: str) -> list[str]:
    """Absolute paths of the files ``records`` list in ``directory``, in order, once each is found
    with its recorded size and sha256; otherwise a one-line error naming the file and ending
    with ``remedy`` (FileNotFoundError for a missing file, ValueError for a changed one)."""
    directory = Path(directory).resolve()
    cache = _read_cache(directory)
    hashed: dict[str, dict[str, Any]] = {}
    paths = []
    try:
        for record in records:
            path = directory / record["name"]
            try:
                status = path.stat()
            except FileNotFoundError:
                raise FileNotFoundError(f"{path}: missing, though the manifest lists it; {remedy}") from None
            if status.st_size != record["bytes"]:
                raise ValueError(f"{path}: {status.st_size} bytes, the manifest records {record['bytes']}; {remedy}")
            stamp = dict(zip(_STAMP, (status.st_size, status.st_mtime_ns, status.st_ctime_ns)))
            entry = cache.get(record["name"])
            if not isinstance(entry, dict) or any(entry.get(key) != value for key, value in stamp.items()):
                entry = hashed[record["name"]] = {**stamp, "sha256": sha256_of(path)}
            if entry.get("sha256") != record["sha256"]:
                raise ValueError(f"{path}: sha256 differs from the manifest's; {remedy}")
            paths.append(str(path))
    finally:
        if hashed:
            _write_cache(directory, {**cache, **hashed})
    return paths
