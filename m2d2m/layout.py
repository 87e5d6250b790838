"""The on-disk layout of a processed dataset (docs/data.md), shared by the pipelines
that write it and the training that reads it, which must not import each other."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from m2d2m.integrity import verified_paths

MANIFEST = "manifest.json"
QUARANTINE = "quarantine.jsonl"
STATS = "stats.npz"
SHARDS = "shards"
NLP = "nlp"
TOKENS = "tokens"
TOKENS_KIND = "tokens"  # the manifest "kind" of a token set
VQ_FILE = "vq.pt"  # the plain VQ-VAE model file, in a run directory and beside its tokens
MODEL_FILE = "model.pt"  # a denoiser run's self-contained checkpoint (m2d2m.generators.m2d2m_checkpoint)


def read_manifest(directory: str | Path) -> dict[str, Any]:
    """The manifest of a dataset (or token set); its absence means the directory is incomplete."""
    path = Path(directory) / MANIFEST
    if not path.exists():
        raise FileNotFoundError(f"{path}: missing; the dataset is incomplete or was never built (run `m2d2m data`)")
    return json.loads(path.read_text(encoding="utf-8"))


def shard_urls(directory: str | Path, split: str) -> list[str]:
    """Absolute paths of a split's shards, from the manifest (the only trusted listing), each
    checked against its record first (:func:`m2d2m.integrity.verified_paths`)."""
    directory = Path(directory).resolve()
    return verified_paths(
        directory / SHARDS,
        read_manifest(directory)["shards"][split],
        f"the dataset changed after it was built (`m2d2m data --check {directory}` lists every "
        "problem; `m2d2m data --force` rebuilds it)",
    )


def token_shard_urls(directory: str | Path, split: str) -> list[str]:
    """Absolute paths of a split's token shards, which sit in the token set's directory itself,
    each checked against its record first."""
    directory = Path(directory).resolve()
    return verified_paths(
        directory,
        read_manifest(directory)["shards"][split],
        f"the token set changed after it was made (`m2d2m tokenize --check {directory}` lists "
        "every problem; `m2d2m tokenize` remakes it)",
    )
