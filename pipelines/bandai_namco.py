"""``bandai-namco``: the Bandai Namco Research Motion Dataset (Kobayashi et al. 2023, "Motion
Capture Dataset for Practical Use of AI-based Motion Editing and Stylization", arXiv:2306.08861;
github.com/BandaiNamcoResearchInc/Bandai-Namco-Research-Motiondataset, CC BY-NC 4.0) as a corpus
(docs/data.md, "The Bandai Namco corpus").

``--raw`` is a clone of that repository, or one of its two dataset folders
(``Bandai-Namco-Research-Motiondataset-{1,2}``, each ``data/dataset-N_<content>_<style>_<NNN>.bvh``
with a ``.json`` of its content and style indices into ``cfg/content_label.txt`` and
``cfg/style_label.txt``); ``--subset dataset-1`` or ``dataset-2`` reads one of the two. Each take
is read by :func:`pipelines.bvh_corpus.take_joints` through the ``bandai-namco`` joint map, in
centimetres, at 20 fps from its 30, its motion standing on a Y-up floor. Its captions are written
from its labels (:mod:`pipelines.bandai_namco_captions`), untagged; its split is a hash of its name
(:func:`pipelines.bvh_corpus.stable_split`: 80/5/15 %).

Frame bounds, 24 ≤ T < 200 feature frames (1.2–10 s): the upper is HumanML3D's; the lower is
KIT-ML's, because a third of dataset-2's raise-up takes last 1.2–2 s (HumanML3D's 40 would drop
471 complete takes; 24 drops 24, of 0.6–1.2 s). Leading and trailing stillness beyond one second
(no joint faster than 0.15 m/s) is left out: dataset-1's dance opens with 8.8 s of standing.
A take longer than the upper bound (36 of them: walks, dataset-1's dance, repeated kicks, sword
slashes, two waves goodbye; all repeat a cycle, so each stretch shows what the labels say) is cut into the
fewest consecutive pieces of equal length within it, each a motion with the take's captions and
the take's split. Every take that cannot be read is one quarantine line: a JSON without its BVH
(as dataset-1's ``dance-long`` where a clone lacks its BVH), a BVH without its JSON, a label index out of
range or without captions, a JSON that says otherwise than its file name.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from m2d2m.layout import relative_to_project
from m2d2m.motion.files.bvh_reader import BvhError, instants, read_bvh_header
from m2d2m.motion.representation.skeleton import T2M, Skeleton
from pipelines.bandai_namco_captions import captions_for
from pipelines.bvh_corpus import stable_split, take_joints
from pipelines.corpora import SPLITS, Corpus, CorpusLayout, Rejected, register_corpus

DATASETS = ("dataset-1", "dataset-2")
FRAME_BOUNDS = (24, 200)
JOINT_MAP, UNITS = "bandai-namco", "cm"
STILL_SPEED = 0.15  # m/s: a frame in which no joint moves faster is still
STILL_KEPT = 20  # frames (1 s at 20 fps) of stillness kept at either end of a take
REPOSITORY = "github.com/BandaiNamcoResearchInc/Bandai-Namco-Research-Motiondataset"

ABOUT = {
    "licence": "CC BY-NC 4.0 (creativecommons.org/licenses/by-nc/4.0): non-commercial use only",
    "attribution": (
        "Bandai Namco Research Motion Dataset, © 2022 Bandai Namco Research Inc., CC BY-NC 4.0, "
        f"{REPOSITORY}; Kobayashi, Liao, Inoue, Yojima and Takahashi 2023, Motion Capture Dataset for "
        "Practical Use of AI-based Motion Editing and Stylization, arXiv:2306.08861. Changed by m2d2m: "
        "resampled to 20 fps, mapped to 22 joints, still ends trimmed, long takes cut, captions written "
        "from the content and style labels."
    ),
    "splits": "a hash of each take's name (80/5/15 % train/val/test); the pieces of a take share its split",
    "captions": (
        "three per take, written from its content and style labels (pipelines/bandai_namco_captions.py), "
        "a hash of its name choosing the style's wording; what the labels leave open was measured from the joints"
    ),
}


def _dataset_of(folder: Path) -> str | None:
    """Which dataset a folder with ``data/`` and ``cfg/`` holds: its labels say (``dataset-1_walk``)."""
    if not ((folder / "data").is_dir() and (folder / "cfg" / "content_label.txt").is_file()):
        return None
    first = (folder / "cfg" / "content_label.txt").read_text(encoding="utf-8").split()
    name = first[0].split("_")[0] if first else None
    return name if name in DATASETS else None


def dataset_folders(raw: str | Path, subset: str | None = None) -> dict[str, Path]:
    """The dataset folders (``data/``, ``cfg/``) of ``raw``, a clone of the repository, its
    ``dataset/`` folder or one dataset's folder, by name (``dataset-1``…); those ``subset``
    names (``dataset-1``, ``dataset-2`` or ``both``; None: both). ValueError or
    FileNotFoundError in one line when there is none of them."""
    if subset not in (None, "both", *DATASETS):
        raise ValueError(f"--subset: {subset!r} is not one of {', '.join(DATASETS)} or both")
    raw = Path(raw).resolve()
    candidates = [raw, *sorted(raw.glob("Bandai-Namco-Research-Motiondataset-*")), *sorted(raw.glob("dataset/*"))]
    folders: dict[str, Path] = {}
    for candidate in candidates:
        name = _dataset_of(candidate)
        if name is not None:
            folders.setdefault(name, candidate)
    if not folders:
        zipped = next(iter(sorted(raw.rglob("data.zip"))), None)
        hint = f"; unzip {relative_to_project(zipped)} where it lies" if zipped else ""
        raise FileNotFoundError(
            f"{raw}: no dataset folder with data/ and cfg/; --raw is a clone of {REPOSITORY} or one of its "
            f"dataset folders{hint}"
        )
    wanted = DATASETS if subset in (None, "both") else (subset,)
    chosen = {name: folders[name] for name in DATASETS if name in folders and name in wanted}
    if not chosen:
        raise ValueError(f"--subset {subset}: {raw} holds only {', '.join(folders)}")
    return chosen


def _labels(folder: Path, kind: str) -> list[str]:
    path = folder / "cfg" / f"{kind}_label.txt"
    if not path.is_file():
        raise FileNotFoundError(f"{folder}: no cfg/{kind}_label.txt")
    return [line.strip() for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]


def _annotation(take: str, json_path: Path, contents: list[str], styles: list[str]) -> tuple[str, str]:
    """A take's content and style labels from its JSON, or a Rejected reason."""
    try:
        annotation = json.loads(json_path.read_text(encoding="utf-8"))
        indices = int(annotation["content"]), int(annotation["style"])
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise Rejected(
            "read", f"bad annotation: {json_path.name} is not {{'content': i, 'style': j}} ({error})"
        ) from error
    for index, labels, kind in ((indices[0], contents, "content"), (indices[1], styles, "style")):
        if not 0 <= index < len(labels):
            raise Rejected(
                "read", f"bad annotation: {json_path.name}'s {kind} {index} is no line of cfg/{kind}_label.txt"
            )
    content, style = contents[indices[0]], styles[indices[1]]
    named = take.split("_")
    if len(named) < 4 or content != f"{named[0]}_{named[1]}" or style != f"{named[0]}_{named[2]}":
        raise Rejected("read", f"labels unlike the file name: {json_path.name} says {content}, {style}")
    return content.split("_", 1)[1], style.split("_", 1)[1]


def moving_span(joints: np.ndarray, fps: float) -> slice:
    """The frames of a take (T, J, 3), metres, that are left once its leading and trailing
    stillness beyond :data:`STILL_KEPT` frames is; Rejected when no joint ever moves."""
    speeds = np.linalg.norm(np.diff(joints, axis=0), axis=-1).max(axis=1) * fps
    moving = np.flatnonzero(speeds > STILL_SPEED)
    if not len(moving):
        raise Rejected("validate", f"no motion: no joint moves faster than {STILL_SPEED} m/s")
    return slice(max(0, moving[0] - STILL_KEPT), min(len(joints), moving[-1] + 1 + STILL_KEPT))


def pieces(frames: int, maximum: int = FRAME_BOUNDS[1]) -> list[tuple[int, int]]:
    """``frames`` cut into the fewest consecutive pieces of (nearly) equal length whose features
    (one frame fewer than their joints) stay under ``maximum``."""
    count = max(1, math.ceil(frames / maximum))
    cuts = [round(k * frames / count) for k in range(count + 1)]
    return list(zip(cuts[:-1], cuts[1:]))


def _take_rows(take: str, row: dict[str, Any], header_frames: int, fps: float) -> list[dict[str, Any]]:
    """The rows of a readable take: itself, or its pieces when it may be longer than the bounds
    (then its motion is read now, to know its length once trimmed)."""
    if len(instants(header_frames, fps, T2M.fps)) <= FRAME_BOUNDS[1]:  # the frames take_joints gives
        return [row]
    try:
        span = moving_span(_joints(row), T2M.fps)
    except Rejected as rejected:
        return [{**row, "reason": rejected.reason, "stage": rejected.stage}]
    cut = pieces(span.stop - span.start)
    if len(cut) == 1:
        return [row]
    return [
        {**row, "id": f"{take}_part{k}of{len(cut)}", "piece": [first, last]}
        for k, (first, last) in enumerate(cut, start=1)
    ]


def _dataset_rows(name: str, folder: Path) -> list[dict[str, Any]]:
    contents, styles = _labels(folder, "content"), _labels(folder, "style")
    data = folder / "data"
    takes = sorted({path.stem for path in data.iterdir() if path.suffix in (".bvh", ".json")})
    rows = []
    for take in takes:
        bvh, annotation = data / f"{take}.bvh", data / f"{take}.json"
        row: dict[str, Any] = {"id": take, "split": stable_split(take), "kind": "joints", "take": take}
        row |= {"dataset": name, "path": str(bvh), "captions": [], "piece": None}
        try:
            if not bvh.is_file():
                raise Rejected("read", f"no BVH file: {bvh.name} is not in {folder.name}/data, its JSON is")
            if not annotation.is_file():
                raise Rejected(
                    "read", f"no JSON annotation: {annotation.name} (its content and style) is not beside it"
                )
            content, style = _annotation(take, annotation, contents, styles)
            try:
                row["captions"] = captions_for(content, style, take)
            except KeyError as error:
                raise Rejected("read", f"no captions: {error.args[0]}") from error
            header = read_bvh_header(bvh)
        except BvhError as error:
            rows.append({**row, "stage": "read", "reason": str(error).removeprefix(f"{bvh}: ")})
        except Rejected as rejected:
            rows.append({**row, "stage": rejected.stage, "reason": rejected.reason})
        else:
            rows += _take_rows(take, row, header.frames, 1.0 / header.frame_time)
    return rows


def list_bandai_namco(raw: str | Path, subset: str | None = None) -> list[dict[str, Any]]:
    """One row per take, or per piece of a long one, of the chosen datasets, in split then name
    order; a take that cannot be read keeps its ``reason`` (read_take raises it)."""
    rows = [row for name, folder in dataset_folders(raw, subset).items() for row in _dataset_rows(name, folder)]
    return [row for split in SPLITS for row in rows if row["split"] == split]


def _joints(row: dict[str, Any], skeleton: Skeleton = T2M) -> np.ndarray:
    return take_joints(row["path"], skeleton, JOINT_MAP, UNITS)[0]


def read_take(row: dict[str, Any], skeleton: Skeleton) -> np.ndarray:
    """The row's motion: its take's joints, still ends left out, or its piece of them."""
    if row.get("reason"):
        raise Rejected(row["stage"], row["reason"])
    joints = _joints(row, skeleton)
    joints = joints[moving_span(joints, skeleton.fps)]
    if row["piece"] is None:
        return joints
    first, last = row["piece"]
    if last > len(joints):
        raise Rejected("validate", f"piece past the take: frames {first}–{last} of {len(joints)} (the file changed?)")
    return joints[first:last]


def read_take_captions(row: dict[str, Any]) -> list[dict[str, Any]]:
    """The row's captions, untagged (the pipeline tags them), each of the whole motion."""
    if not row["captions"]:
        raise Rejected("read", row.get("reason") or "no captions")
    return [{"text": text, "tokens": None, "start": 0.0, "end": 0.0} for text in row["captions"]]


BANDAI_NAMCO_LAYOUT = CorpusLayout(
    "bandai-namco",
    list_bandai_namco,
    read_take,
    read_take_captions,
    options=("subset",),
    tagged_captions=False,
    about=ABOUT,
)
register_corpus(Corpus("bandai-namco", T2M, FRAME_BOUNDS, BANDAI_NAMCO_LAYOUT))
