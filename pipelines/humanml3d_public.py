"""``humanml3d-public``: the rows of HumanML3D whose motion needs no registration
(docs/data.md, "HumanML3D's public rows").

HumanML3D (Guo et al., CVPR 2022; github.com/EricGuo5513/HumanML3D) lists in ``index.csv`` where
each of its 14,616 motions comes from: a source take, a start and an end frame at 20 fps, and the
motion's id. Most sources are AMASS's, which needs a registration and the SMPL+H body model; two
need neither:

* HumanAct12 (1,191 rows): its joints ship in HumanML3D's repository (``pose_data/humanact12.zip``)
  and HumanML3D's ``raw_pose_processing.ipynb`` takes them as they are: the first 22 joints, the
  whole take, no mirroring of the x axis;
* CMU (2,913 rows): CMU's motion capture is public as BVH (cgspeed's conversions), which goes
  through :func:`pipelines.bvh_corpus.take_joints` with CMU's units and joint map, every n-th
  frame as HumanML3D keeps every n-th of AMASS's (``int(mocap_framerate / 20)``), then HumanML3D's
  ``[start:end]``. The BVH files say 120 fps, yet some takes were captured at 60: a take whose
  rows end beyond its length at 120 fps is read at 60 (every 3rd frame), and one whose rows end
  beyond even that does not line up and is quarantined. No x negation: HumanML3D negates x to
  undo the axis swap it makes of AMASS's Z-up world, while CMU's BVH is Y-up already.

``--raw`` is a clone of HumanML3D with ``HumanML3D/texts.zip`` and ``pose_data/humanact12.zip``
unzipped where they lie (HumanAct12's files are found by name anywhere under
``pose_data/humanact12/``); ``--bvh`` a folder holding CMU's BVH files (``<take>.bvh`` in any
subfolder). Every other row is quarantined as "needs AMASS" with its source, so the manifest
counts what is missing. The captions, ids and splits are HumanML3D's; the pipeline makes the
mirrors (``M<id>``) as HumanML3D does. CMU's skeleton is not SMPL's (its spine, neck and collars
are approximated), so these features are not HumanML3D's: never set their scores beside
published ones.
"""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from m2d2m.layout import relative_to_project
from m2d2m.motion.files.bvh_reader import BvhError, read_bvh_header
from m2d2m.motion.representation.skeleton import T2M, Skeleton
from m2d2m.motion.rigs.joint_map import joint_map_for
from pipelines.bvh_corpus import take_joints
from pipelines.corpora import SPLITS, Corpus, CorpusLayout, Rejected, load_captions, register_corpus

INDEX = "index.csv"
HUMANACT12 = "humanact12"
CMU = "CMU"
CMU_UNITS = "cmu"
LINE_UP_FRAMES = 1  # how far past a take's end (20-fps frames) a row may end and still line up


def _splits(texts_root: Path) -> dict[str, str]:
    """HumanML3D's split of each original id (the files list the mirrors ``M<id>`` too)."""
    missing = [f"{split}.txt" for split in SPLITS if not (texts_root / f"{split}.txt").is_file()]
    if missing:
        raise FileNotFoundError(f"{texts_root}: missing split file(s) {', '.join(missing)}")
    return {
        line.strip(): split
        for split in SPLITS
        for line in (texts_root / f"{split}.txt").read_text(encoding="utf-8").splitlines()
        if line.strip() and not line.startswith("M")
    }


def _index(raw: Path) -> list[dict[str, str]]:
    path = raw / INDEX
    if not path.is_file():
        raise FileNotFoundError(f"{raw}: no {INDEX}; --raw is a clone of github.com/EricGuo5513/HumanML3D")
    with path.open(encoding="utf-8", newline="") as handle:
        reader = csv.DictReader(handle)
        needed = {"source_path", "start_frame", "end_frame", "new_name"}
        if not needed <= set(reader.fieldnames or ()):
            raise ValueError(f"{path}: not HumanML3D's index (columns {', '.join(sorted(needed))})")
        return list(reader)


def source_of(source_path: str) -> str:
    """The source dataset of an index row: ``./pose_data/<source>/…``."""
    parts = Path(source_path).parts
    return parts[parts.index("pose_data") + 1] if "pose_data" in parts else parts[0]


def take_name(source_path: str) -> str:
    """CMU's name of a take from its AMASS path: ``…/CMU/131/131_02_poses.npy`` → ``131_02``."""
    return Path(source_path).name.removesuffix(".npy").removesuffix("_poses")


def frame_step(frames: int, fps: float, ends: list[int], target_fps: float) -> int | None:
    """The step through a take's ``frames`` (at the ``fps`` its file states) that HumanML3D took,
    judged from where its rows ``ends``: every n-th frame for a take captured at ``fps`` (n =
    fps / target), every n/2-th for one captured at half that yet written at ``fps``, or None
    when its rows end beyond the take either way."""
    step = round(fps / target_fps)
    for candidate in (step, step // 2) if step % 2 == 0 else (step,):
        if max(ends) <= math.ceil(frames / candidate) + LINE_UP_FRAMES:
            return candidate
    return None


def _bvh_files(folder: str | None) -> dict[str, Path]:
    if folder is None:
        return {}
    root = Path(folder).resolve()
    if not root.is_dir():
        raise FileNotFoundError(f"{folder}: no such folder of CMU's BVH files (--bvh)")
    return {path.stem: path for path in sorted(root.rglob("*.bvh"))}


def _cmu_rows(rows: list[dict[str, Any]], bvh: dict[str, Path], bvh_folder: str | None, joint_map: str | None) -> None:
    """Give each CMU row its BVH file and frame step, or the reason it has none."""
    by_take: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for row in rows:
        by_take[take_name(row["source_path"])].append(row)
    for take, take_rows in by_take.items():
        path = bvh.get(take)
        if path is None:
            where = (
                f"no {take}.bvh under {relative_to_project(bvh_folder)}"
                if bvh_folder
                else "pass --bvh <a folder of CMU's BVH>"
            )
            reason = f"needs CMU's BVH: {where}"
        else:
            try:
                header = read_bvh_header(path)
                rest = joint_map_for(header, joint_map).rest_frames
            except (BvhError, ValueError) as error:
                reason, step = str(error), None
            else:
                frames = header.frames - rest
                step = frame_step(frames, 1.0 / header.frame_time, [r["end"] for r in take_rows], T2M.fps)
                reason = (
                    None
                    if step
                    else f"does not line up: rows end at frame {max(r['end'] for r in take_rows)}, past the "
                    f"take's {frames} frames at {1.0 / header.frame_time:g} fps or half that"
                )
        for row in take_rows:
            row |= {"path": str(path) if path else None, "reason": reason}
            if reason is None:
                row["fps"] = T2M.fps * step


def _humanact12_files(raw: Path) -> dict[str, Path]:
    """HumanAct12's joint files by name, wherever under ``pose_data/humanact12/`` its zip put them."""
    folder = raw / "pose_data" / HUMANACT12
    return {path.name: path for path in sorted(folder.rglob("*.npy"))} if folder.is_dir() else {}


def list_public_rows(raw: str | Path, bvh: str | None = None, joint_map: str | None = None) -> list[dict[str, Any]]:
    """Every row of HumanML3D's splits, in split then index order, each with what reads it:
    HumanAct12's joints, a CMU BVH take, or the reason it cannot be read."""
    raw = Path(raw).resolve()
    texts_root = raw / "HumanML3D"
    splits = _splits(texts_root)
    humanact12 = _humanact12_files(raw)
    rows = []
    for entry in _index(raw):
        motion_id = Path(entry["new_name"]).stem
        if motion_id not in splits:
            continue  # two index rows no split lists: not HumanML3D samples
        source = source_of(entry["source_path"])
        row = {
            "id": motion_id,
            "split": splits[motion_id],
            "kind": "joints",
            "source": source,
            "source_path": entry["source_path"],
            "start": int(entry["start_frame"]),
            "end": int(entry["end_frame"]),
            "text_path": str(texts_root / "texts" / f"{motion_id}.txt"),
            "joint_map": joint_map,
        }
        if source == HUMANACT12:
            listed = (raw / entry["source_path"]).resolve()
            row["path"] = str(humanact12.get(listed.name, listed))
        elif source != CMU:
            row["reason"] = f"needs AMASS: from AMASS's {source} (registration and the SMPL+H body model)"
        rows.append(row)
    _cmu_rows([r for r in rows if r["source"] == CMU], _bvh_files(bvh), bvh, joint_map)
    return [row for split in SPLITS for row in rows if row["split"] == split]


def _humanact12_joints(row: dict[str, Any], skeleton: Skeleton) -> np.ndarray:
    path = Path(row["path"])
    if not path.is_file():
        raise Rejected(
            "read",
            f"no HumanAct12 joints: {path.name} is not in {relative_to_project(path.parent)} (unzip pose_data/humanact12.zip in pose_data/)",
        )
    try:
        joints = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as error:
        raise Rejected("read", f"unreadable .npy ({error})") from error
    if joints.ndim != 3 or joints.shape[1] < skeleton.num_joints or joints.shape[2] != 3:
        raise Rejected("validate", f"wrong shape {joints.shape}, expected (T, ≥{skeleton.num_joints}, 3)")
    if not np.isfinite(joints).all():
        raise Rejected("validate", "NaN or Inf values")
    return joints[:, : skeleton.num_joints].astype(np.float32)


def read_public_motion(row: dict[str, Any], skeleton: Skeleton) -> np.ndarray:
    """The row's joints as HumanML3D makes them from its source, or why there are none."""
    if row.get("reason"):
        raise Rejected("read", row["reason"])
    if row["source"] == HUMANACT12:
        return _humanact12_joints(row, skeleton)
    joints, _ = take_joints(row["path"], skeleton, row["joint_map"], CMU_UNITS, fps=row["fps"])
    cut = joints[row["start"] : row["end"]]
    if not len(cut):
        raise Rejected("validate", f"frames {row['start']}–{row['end']} are past the take's {len(joints)}")
    return cut


PUBLIC_LAYOUT = CorpusLayout(
    "humanml3d-public", list_public_rows, read_public_motion, load_captions, options=("bvh", "joint_map")
)
register_corpus(Corpus("humanml3d-public", T2M, (40, 200), PUBLIC_LAYOUT))
