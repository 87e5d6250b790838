"""The ``bvh`` corpus: your own motion capture as BVH files and a table of captions
(docs/data.md, "Your own motion capture").

``--raw`` is a folder holding BVH files (in any subfolders) and ``captions.csv``, whose columns
are ``file`` (the BVH's path in the folder), ``caption``, and optionally ``start`` and ``end``
(seconds of the take the caption describes; the whole take when left out) and ``split``
(``train``, ``val`` or ``test``; a stable hash of the take's name decides when left out). The
lines of one file with the same start and end are one motion with several captions. Each take
goes through :func:`take_joints`: forward kinematics, a joint map to the 22 T2M joints
(``--joint-map``: a preset, a YAML file, or by default the preset whose joints the file has),
lengths in metres (``--units``, by default the unit in which the rig stands a person's height:
:meth:`~m2d2m.motion.rigs.joint_map.JointMap.metres_per_unit`)
and the corpus's frame rate. A take that cannot become joints (not a BVH, a joint the map lacks,
no frames, NaN, an unknown unit) is quarantined with its reason, as is a BVH that no caption
names; nothing in the folder is passed over.
"""

from __future__ import annotations

import csv
import hashlib
import re
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from m2d2m.layout import relative_to_project
from m2d2m.motion.files.bvh_reader import BvhError, instants, read_bvh, resample, whole_step
from m2d2m.motion.representation.skeleton import T2M, Skeleton
from m2d2m.motion.rigs.joint_map import JointMap, joint_map_for
from m2d2m.motion.rigs.up_axis import stance
from pipelines.corpora import SPLITS, Corpus, CorpusLayout, Rejected, register_corpus

CAPTIONS = "captions.csv"
_SPLIT_SHARES = (("train", 0.8), ("val", 0.05), ("test", 0.15))  # HumanML3D's proportions


def take_joints(
    path: str | Path,
    skeleton: Skeleton = T2M,
    joint_map: str | None = None,
    units: str | None = None,
    fps: float | None = None,
) -> tuple[np.ndarray, JointMap]:
    """A BVH take as ``skeleton``'s joints (T, J, 3) in metres, standing along +Y (turned so where
    its motion stands along another axis: :func:`~m2d2m.motion.rigs.up_axis.stance`), at the
    skeleton's frame rate: every n-th frame of a take at n times that rate (HumanML3D's rule),
    else read at the rate's instants with rotations slerped, so that bones keep their lengths.
    Returns them and the joint map that made them; ``fps`` is the rate the take was captured at
    where its Frame Time says otherwise. :class:`Rejected` says why a take cannot be read."""
    try:
        clip = read_bvh(path)
        mapping = joint_map_for(clip, joint_map)
        rate = fps or clip.fps
        step = whole_step(rate, skeleton.fps)
        at = None if step else instants(len(clip.values) - mapping.rest_frames, rate, skeleton.fps)
        mapped = mapping.joints(clip, skeleton, at)
        standing = stance(mapped, skeleton)
        scale = mapping.metres_per_unit(clip, units, skeleton, standing)
        joints = standing.upright(mapped) * scale
        joints = resample(joints, rate, skeleton.fps) if step else joints
    except (BvhError, ValueError) as error:  # a YAML map that is not one is a ValueError
        raise Rejected("read", str(error).removeprefix(f"{path}: ")) from error  # the row names the file
    return joints.astype(np.float32), mapping


def stable_split(name: str) -> str:
    """The split a take goes to when its table names none: a hash of its name, so it never moves
    when other takes are added (80 % train, 5 % val, 15 % test)."""
    point = int(hashlib.sha256(name.encode("utf-8")).hexdigest()[:8], 16) / 16**8
    for split, share in _SPLIT_SHARES:
        if point < share:
            return split
        point -= share
    return _SPLIT_SHARES[-1][0]


def _seconds(value: str | None, line: int, column: str) -> float | None:
    if value is None or not value.strip():
        return None
    try:
        seconds = float(value)
    except ValueError:
        raise ValueError(f"{CAPTIONS} line {line}: {column} {value!r} is not a number of seconds") from None
    if not seconds >= 0:
        raise ValueError(f"{CAPTIONS} line {line}: {column} must be 0 or more seconds, got {value}")
    return seconds


def _table(raw: Path) -> Iterable[tuple[int, dict[str, str]]]:
    path = raw / CAPTIONS
    if not path.is_file():
        raise FileNotFoundError(f"{raw}: no {CAPTIONS} (columns file, caption[, start, end][, split])")
    with path.open(encoding="utf-8", newline="") as handle:
        reader = csv.DictReader(handle)
        missing = {"file", "caption"} - set(reader.fieldnames or ())
        if missing:
            raise ValueError(
                f"{path}: no column {', '.join(sorted(missing))} (columns file, caption[, start, end][, split])"
            )
        yield from enumerate(reader, start=2)


def _row_id(file: str, start: float | None, end: float | None) -> str:
    """``<path without .bvh>``, and ``_<start>-<end>ms`` for a span: a shard key (no dots)."""
    stem = re.sub(r"[^A-Za-z0-9_-]", "_", Path(file).with_suffix("").as_posix())
    if start is None and end is None:
        return stem
    return f"{stem}_{round((start or 0) * 1000)}-{'end' if end is None else round(end * 1000)}ms"


def _motion(
    row_id: str,
    split: str | None,
    path: Path,
    start: float | None,
    end: float | None,
    joint_map: str | None,
    units: str | None,
) -> dict[str, Any]:
    """A row of the corpus, its captions still to be added."""
    return {
        "id": row_id,
        "split": split or stable_split(row_id),
        "kind": "joints",
        "path": str(path),
        "start": start,
        "end": end,
        "captions": [],
        "joint_map": joint_map,
        "units": units,
    }


def list_takes(raw: str | Path, joint_map: str | None = None, units: str | None = None) -> list[dict[str, Any]]:
    """One row per motion the table names (a file and a span of it) and per BVH file it names
    nowhere, in split then table order; ValueError for a table that cannot be read."""
    raw = Path(raw).resolve()
    motions: dict[str, dict[str, Any]] = {}
    for line, entry in _table(raw):
        file, caption = (entry.get("file") or "").strip(), (entry.get("caption") or "").strip()
        if not file or not caption:
            raise ValueError(f"{raw / CAPTIONS} line {line}: a file and a caption are needed")
        start, end = _seconds(entry.get("start"), line, "start"), _seconds(entry.get("end"), line, "end")
        if start is not None and end is not None and end <= start:
            raise ValueError(f"{raw / CAPTIONS} line {line}: end {end:g} s is not after start {start:g} s")
        split = (entry.get("split") or "").strip() or None
        if split is not None and split not in SPLITS:
            raise ValueError(f"{raw / CAPTIONS} line {line}: split {split!r} is not one of {', '.join(SPLITS)}")
        row_id = _row_id(file, start, end)
        motion = motions.setdefault(row_id, _motion(row_id, split, raw / file, start, end, joint_map, units))
        if split is not None and split != motion["split"]:
            raise ValueError(f"{raw / CAPTIONS} line {line}: {row_id} is in {motion['split']} on an earlier line")
        motion["captions"].append(caption)
    named = {Path(m["path"]).resolve() for m in motions.values()}
    for path in sorted(raw.rglob("*.bvh")):
        if path.resolve() not in named:
            row_id = _row_id(path.relative_to(raw).as_posix(), None, None)
            motions[row_id] = _motion(row_id, None, path, None, None, joint_map, units)
    rows = list(motions.values())
    return [row for split in SPLITS for row in rows if row["split"] == split]


def read_take(row: dict[str, Any], skeleton: Skeleton) -> np.ndarray:
    """The row's span of its take as the skeleton's joints."""
    if not Path(row["path"]).is_file():
        raise Rejected("read", f"no such BVH file {relative_to_project(row['path'])} (named in {CAPTIONS})")
    joints, _ = take_joints(row["path"], skeleton, row["joint_map"], row["units"])
    return slice_seconds(joints, row["start"], row["end"], skeleton.fps)


def slice_seconds(joints: np.ndarray, start: float | None, end: float | None, fps: float) -> np.ndarray:
    """The frames of ``joints`` from ``start`` to ``end`` seconds (None: the take's start, end)."""
    first = round((start or 0.0) * fps)
    last = len(joints) if end is None else round(end * fps)
    if last > len(joints) or first >= len(joints):
        span = f"{start or 0:g}–{'end' if end is None else f'{end:g}'} s"
        raise Rejected("validate", f"span {span} is past the take's {len(joints) / fps:.2f} s")
    return joints[first:last]


def read_table_captions(row: dict[str, Any]) -> list[dict[str, Any]]:
    """The row's captions, untagged (the pipeline tags them), each covering the whole motion."""
    if not row["captions"]:
        raise Rejected("read", f"no caption in {CAPTIONS} names this file")
    return [{"text": text, "tokens": None, "start": 0.0, "end": 0.0} for text in row["captions"]]


BVH_LAYOUT = CorpusLayout(
    "bvh", list_takes, read_take, read_table_captions, options=("joint_map", "units"), tagged_captions=False
)
register_corpus(Corpus("bvh", T2M, (40, 200), BVH_LAYOUT))
