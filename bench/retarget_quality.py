"""How well our motion lands on other rigs (docs/generation.md, "How well it lands"): HumanML3D's
walking clip 012314 retargeted (:func:`m2d2m.motion.rigs.retarget.retarget`) onto every rig the tests
know (tests/rigs.py's naming conventions, Mixamo's X Bot, CMU's 131_01 rig), measured where it
matters to whoever animates with it.

Columns: the rig's leg (hip to ankle, m); where its feet stand in our clip's stance frames
(:func:`m2d2m.motion.transforms.feet.foot_contacts`), against where they stand in its own rest pose on its
floor (ankles, then toes: median and largest gap, cm); how fast its feet slide then, against
ours scaled by the legs' ratio (mean horizontal speed, cm/s); the largest angle between a mapped
bone from a joint with one mapped child and ours (degrees), feet and head aside where they turn
from the rig's rest as ours turn from where ours stand (on a character standing at rest:
:func:`m2d2m.motion.rigs.retarget.stands_at_rest`), so the next column is how far their angle from ours
strays from the one their rests make (degrees); its hips' height over its leg, against ours.

    python bench/retarget_quality.py

prints the command and the table (markdown). Deterministic; a few seconds.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # tests/rigs.py's conventions, run as a script

from m2d2m.motion.files.bvh_reader import read_bvh  # noqa: E402
from m2d2m.motion.representation.rigid import on_rigid_skeleton  # noqa: E402
from m2d2m.motion.representation.skeleton import T2M  # noqa: E402
from m2d2m.motion.rigs.joint_map import JointMap, joint_map_for  # noqa: E402
from m2d2m.motion.rigs.retarget import OUR_ANKLE_ON_FLOOR_M, OUR_REST_AIMS, Rig, ankle_lift, read_rig, retarget  # noqa: E402
from m2d2m.motion.transforms.feet import foot_contacts  # noqa: E402
from tests.rigs import CONVENTIONS  # noqa: E402

SAMPLE = ROOT / "tests" / "fixtures" / "humanml3d-sample" / "new_joints" / "012314.npy"
XBOT = ROOT / "tests" / "fixtures" / "mixamo" / "xbot-skeleton.glb"
CMU = ROOT / "tests" / "fixtures" / "cmu-bvh" / "131_01.bvh"
CMU_METRES = 0.056444  # cgspeed's unit: 1/0.45 inch
FEET = (7, 10, 8, 11)  # foot_contacts' order: left ankle, left toe, right ankle, right toe
LEGS = ((1, 4), (4, 7))


@dataclass(frozen=True)
class Landing:
    """One rig's row (cm, cm/s, degrees as the module says)."""

    leg: float
    ankles: tuple[float, float]  # median gap, largest |gap|
    toes: tuple[float, float] | None  # None on a rig without toe joints
    slide: float
    our_slide: float
    bone_max: float
    from_rest_max: float | None  # None where feet and head point as ours (a rig not standing at rest)
    hips: float
    our_hips: float


def our_clip() -> np.ndarray:
    """HumanML3D's clip 012314 (a walk) on one rigid skeleton, as a delivery gives it."""
    return on_rigid_skeleton(np.load(SAMPLE).astype(np.float64), T2M)


def _leg(points: np.ndarray, pairs) -> float:
    return float(sum(np.linalg.norm(points[..., b, :] - points[..., a, :], axis=-1).mean() for a, b in pairs))


def landing(ours: np.ndarray, rig: Rig, joint_map: JointMap, fps: float = 20.0) -> Landing:
    """Our joints ``ours`` (T, 22, 3, metres) on ``rig`` (metres) through ``joint_map``, measured."""
    motion = retarget(ours, rig, joint_map)
    moved = motion.positions()
    theirs = {
        T2M.joint_names.index(o): rig.names.index(t[0])
        for o, t in joint_map.sources.items()
        if len(t) == 1 and o not in joint_map.offsets and t[0] in rig.names
    }
    rest = rig.rest_positions()
    rig_leg = _leg(rest, [(theirs[a], theirs[b]) for a, b in LEGS])
    scale = rig_leg / _leg(ours, LEGS)
    # The rig's floor in its rest pose; in the motion, ours (y = 0) scaled
    floor = float(rest[theirs[7], 1]) - (ankle_lift(rest, theirs[7], rig_leg, scale) + scale * OUR_ANKLE_ON_FLOOR_M)
    contacts = foot_contacts(ours, T2M, fps)
    gaps: dict[int, list[np.ndarray]] = {0: [], 1: []}  # ankles, toes
    slides, our_slides = [], []
    for k, joint in enumerate(FEET):
        if joint not in theirs:
            continue
        stance = contacts[:, k]
        gaps[k % 2].append((moved[:, theirs[joint], 1] - (rest[theirs[joint], 1] - floor))[stance] * 100)
        step = np.linalg.norm(np.diff(moved[:, theirs[joint], [0, 2]], axis=0), axis=-1) * fps
        our_step = np.linalg.norm(np.diff(ours[:, joint, [0, 2]], axis=0), axis=-1) * fps * scale
        slides.append(step[stance[1:] & stance[:-1]])
        our_slides.append(our_step[stance[1:] & stance[:-1]])
    spread = {
        k: (float(np.median(np.concatenate(g))), float(np.abs(np.concatenate(g)).max())) for k, g in gaps.items() if g
    }
    rested = {  # the bones that turned from the rig's rest → where ours stand
        (T2M.joint_names.index(a), T2M.joint_names.index(b)): d
        for (a, b), d in OUR_REST_AIMS.items()
        if T2M.joint_names.index(b) in motion.from_rest
    }
    pairs = [
        (theirs[int(T2M.parents[c])], theirs[c], int(T2M.parents[c]), c)
        for c in range(1, 22)
        if c in theirs and int(T2M.parents[c]) in theirs and np.count_nonzero(T2M.parents == T2M.parents[c]) == 1
    ]
    aimed = [pair for pair in pairs if pair[2:] not in rested]
    a = np.stack([moved[:, b] - moved[:, p] for p, b, _, _ in aimed], axis=1)
    b = np.stack([ours[:, c] - ours[:, p] for _, _, p, c in aimed], axis=1)
    # Feet and head turn from the rig's rest as ours from our rest: they keep their rest's angle from ours
    from_rest = [
        _angle(moved[:, b] - moved[:, p], ours[:, c] - ours[:, q]) - _angle(rest[b] - rest[p], np.array(rested[q, c]))
        for p, b, q, c in pairs
        if (q, c) in rested
    ]
    hips = moved[:, [theirs[1], theirs[2]], 1].mean(axis=1)
    return Landing(
        leg=rig_leg,
        ankles=spread[0],
        toes=spread.get(1),
        slide=float(np.concatenate(slides).mean()) * 100,
        our_slide=float(np.concatenate(our_slides).mean()) * 100,
        bone_max=float(_angle(a, b).max()),
        from_rest_max=float(np.abs(from_rest).max()) if from_rest else None,
        hips=float(hips.mean()) / rig_leg,
        our_hips=float(ours[:, [1, 2], 1].mean()) / _leg(ours, LEGS),
    )


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Degrees between vectors a and b (..., 3)."""
    cosine = np.sum(a * b, -1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
    return np.degrees(np.arccos(np.clip(cosine, -1, 1)))


def rigs() -> list[tuple[str, Rig, JointMap]]:
    """Every rig of the tests, in metres, with the map it takes."""
    found = []
    for convention in CONVENTIONS:
        clip = convention.rig().clip()
        found.append((convention.name, Rig.from_bvh(clip), joint_map_for(clip)))
    xbot = read_rig(XBOT)
    found.append(("Mixamo X Bot (GLB)", Rig.from_bvh(xbot), joint_map_for(xbot)))
    cmu = read_bvh(CMU, CMU_METRES)
    found.append(("CMU 131_01 (BVH)", Rig.from_bvh(cmu), joint_map_for(cmu)))
    return found


def main() -> None:
    print("    python bench/retarget_quality.py\n")
    print(
        "| rig | leg (m) | ankles in stance vs rest: median, max (cm) | toes, the same | slide (cm/s), ours scaled "
        "| bone angle max (°) | feet, head: from rest's angle, max (°) | hips / leg, ours |"
    )
    print("|---|---|---|---|---|---|---|---|")
    ours = our_clip()
    for name, rig, joint_map in rigs():
        row = landing(ours, rig, joint_map)
        toes = "no toes" if row.toes is None else f"{row.toes[0]:+.1f}, {row.toes[1]:.1f}"
        from_rest = "aimed as ours" if row.from_rest_max is None else f"{row.from_rest_max:.1e}"
        print(
            f"| {name} | {row.leg:.2f} | {row.ankles[0]:+.1f}, {row.ankles[1]:.1f} | {toes} "
            f"| {row.slide:.1f}, {row.our_slide:.1f} | {row.bone_max:.1e} | {from_rest} | {row.hips:.3f}, {row.our_hips:.3f} |"
        )


if __name__ == "__main__":
    main()
