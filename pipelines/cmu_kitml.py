"""``cmu-kitml``: CMU's motion capture with KIT-ML's crowd-sourced captions (docs/data.md, "CMU
with KIT-ML's captions").

The KIT Motion-Language Dataset (Plappert, Mandery and Asfour 2016, "The KIT Motion-Language
Dataset", Big Data 4(4), doi:10.1089/big.2016.0028) captions motions of KIT's whole-body
database; 790 of the 2,883 that github.com/Mathux/TMR's copy keeps are CMU's takes.
``--annotations`` is that copy's ``annotations.json`` (``datasets/annotations/kitml/``: ids →
``{path, duration, annotations: [{text, start, end}]}``), KIT-ML's split files in ``splits/``
beside it. ``--raw`` is a clone of github.com/una-dinosauria/cmu-mocap (cgspeed's
MotionBuilder-friendly BVH, a take found by its name ``<subject>_<take>.bvh`` in any subfolder)
or any folder of CMU's BVH.

Each CMU take is read by :func:`pipelines.bvh_corpus.take_joints` in CMU's units, its T-pose
frame left out by the joint map, at the rate it was captured: the files all say 120 fps, yet some
takes were captured at 60, so the rate is recovered from KIT-ML's duration (its frames over the
duration, 120 or 60 within a frame) and a take that lines up with neither is quarantined with
its numbers. Every entry of the file is a sample or a quarantine line: KIT's own takes
(``KIT/``, ``EKUT/``: motion this corpus does not read) and takes without their BVH are
quarantined, one line each, and a mirror entry ``M<id>`` follows its original (the pipeline
makes ``M<id>`` from a sample; a quarantined original's line stands for both). CMU's own
one-line description of a take (``cmu-mocap-index-text.txt`` in the clone) becomes a second
caption where it describes the motion (:func:`cmu_description`). A take outside HumanML3D's
frame bounds is quarantined by them, not cut: KIT-ML's caption tells the whole take.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np

from m2d2m.layout import relative_to_project
from m2d2m.motion.files.bvh_reader import BvhError, read_bvh_header
from m2d2m.motion.representation.skeleton import T2M, Skeleton
from m2d2m.motion.rigs.joint_map import joint_map_for
from pipelines.bvh_corpus import stable_split, take_joints
from pipelines.corpora import SPLITS, Corpus, CorpusLayout, Rejected, register_corpus

ANNOTATIONS = "annotations.json"
DEFAULT_ANNOTATIONS = Path("kitml") / ANNOTATIONS  # where, under --raw, it is looked for when not given
TMR_ANNOTATIONS = Path("datasets") / "annotations" / "kitml" / ANNOTATIONS  # its place in a TMR clone
INDEX_TEXT = "cmu-mocap-index-text.txt"
CMU, UNITS = "CMU", "cmu"
CAPTURE_RATES = (120, 60)  # fps CMU captured at; cgspeed's files say 120 for all
LINE_UP_FRAMES = 1.0  # how far a take's frames may be from its rate times KIT-ML's duration
FRAME_BOUNDS = (40, 200)  # HumanML3D's: 2 s ≤ a motion < 10 s at 20 fps
REPOSITORIES = "github.com/Mathux/TMR (datasets/annotations/kitml), github.com/una-dinosauria/cmu-mocap"

ABOUT = {
    "licence": (
        "KIT-ML's captions: no licence stated; the KIT Motion-Language Dataset "
        "(motion-annotation.humanoids.kit.edu) asks to be cited. Mathux/TMR's annotations.json and splits: "
        "MIT (© 2023 Mathis Petrovich), shipped with the KIT-ML authors' agreement. CMU's motion capture: free "
        "for research and commercial use, not to be resold as a database. Ask KIT (H2T) before passing these "
        "shards on."
    ),
    "attribution": (
        "The data used in this project was obtained from mocap.cs.cmu.edu. The database was created with "
        "funding from NSF EIA-0196217. Captions: Plappert, Mandery and Asfour 2016, The KIT Motion-Language "
        "Dataset, Big Data 4(4):236-252, doi:10.1089/big.2016.0028, as distributed by github.com/Mathux/TMR. "
        "BVH: B. Hahne's (cgspeed) MotionBuilder-friendly conversion, github.com/una-dinosauria/cmu-mocap. "
        "Changed by m2d2m: each take at its recovered capture rate resampled to 20 fps, its T-pose frame left "
        "out, mapped to 22 joints, lengths in metres."
    ),
    "splits": (
        "KIT-ML's own (TMR's datasets/annotations/kitml/splits/{train,val,test}.txt; of the 790 CMU takes "
        "636 train, 33 val, 121 test); an id they do not list goes where a hash of it points (80/5/15 %)"
    ),
    "captions": (
        "KIT-ML's crowd-sourced sentences, untagged (the pipeline tags them), and CMU's own one-line "
        "description of the take (cmu-mocap-index-text.txt) where it describes the motion"
    ),
    "frame_rate": (
        "each take's capture rate recovered from KIT-ML's duration: its frames (the T-pose left out) over "
        "the duration, 120 or 60 fps within a frame, else quarantined; resampled to 20 fps"
    ),
    "left_out": (
        "KIT's own takes (KIT/, EKUT/; 2,093 of KIT-ML's 2,883 motions): one quarantine line each; "
        "by the frame bounds, takes over 10 s (349 of the 790 CMU takes, 2.1 of their 2.88 h; a caption tells "
        "the whole take, so none is cut) and of 2 s or less (57)"
    ),
}

# CMU's index lines that are bookkeeping, not a description of the motion (after _words).
_BOOKKEEPING = re.compile(
    r"unknown|clean(ed)?|bad amc|.*\.amc|.*calibration|.*motor ?cycle( pose)?|range of motion|t-? ?pose"
    r"|lost marker|no movie|movie and trial dont match|[\d\s.]+( ?lbs?)?",
    re.IGNORECASE,
)
_TAGS = (
    re.compile(r"\s*\((2 )?subjects - subject [ab]\)", re.IGNORECASE),  # who of a pair: kept in the take's name
    re.compile(r"\s+cleaned ?grs", re.IGNORECASE),  # a clean-up note of subject 78
)


def _words(label: str) -> str:
    """A label as words: ``RightWideTurn`` → ``right wide turn``, ``Left_Lunges001`` → ``left lunges``."""
    for tag in _TAGS:
        label = tag.sub("", label)
    label = re.sub(r"(?<=[A-Za-z])_?0\d{1,2}$", "", label.strip())  # a take's number: Cartwheels001
    label = re.sub(r"(?<=[a-z])(?=[A-Z])", " ", label).replace("_", " ")
    words = [word if len(word) > 1 and word.isupper() else word.lower() for word in label.split()]
    return " ".join(words)


def cmu_description(line: str | None) -> str | None:
    """CMU's description of a take as a caption, or None where it says nothing of the motion
    ("Unknown", "clean", "bad AMC", a calibration or range-of-motion take, a suitcase's weight)."""
    if not line:
        return None
    words = _words(line)
    if not re.search(r"[a-z]{2}", words, re.IGNORECASE) or _BOOKKEEPING.fullmatch(words):
        return None
    return words


def read_index_text(path: Path) -> dict[str, str]:
    """CMU's description of each take (``<subject>_<take>\\t<description>`` lines), by take name."""
    text = path.read_bytes().decode("utf-8", errors="replace")
    lines = (re.match(r"(\d+_\d+)\t(.*)$", line.rstrip("\r")) for line in text.splitlines())
    return {found[1]: found[2].strip() for found in lines if found}


def capture_rate(frames: int, duration: float) -> int | None:
    """The rate of :data:`CAPTURE_RATES` at which ``frames`` last ``duration`` seconds within
    :data:`LINE_UP_FRAMES`, or None."""
    for rate in CAPTURE_RATES:
        if abs(frames - rate * duration) <= LINE_UP_FRAMES:
            return rate
    return None


def _off_rate(frames: int, duration: float) -> str:
    lasts = ", ".join(f"at {rate} fps they last {frames / rate:.3g} s" for rate in CAPTURE_RATES)
    return (
        f"does not line up: {frames} frames in KIT-ML's {duration:g} s is {frames / duration:.1f} fps, "
        f"more than a frame from {' or '.join(map(str, CAPTURE_RATES))} fps ({lasts})"
    )


def annotations_file(raw: Path, annotations: str | None) -> Path:
    """KIT-ML's ``annotations.json``: ``--annotations`` (the file, its folder or a TMR clone), else
    ``<raw>/kitml/annotations.json``; FileNotFoundError in one line saying how to pass it."""
    if annotations is None:
        path = raw / DEFAULT_ANNOTATIONS
        if path.is_file():
            return path
        raise FileNotFoundError(
            f"no KIT-ML annotations: pass --annotations <a clone of github.com/Mathux/TMR>/{TMR_ANNOTATIONS.as_posix()} "
            f"(or put it at {relative_to_project(path)}, its splits/ beside it)"
        )
    given = Path(annotations)
    for path in (given, given / ANNOTATIONS, given / TMR_ANNOTATIONS):
        if path.is_file():
            return path
    raise FileNotFoundError(
        f"--annotations: {annotations} is no {ANNOTATIONS}, nor a folder or TMR clone holding one "
        f"({TMR_ANNOTATIONS.as_posix()})"
    )


def _entries(path: Path) -> dict[str, Any]:
    try:
        entries = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as error:
        raise ValueError(f"{path}: not KIT-ML's annotations.json ({error})") from None
    if not isinstance(entries, dict):
        raise ValueError(f"{path}: not KIT-ML's annotations.json (an object of ids is expected)")
    return entries


def kitml_splits(annotations: Path) -> dict[str, str]:
    """The split of each id in KIT-ML's split files (``splits/{train,val,test}.txt`` beside
    ``annotations.json``, as in TMR); FileNotFoundError in one line when any is missing."""
    folder = annotations.parent / "splits"
    missing = [f"{split}.txt" for split in SPLITS if not (folder / f"{split}.txt").is_file()]
    if missing:
        raise FileNotFoundError(
            f"{folder}: no KIT-ML split file(s) {', '.join(missing)} (TMR ships them in "
            f"datasets/annotations/kitml/splits/, beside {ANNOTATIONS})"
        )
    return {
        line.strip(): split
        for split in SPLITS
        for line in (folder / f"{split}.txt").read_text(encoding="utf-8").splitlines()
        if line.strip()
    }


def _captions(entry: dict[str, Any]) -> list[dict[str, Any]]:
    """An entry's captions: text, and its span, 0–0 for the whole take (HumanML3D's convention)."""
    duration = float(entry["duration"])
    captions = []
    for annotation in entry["annotations"]:
        text = str(annotation["text"]).strip()
        if not text:
            continue
        start, end = float(annotation.get("start", 0.0)), float(annotation.get("end", duration))
        whole = start <= 0.5 / T2M.fps and end >= duration - 0.5 / T2M.fps
        captions.append({"text": text, "start": 0.0 if whole else start, "end": 0.0 if whole else end})
    return captions


def _cmu_row(row: dict[str, Any], entry: dict[str, Any], raw: Path, takes: dict[str, Path]) -> None:
    """Give a CMU entry's row its BVH and capture rate, or the reason it has none (Rejected)."""
    source = entry["path"]
    take = Path(source).name.removesuffix("_poses")
    path = takes.get(take)
    if path is None:
        raise Rejected("read", f"no BVH: no {take}.bvh under {relative_to_project(raw)} (KIT-ML's {source})")
    row |= {"take": take, "path": str(path)}
    try:
        header = read_bvh_header(path)
        frames = header.frames - joint_map_for(header).rest_frames
    except (BvhError, ValueError) as error:
        raise Rejected("read", str(error).removeprefix(f"{path}: ")) from error
    rate = capture_rate(frames, row["duration"])
    if rate is None:
        raise Rejected("read", _off_rate(frames, row["duration"]))
    row["fps"] = rate


def _row(
    entry_id: str, entry: Any, splits: dict[str, str], raw: Path, takes: dict[str, Path], index: dict[str, str]
) -> dict[str, Any]:
    row: dict[str, Any] = {"id": entry_id, "split": splits.get(entry_id) or stable_split(entry_id), "kind": "joints"}
    row |= {"path": None, "fps": None, "captions": []}
    try:
        try:
            source, duration = str(entry["path"]), float(entry["duration"])
            row |= {"source": source, "duration": duration, "captions": _captions(entry)}
        except (KeyError, TypeError, ValueError) as error:
            raise Rejected("read", f"bad entry: not {{path, duration, annotations: [{{text, ...}}]}} ({error!r})")
        if source.split("/")[0] != CMU:
            raise Rejected("read", f"not CMU's motion: {source} is KIT's own (its mirror M{entry_id} with it)")
        if not duration > 0:
            raise Rejected("read", f"bad entry: duration {duration:g} s")
        if not row["captions"]:
            raise Rejected("read", "no caption: every text of the entry is empty")
        _cmu_row(row, entry, raw, takes)
    except Rejected as rejected:
        return row | {"stage": rejected.stage, "reason": rejected.reason}
    description = cmu_description(index.get(row["take"]))
    if description and description.lower() not in {c["text"].lower().rstrip(".") for c in row["captions"]}:
        row["captions"].append({"text": description, "start": 0.0, "end": 0.0})
    return row


def list_cmu_kitml(raw: str | Path, annotations: str | None = None) -> list[dict[str, Any]]:
    """One row per entry of KIT-ML's annotations.json but the mirrors of the entries in it, in
    split then file order: a CMU take to read, or the reason it cannot be (``reason``)."""
    raw = Path(raw).resolve()
    if not raw.is_dir():
        raise FileNotFoundError(f"{raw}: no such folder; --raw is a clone of github.com/una-dinosauria/cmu-mocap")
    path = annotations_file(raw, annotations)
    entries, splits = _entries(path), kitml_splits(path)
    takes: dict[str, Path] = {}
    for bvh in sorted(raw.rglob("*.bvh")):
        takes.setdefault(bvh.stem, bvh)
    index_files = sorted(raw.rglob(INDEX_TEXT))
    index = read_index_text(index_files[0]) if index_files else {}
    rows = []
    for entry_id, entry in entries.items():
        if entry_id.startswith("M") and entry_id[1:] in entries:
            continue  # the pipeline makes this mirror from its original
        if entry_id.startswith("M"):
            row = {"id": entry_id, "split": splits.get(entry_id) or stable_split(entry_id), "kind": "joints"}
            reason = f"a mirror without its original: {entry_id[1:]} is not in {ANNOTATIONS}"
            rows.append(row | {"path": None, "captions": [], "stage": "read", "reason": reason})
            continue
        rows.append(_row(entry_id, entry, splits, raw, takes, index))
    return [row for split in SPLITS for row in rows if row["split"] == split]


def read_take(row: dict[str, Any], skeleton: Skeleton) -> np.ndarray:
    """The row's take as the skeleton's joints, read at its recovered capture rate."""
    if row.get("reason"):
        raise Rejected(row["stage"], row["reason"])
    if not Path(row["path"]).is_file():
        raise Rejected("read", f"no BVH: {relative_to_project(row['path'])} is gone (listed, then removed?)")
    joints, _ = take_joints(row["path"], skeleton, None, UNITS, fps=row["fps"])
    return joints


def read_take_captions(row: dict[str, Any]) -> list[dict[str, Any]]:
    """The row's captions, untagged: the pipeline tags them."""
    if not row["captions"]:
        raise Rejected("read", row.get("reason") or "no caption")
    return [{**caption, "tokens": None} for caption in row["captions"]]


CMU_KITML_LAYOUT = CorpusLayout(
    "cmu-kitml",
    list_cmu_kitml,
    read_take,
    read_take_captions,
    options=("annotations",),
    tagged_captions=False,
    about=ABOUT,
)
register_corpus(Corpus("cmu-kitml", T2M, FRAME_BOUNDS, CMU_KITML_LAYOUT))
