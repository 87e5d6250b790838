"""The corpora ``m2d2m data`` reads, by name (:class:`Corpus`: a skeleton, frame bounds and a
:class:`CorpusLayout`), the readers of HumanML3D's layout (HumanML3D, KIT-ML, the synthetic
corpus), and the validation every input passes before it becomes a sample.

A corpus in HumanML3D's layout holds ``joints/<id>.npy`` (T, J, 3) or ``new_joint_vecs/<id>.npy``
(T, D), ``texts/<id>.txt`` and the split files ``train.txt``, ``val.txt``, ``test.txt``. Another
layout is a plugin's :class:`CorpusLayout` registered with :func:`register_corpus`
(docs/architecture.md, "How to add a corpus"). Every problem with an input is raised as
:class:`Rejected` with the stage and a reason a person can act on; the pipeline turns it into a
line of ``quarantine.jsonl``, so nothing is dropped silently.
"""

from __future__ import annotations

import importlib
import math
import zipfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from m2d2m.motion.representation.skeleton import KIT, T2M, Skeleton

SPLITS = ("train", "val", "test")


class Rejected(Exception):
    """An input that cannot become a sample: where it failed and why."""

    def __init__(self, stage: str, reason: str) -> None:
        super().__init__(f"{stage}: {reason}")
        self.stage = stage
        self.reason = reason


@dataclass(frozen=True)
class FrameBounds:
    minimum: int
    maximum: int  # exclusive

    def check(self, frames: int) -> None:
        if frames < self.minimum:
            raise Rejected("validate", f"too few frames: {frames} < {self.minimum}")
        if frames >= self.maximum:
            raise Rejected("validate", f"too many frames: {frames} >= {self.maximum}")


def list_corpus(raw: str | Path) -> list[dict[str, Any]]:
    """One row per id of the split files, in split then file order: the id, its split, where
    its motion and text should be, and whether the motion is raw joints or processed features.

    An id with no motion file keeps ``motion_path = None``; validation rejects it.
    """
    raw = Path(raw).resolve()
    missing = [f"{s}.txt" for s in SPLITS if not (raw / f"{s}.txt").exists()]
    if missing:
        raise FileNotFoundError(f"{raw}: missing split file(s) {', '.join(missing)}")
    rows: list[dict[str, Any]] = []
    seen: set[str] = set()
    for split in SPLITS:
        for line in (raw / f"{split}.txt").read_text(encoding="utf-8").splitlines():
            motion_id = line.strip()
            if not motion_id or motion_id in seen:
                continue
            seen.add(motion_id)
            rows.append(
                {
                    "id": motion_id,
                    "split": split,
                    **_motion_location(raw, motion_id),
                    "text_path": str(raw / "texts" / f"{motion_id}.txt"),
                }
            )
    return rows


def _motion_location(raw: Path, motion_id: str) -> dict[str, Any]:
    for folder, kind in (("joints", "joints"), ("new_joint_vecs", "features")):
        path = raw / folder / f"{motion_id}.npy"
        if path.exists():
            return {"motion_path": str(path), "kind": kind}
    return {"motion_path": None, "kind": None}


def corpus_ships_mirrors(rows: list[dict[str, Any]]) -> bool:
    """HumanML3D's releases list each mirror ``M<id>`` beside its original in the split files."""
    ids = {row["id"] for row in rows}
    return any(i.startswith("M") and i[1:] in ids for i in ids)


def load_motion(row: dict[str, Any], skeleton: Skeleton) -> np.ndarray:
    """The motion array of a row, checked for readability, dtype, shape and finiteness."""
    if row["motion_path"] is None:
        raise Rejected("read", "no motion file (listed in a split file, absent from joints/ and new_joint_vecs/)")
    try:
        array = np.load(row["motion_path"], allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        raise Rejected("read", f"unreadable or truncated .npy ({error})") from error
    if not np.issubdtype(array.dtype, np.floating):
        raise Rejected("validate", f"wrong dtype {array.dtype}, expected float")
    expected = (skeleton.num_joints, 3) if row["kind"] == "joints" else (skeleton.feature_dim,)
    if array.ndim != len(expected) + 1 or array.shape[1:] != expected:
        raise Rejected("validate", f"wrong shape {array.shape}, expected (T, {', '.join(map(str, expected))})")
    if not np.isfinite(array).all():
        raise Rejected("validate", "NaN or Inf values")
    return array.astype(np.float32)


def _seconds(text: str) -> float:
    """A start/end field; HumanML3D's loaders read NaN as 0 (whole clip)."""
    value = float(text)
    return 0.0 if math.isnan(value) else value


def parse_caption_line(line: str) -> dict[str, Any]:
    """``caption#word/POS ...#start#end`` → {text, tokens, start, end}."""
    fields = line.split("#")
    if len(fields) != 4:
        raise ValueError(f"expected 4 '#'-separated fields, got {len(fields)}: {line!r}")
    text, tokens, start, end = fields
    if not text.strip():
        raise ValueError(f"empty caption: {line!r}")
    try:
        start_s, end_s = _seconds(start), _seconds(end)
    except ValueError as error:
        raise ValueError(f"start/end are not numbers: {line!r}") from error
    return {"text": text.strip(), "tokens": tokens.split(), "start": start_s, "end": end_s}


def load_captions(row: dict[str, Any]) -> list[dict[str, Any]]:
    """Every caption of a row's text file; any unreadable or malformed line rejects the input."""
    path = Path(row["text_path"])
    if not path.exists():
        raise Rejected("read", "no text file")
    try:
        content = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as error:
        raise Rejected("validate", f"text is not UTF-8 ({error.reason} at byte {error.start})") from error
    lines = [line for line in content.splitlines() if line.strip()]
    if not lines:
        raise Rejected("validate", "empty text")
    captions = []
    for number, line in enumerate(lines, start=1):
        try:
            captions.append(parse_caption_line(line))
        except ValueError as error:
            raise Rejected("validate", f"caption line {number}: {error}") from error
    return captions


def never_mirrored(rows: list[dict[str, Any]]) -> bool:
    """A layout whose corpora never ship mirrors: the pipeline makes them."""
    return False


@dataclass(frozen=True)
class CorpusLayout:
    """How a corpus on disk becomes inputs. ``list_rows(raw, **options)`` gives one JSON-able row
    per input, in split then file order, each with ``id``, ``split`` (one of :data:`SPLITS`) and
    ``kind`` (``joints``: (T, J, 3) positions in metres, or ``features``: (T, D)), and whatever the
    readers need; rows travel to the Ray tasks as JSON. ``options`` names the keyword arguments
    ``list_rows`` takes beyond ``raw`` (``m2d2m data --bvh``, ``--joint-map``, ``--units``).
    ``read_motion(row, skeleton)`` and ``read_captions(row)`` (dicts of text, tokens as
    ``word/POS``, start and end seconds) raise :class:`Rejected` for an input that cannot become a
    sample. ``tagged_captions``: whether the captions come with their tags; where they do not,
    their tokens are ``None`` and the pipeline tags them. ``ships_mirrors(rows)``: whether the
    corpus lists its own mirrors, so the pipeline makes none. ``about``: what a user of the
    shards must know of the corpus (``licence``, ``attribution``, how ``splits`` are made...),
    recorded in the manifest under ``corpus``; ``m2d2m data`` prints its licence."""

    name: str
    list_rows: Callable[..., list[dict[str, Any]]]
    read_motion: Callable[[dict[str, Any], Skeleton], np.ndarray]
    read_captions: Callable[[dict[str, Any]], list[dict[str, Any]]]
    ships_mirrors: Callable[[list[dict[str, Any]]], bool] = never_mirrored
    options: tuple[str, ...] = ()
    tagged_captions: bool = True
    about: Mapping[str, str] = field(default_factory=dict)


HUMANML3D_LAYOUT = CorpusLayout("humanml3d", list_corpus, load_motion, load_captions, corpus_ships_mirrors)


@dataclass(frozen=True)
class Corpus:
    """A dataset ``m2d2m data --dataset NAME`` builds: its skeleton, the feature frames a sample
    may have (``minimum ≤ T < maximum``, overridable by ``--min-frames``/``--max-frames``) and its layout."""

    name: str
    skeleton: Skeleton
    frame_bounds: tuple[int, int]
    layout: CorpusLayout = HUMANML3D_LAYOUT


_CORPORA: dict[str, Corpus] = {}
# Layouts of this package that live in modules of their own and register when imported.
_BUILT_IN_MODULES = (
    "pipelines.bvh_corpus",
    "pipelines.humanml3d_public",
    "pipelines.bandai_namco",
    "pipelines.cmu_kitml",
)


def register_corpus(corpus: Corpus) -> Corpus:
    """Add (or replace) a corpus; a plugin module calls this when it is imported."""
    _CORPORA[corpus.name] = corpus
    return corpus


def corpora() -> dict[str, Corpus]:
    """Every registered corpus, by name."""
    for module in _BUILT_IN_MODULES:
        importlib.import_module(module)
    return dict(_CORPORA)


def corpus(name: str) -> Corpus:
    """The corpus ``name``, or ValueError listing those there are."""
    if name not in corpora():
        raise ValueError(f"unknown dataset {name!r}; choose one of {', '.join(_CORPORA)}")
    return _CORPORA[name]


# HumanML3D's loaders keep 40 ≤ T < 200 feature frames; KIT-ML's keep 24 ≤ T < 200.
register_corpus(Corpus("synthetic", T2M, (40, 200)))
register_corpus(Corpus("humanml3d", T2M, (40, 200)))
register_corpus(Corpus("kit", KIT, (24, 200)))
