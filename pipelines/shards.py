"""WebDataset shards written atomically and reproducibly, their manifest, and their verification.

Every arrow of the flow is a set of tar shards plus a ``manifest.json`` written last, so a reader
can trust a directory whose manifest exists: an interrupted writer leaves only files marked
``.partial``, which are never listed. Tar headers are fixed (mtime 0, one owner, sorted members), so
the same samples in the same order give byte-identical shards.
"""

from __future__ import annotations

import io
import json
import os
import tarfile
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import webdataset as wds

from m2d2m.atomic import atomic_path
from m2d2m.integrity import sha256_of

SCHEMA_VERSION = 1
PARTIAL_SUFFIX = ".partial"


@dataclass(frozen=True)
class ShardInfo:
    name: str
    samples: int
    bytes: int
    sha256: str


def npy_bytes(array: np.ndarray) -> bytes:
    """``.npy`` serialisation (deterministic for a given array)."""
    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=False)
    return buffer.getvalue()


def json_bytes(value: Any) -> bytes:
    """Canonical JSON: sorted keys, UTF-8, so equal metadata gives equal bytes."""
    return json.dumps(value, sort_keys=True, ensure_ascii=False, separators=(",", ":")).encode("utf-8")


class ShardWriter:
    """Writes samples to ``<directory>/<prefix>-000000.tar``, ``-000001.tar``, … with at most
    ``samples_per_shard`` samples each; numbering starts at ``first_index`` so that parallel
    writers can each own a range of names. A shard is written as ``<name>.partial`` and renamed
    only when complete; if writing fails, the partial file is removed."""

    def __init__(self, directory: str | Path, prefix: str, samples_per_shard: int, first_index: int = 0) -> None:
        if samples_per_shard <= 0:
            raise ValueError(f"samples_per_shard must be positive, got {samples_per_shard}")
        self.directory = Path(directory)
        self.prefix = prefix
        self.samples_per_shard = samples_per_shard
        self.first_index = first_index
        self.shards: list[ShardInfo] = []
        self._stream: io.BufferedWriter | None = None
        self._tar: wds.TarWriter | None = None
        self._count = 0

    def _partial_path(self) -> Path:
        return self.directory / f"{self.prefix}-{self.first_index + len(self.shards):06d}.tar{PARTIAL_SUFFIX}"

    def _open(self) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        self._stream = self._partial_path().open("wb")
        self._tar = wds.TarWriter(self._stream, user="m2d2m", group="m2d2m", mode=0o644, encoder=False, mtime=0)
        self._count = 0

    def _finish(self) -> None:
        assert self._tar is not None and self._stream is not None
        partial = self._partial_path()
        self._tar.close()  # closes the stream too
        self._stream = self._tar = None
        final = partial.with_name(partial.name.removesuffix(PARTIAL_SUFFIX))
        os.replace(partial, final)
        self.shards.append(ShardInfo(final.name, self._count, final.stat().st_size, sha256_of(final)))

    def write(self, key: str, members: dict[str, bytes]) -> None:
        """Add one sample; ``members`` maps suffixes (``motion.npy``) to encoded bytes."""
        if "." in key or not key:
            raise ValueError(f"sample key {key!r} must be non-empty and contain no dots")
        if self._tar is None:
            self._open()
        self._tar.write({"__key__": key, **members})
        self._count += 1
        if self._count == self.samples_per_shard:
            self._finish()

    def close(self) -> list[ShardInfo]:
        """Complete the last shard and return every shard written."""
        if self._tar is not None:
            self._finish()
        return self.shards

    def abort(self) -> None:
        """Drop the shard being written (complete shards stay; the manifest decides validity)."""
        if self._tar is not None:
            partial = self._partial_path()
            self._tar.close()
            self._stream = self._tar = None
            partial.unlink(missing_ok=True)

    def __enter__(self) -> ShardWriter:
        return self

    def __exit__(self, exc_type, exc, traceback) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def write_json_atomically(path: str | Path, value: Any) -> None:
    """Write JSON under a temporary name, then rename: readers never see half a file."""
    with atomic_path(path) as partial:
        partial.write_text(json.dumps(value, indent=2, sort_keys=True, ensure_ascii=False) + "\n", encoding="utf-8")


def shard_records(shards: list[ShardInfo]) -> list[dict[str, Any]]:
    return [asdict(s) for s in shards]


def iter_tar_samples(path: str | Path) -> Iterator[tuple[str, dict[str, bytes]]]:
    """Samples of one shard as (key, {suffix: bytes}), in file order, grouping consecutive
    members by key as WebDataset does."""
    key, members = None, {}
    with tarfile.open(path, "r") as tar:
        for info in tar:
            if not info.isfile():
                continue
            name = Path(info.name).name
            sample_key, _, suffix = name.partition(".")
            if sample_key != key and key is not None:
                yield key, members
                members = {}
            key = sample_key
            members[suffix] = tar.extractfile(info).read()
    if key is not None:
        yield key, members


SampleCheck = Callable[[str, dict[str, bytes]], list[str]]


def verify_shards(directory: str | Path, shards: list[dict[str, Any]], check_sample: SampleCheck) -> list[str]:
    """Problems found when comparing shards on disk with their manifest records: missing files,
    checksums, sample counts, and whatever ``check_sample`` reports about each sample."""
    directory = Path(directory)
    problems: list[str] = []
    for record in shards:
        path = directory / record["name"]
        if not path.exists():
            problems.append(f"{record['name']}: missing")
            continue
        if sha256_of(path) != record["sha256"]:
            problems.append(f"{record['name']}: sha256 differs from the manifest")
        try:
            count = 0
            for key, members in iter_tar_samples(path):
                count += 1
                problems.extend(f"{record['name']}: {key}: {p}" for p in check_sample(key, members))
        except tarfile.TarError as error:
            problems.append(f"{record['name']}: unreadable tar ({error})")
            continue
        if count != record["samples"]:
            problems.append(f"{record['name']}: {count} samples, manifest says {record['samples']}")
    listed = {r["name"] for r in shards}
    for stray in sorted(directory.glob("*.tar")):
        if stray.name not in listed:
            problems.append(f"{stray.name}: not in the manifest")
    return problems
