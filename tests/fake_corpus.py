"""A corpus layout registered from outside the framework as a plugin
(``M2D2M_PLUGINS=tests.fake_corpus``): one ``<split>/<id>.npz`` per clip holding its joints and
its caption lines, nothing of HumanML3D's folders and split files. If ``m2d2m data`` knew only
HumanML3D's layout, this corpus could not become shards."""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from m2d2m.motion.representation.skeleton import T2M, Skeleton
from pipelines.corpora import SPLITS, Corpus, CorpusLayout, Rejected, parse_caption_line, register_corpus


def list_clips(raw: str | Path) -> list[dict[str, Any]]:
    """Every clip of every split folder, in split then name order."""
    raw = Path(raw).resolve()
    if not any((raw / split).is_dir() for split in SPLITS):
        raise FileNotFoundError(f"{raw}: no train/, val/ or test/ folder of .npz clips")
    return [
        {"id": path.stem, "split": split, "kind": "joints", "path": str(path)}
        for split in SPLITS
        for path in sorted((raw / split).glob("*.npz"))
    ]


def _read(row: dict[str, Any]) -> dict[str, np.ndarray]:
    try:
        with np.load(row["path"], allow_pickle=False) as archive:
            return {name: archive[name] for name in archive.files}
    except (OSError, ValueError, zipfile.BadZipFile) as error:
        raise Rejected("read", f"unreadable .npz ({error})") from error


def read_joints(row: dict[str, Any], skeleton: Skeleton) -> np.ndarray:
    joints = _read(row)["joints"]
    if joints.ndim != 3 or joints.shape[1:] != (skeleton.num_joints, 3):
        raise Rejected("validate", f"wrong shape {joints.shape}")
    return joints.astype(np.float32)


def read_captions(row: dict[str, Any]) -> list[dict[str, Any]]:
    return [parse_caption_line(str(line)) for line in _read(row)["captions"]]


NPZ_CORPUS = register_corpus(
    Corpus("npz-clips", T2M, (40, 200), CorpusLayout("npz", list_clips, read_joints, read_captions))
)
