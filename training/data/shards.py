"""What a DataModule reads of a directory of shards without streaming it: each clip's ``meta.json``
and frame count from the tar headers, a token set's manifest and arrays, and the train and val
splits training needs (docs/data.md, the processed dataset)."""

from __future__ import annotations

import io
import json
import tarfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from m2d2m.layout import MANIFEST, TOKENS_KIND, read_manifest


def clip_metas(urls: list[str]) -> Iterator[dict[str, Any]]:
    """The ``meta.json`` of every clip in local shards, in order, from those small members alone:
    the tar headers let the motion or token arrays be skipped instead of read."""
    for url in urls:
        with tarfile.open(url) as archive:
            for member in archive:
                if member.name.endswith(".meta.json"):
                    yield json.loads(archive.extractfile(member).read())


def clip_lengths(urls: list[str]) -> list[int]:
    """The frame count of every clip in local shards."""
    return [meta["frames"] for meta in clip_metas(urls)]


def require_training_splits(urls: dict[str, list[str]], directory: Path) -> dict[str, list[str]]:
    """``urls`` when both the train and the val split have shards: training samples the one and
    validates (and keeps its checkpoints) on the other, so a dataset lacking either is refused in
    one line before anything runs, not with a traceback at the first validation."""
    empty = [split for split in ("train", "val") if not urls.get(split)]
    if empty:
        raise ValueError(
            f"{directory}: no {' and no '.join(empty)} motions, and training needs both; rebuild the dataset "
            "with motions in each split (the bvh corpus: name some in the split column of captions.csv)"
        )
    return urls


def read_token_manifest(tokens_dir: Path) -> dict[str, Any]:
    """A token set's manifest, refusing a missing one or a directory that is not a token set (a
    processed dataset, say), with what to run instead."""
    path = tokens_dir / MANIFEST
    if not path.exists():
        raise FileNotFoundError(f"{path}: missing; no token set here (make one with `m2d2m tokenize` or `make tokens`)")
    manifest = read_manifest(tokens_dir)
    if manifest.get("kind") != TOKENS_KIND:
        raise ValueError(
            f"{path}: kind {manifest.get('kind')!r}, not a token set ({TOKENS_KIND!r}); pass the "
            "directory `m2d2m tokenize` wrote (data/<name>/tokens/<vq-run>/)"
        )
    return manifest


def token_arrays(urls: list[str]) -> dict[str, np.ndarray]:
    """Every clip's ``tokens.npy`` in local token shards, by key."""
    arrays = {}
    for url in urls:
        with tarfile.open(url) as archive:
            for member in archive:
                if member.name.endswith(".tokens.npy"):
                    key = member.name[: -len(".tokens.npy")]
                    arrays[key] = np.load(io.BytesIO(archive.extractfile(member).read()), allow_pickle=False)
    return arrays
