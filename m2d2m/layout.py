"""The on-disk layout of a processed dataset (docs/data.md), shared by the pipelines
that write it and the training that reads it, which must not import each other; and how a file
records where another one is, so that a project can move (docs/reliability.md, "A project can move")."""

from __future__ import annotations

import json
import os
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
MODEL_FILE = "model.pt"  # a denoiser run's self-contained checkpoint (m2d2m.generators.m2d2m.checkpoint)
PROJECT_FOLDERS = ("data", "runs")  # a project's folders that records point into


def relative_to_project(path: str | Path) -> str:
    """``path`` as a file records it: relative to the project, the folder every verb runs in, when
    it lies inside, so that a copy of the project at another path finds its own files rather than
    the original's; absolute when it lies elsewhere (a corpus on shared storage)."""
    project, absolute = Path.cwd(), Path(os.path.abspath(path))
    for inside, root in ((absolute, project), (absolute.resolve(), project.resolve())):  # as given, then real
        if inside.is_relative_to(root):
            return inside.relative_to(root).as_posix()
    return str(absolute.resolve())


def project_of(path: str | Path) -> Path | None:
    """The project a file lies in: the folder holding the ``runs/`` or ``data/`` above it (None
    for a file in neither, a model file copied out of its project)."""
    return next((folder.parent for folder in Path(path).absolute().parents if folder.name in PROJECT_FOLDERS), None)


def recorded_path(recorded: str | Path, by: str | Path) -> Path:
    """A path the file ``by`` recorded, to open. A relative one (what :func:`relative_to_project`
    records for a file inside the project) is taken from the project ``by`` lies in (the working
    directory when it lies in none), so a model file given from another folder, or a project moved
    since, finds its own dataset; an absolute one (a file that lay outside the project) as it stands."""
    path, project = Path(recorded), project_of(by)
    if path.is_absolute():
        return path
    base = Path() if project is None or project.resolve() == Path.cwd().resolve() else project
    return base / path


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
