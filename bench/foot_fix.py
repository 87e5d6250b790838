"""What the foot clean-up (:func:`m2d2m.motion.transforms.feet.plant_feet`, as a delivery runs it) does to
real motion, which it must leave alone, and to motion that skates, which it must fix
(docs/evaluation.md, "Feet that stay planted").

Real motion: HumanML3D's clip 012314 (by its joints, as ``m2d2m export --foot-fix`` reads a file,
and with its features' contact channels, as a generated clip comes), CMU's takes 131_01–03
(tests/fixtures/cmu-bvh), Bandai Namco's takes (tests/fixtures/bandai-namco, or ``--bandai``: any
folder of the dataset's BVH files, ``--pool`` for one row of them all; ``--bandai-map``: the joint
map, by default the preset that fits) and ``--synthetic`` clips of the synthetic corpus, pooled in
one row. Recorded takes are put on the floor first, lowest foot joint at y = 0, as HumanML3D's
processing puts its clips, so that GMD's 5 cm means the same on every row.

Motion that skates: each of those clips with its planted feet made to slide (:func:`slide_feet`)
``--slide-distance`` metres at ``--slide`` m/s, forwards about where they stand and back in the
air, the legs solved to follow.

Columns: GMD's skating ratio before and after the fix (and of the clean clip, for a sliding one),
each frame's largest joint displacement by the fix (p50, p95, max, mm), the largest in a frame
whose moved foot is off the ground (:func:`off_ground`), the frames moved more than 1 cm, and for
a sliding clip how far its fixed feet are from the clean clip's where those stand on the ground
(p95 over such frames of a foot's farther joint, ankle or toe, mm).

    python bench/foot_fix.py [--bandai DIR [--pool]] [--bandai-map MAP] [--synthetic 40] [--slide 0.6]
                             [--slide-distance 0.15] [--jitter 0.005 0.01]

prints the command and the table (markdown); ``--jitter`` adds a second table, what putting a
shaking clip on one rigid skeleton (as a generation is delivered) does to its skating
(:func:`rigid_versus_decoded`). Deterministic; a few seconds on two cores (61 Bandai takes: 15).
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m2d2m.motion.representation.skeleton import T2M, Skeleton
from m2d2m.motion.transforms.delivery import Delivery, deliver
from m2d2m.motion.transforms.feet import contact_runs, leg_of, skating_ratio, two_bone_ik

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "tests" / "fixtures" / "humanml3d-sample"
CMU = ROOT / "tests" / "fixtures" / "cmu-bvh"
BANDAI = ROOT / "tests" / "fixtures" / "bandai-namco"
FPS = T2M.fps
MOVED_M = 0.01  # a frame counts as moved when a joint moves more than this
# A foot is on the ground in a frame when its ankle or toe is within GMD's 5 cm of that joint's
# lowest height in the clip and slower than HumanML3D's contact speed (0.002 m² a frame at 20 fps:
# 0.89 m/s) on both steps around it: the measure's own rule, independent of the fix's.
GROUND_M = 0.05
GROUND_SPEED_M_S = float(np.sqrt(T2M.contact_threshold) * T2M.fps)


@dataclass(frozen=True)
class Clip:
    """A clip to fix: ``joints`` (T, 22, 3) in metres at 20 fps, ``features`` whose contact
    channels the fix reads (None: from the joints), and the ``clean`` clip a sliding one was made
    from."""

    name: str
    joints: np.ndarray
    features: np.ndarray | None = None
    clean: np.ndarray | None = None


def fixed(clip: Clip) -> np.ndarray:
    """The clip with its feet fixed, as a delivery fixes them."""
    done = deliver(clip.joints, FPS, T2M, [(0, len(clip.joints))], Delivery(plant_feet=True), clip.features)
    return done.joints.astype(np.float64)


def on_floor(joints: np.ndarray, skeleton: Skeleton = T2M) -> np.ndarray:
    """``joints`` lowered or raised so that the lowest foot joint of the clip is at y = 0."""
    feet = list(skeleton.feet_left + skeleton.feet_right)
    return joints - np.array([0.0, joints[:, feet, 1].min(), 0.0])


def frame_speeds(positions: np.ndarray, fps: float) -> np.ndarray:
    """(T, ...) the faster horizontal speed of the steps into and out of each frame."""
    step = np.linalg.norm(np.diff(positions[..., [0, 2]], axis=0), axis=-1) * fps
    return np.maximum(np.concatenate([step[:1], step]), np.concatenate([step, step[-1:]]))


def on_ground(joints: np.ndarray, skeleton: Skeleton = T2M, fps: float = FPS) -> np.ndarray:
    """(T, 2) whether each foot (left, right) is on the ground by the measure's rule."""
    grounded = []
    for pair in (skeleton.feet_left, skeleton.feet_right):
        joint = joints[:, list(pair)] * skeleton.metres_per_unit
        low = joint[..., 1] - joint[..., 1].min(axis=0) < GROUND_M
        grounded.append((low & (frame_speeds(joint, fps) < GROUND_SPEED_M_S)).any(axis=1))
    return np.stack(grounded, axis=1)


def off_ground(joints: np.ndarray, skeleton: Skeleton = T2M) -> np.ndarray:
    """(T, 2) the complement of :func:`on_ground`: frames where a foot swings or is raised."""
    return ~on_ground(joints, skeleton)


@dataclass(frozen=True)
class Row:
    """One line of the table."""

    name: str
    frames: int
    skating_clean: float | None
    skating_before: float
    skating_after: float
    displacement: np.ndarray  # (T,) each frame's largest joint displacement, m
    off_ground_max: float  # m
    from_clean: np.ndarray | None  # each grounded foot's largest joint distance to the clean clip's, m

    def cells(self) -> list[str]:
        p50, p95, most = np.percentile(self.displacement, [50, 95, 100]) * 1000.0
        clean = "" if self.skating_clean is None else f"{self.skating_clean:.3f}"
        away = "" if self.from_clean is None else f"{np.percentile(self.from_clean, 95) * 1000.0:.0f}"
        return [
            self.name,
            str(self.frames),
            clean,
            f"{self.skating_before:.3f}",
            f"{self.skating_after:.3f}",
            f"{p50:.1f}",
            f"{p95:.1f}",
            f"{most:.1f}",
            f"{self.off_ground_max * 1000.0:.1f}",
            f"{int((self.displacement > MOVED_M).sum())}",
            away,
        ]


HEADER = [
    "clip",
    "frames",
    "skating clean",
    "skating before",
    "after",
    "moved p50 mm",
    "p95",
    "max",
    "max off ground",
    "frames > 1 cm",
    "stance from clean p95 mm",
]


def measure(clips: Sequence[Clip], name: str | None = None) -> Row:
    """One row for ``clips`` (their frames pooled; skating averaged over the clips)."""
    before, after, moved, away, clean_skating, off = [], [], [], [], [], 0.0
    for clip in clips:
        result = fixed(clip)
        distance = np.linalg.norm(result - clip.joints, axis=-1)  # (T, J)
        moved.append(distance.max(axis=1))
        swinging = off_ground(clip.joints)
        for side, pair in enumerate((T2M.feet_left, T2M.feet_right)):
            leg = list(leg_of(T2M, pair)[2:])
            if swinging[:, side].any():
                off = max(off, float(distance[swinging[:, side]][:, leg].max()))
        before.append(skating_ratio(clip.joints, T2M, FPS))
        after.append(skating_ratio(result, T2M, FPS))
        if clip.clean is not None:
            clean_skating.append(skating_ratio(clip.clean, T2M, FPS))
            standing = on_ground(clip.clean)
            for side, pair in enumerate((T2M.feet_left, T2M.feet_right)):
                gap = np.linalg.norm(result[:, list(pair)] - clip.clean[:, list(pair)], axis=-1).max(axis=1)
                away.append(gap[standing[:, side]])
    return Row(
        name or clips[0].name,
        sum(len(c.joints) for c in clips),
        float(np.mean(clean_skating)) if clean_skating else None,
        float(np.mean(before)),
        float(np.mean(after)),
        np.concatenate(moved),
        off,
        np.concatenate(away) if away else None,
    )


def slide_feet(
    joints: np.ndarray, speed: float, distance: float, skeleton: Skeleton = T2M, fps: float = FPS
) -> np.ndarray:
    """``joints`` (T, J, 3) with every planted stretch of each foot made to slide at ``speed``
    m/s along the body's forward direction at that stretch, ``distance`` metres (less in a
    stretch too short for it), from behind where the foot stands to in front of it (the slide
    centred on the real footprint), and back again in the air: a clip that skates by a known
    amount. A stretch is a run of :func:`on_ground` frames; between
    two, the offset goes from one's last value to the next's first with a smoothstep. The foot
    moves rigidly; the knee comes from :func:`m2d2m.motion.transforms.feet.two_bone_ik` from the unmoved
    hip, so every bone keeps its length and only the legs below the hips change."""
    joints = np.asarray(joints, dtype=np.float64)
    grounded = on_ground(joints, skeleton, fps)
    across = joints[:, skeleton.face_joints[1]] - joints[:, skeleton.face_joints[0]]  # right hip → left hip
    forward = np.stack([-across[:, 2], np.zeros(len(joints)), across[:, 0]], axis=-1)
    forward /= np.maximum(np.linalg.norm(forward, axis=-1, keepdims=True), 1e-9)
    result = joints.copy()
    frames = np.arange(len(joints))
    for side, pair in enumerate((skeleton.feet_left, skeleton.feet_right)):
        runs = contact_runs(grounded[:, side])
        if not runs:
            continue
        offset = np.zeros(len(joints))  # metres along each run's forward direction
        direction = np.zeros((len(joints), 3))
        for first, end in runs:
            middle = (first + end - 1) / 2.0
            offset[first:end] = np.clip(speed * (frames[first:end] - middle) / fps, -distance / 2, distance / 2)
            direction[first:end] = forward[first:end].mean(axis=0)
        vector = offset[:, None] * direction
        for (_, end), (first, _) in zip(runs[:-1], runs[1:]):
            s = (frames[end:first] - end + 1) / (first - end + 1)
            ease = (s * s * (3.0 - 2.0 * s))[:, None]
            vector[end:first] = (1.0 - ease) * vector[end - 1] + ease * vector[first]
        vector[: runs[0][0]] = vector[runs[0][0]]
        vector[runs[-1][1] :] = vector[runs[-1][1] - 1]
        chain = leg_of(skeleton, pair)
        hip, knee, ankle, foot = chain[1], chain[2], chain[3], list(chain[3:])
        target = joints[:, ankle] + vector / skeleton.metres_per_unit
        new_knee, new_ankle = two_bone_ik(joints[:, hip], joints[:, knee], joints[:, ankle], target)
        result[:, knee] = new_knee
        result[:, foot] = joints[:, foot] + (new_ankle - joints[:, ankle])[:, None]
    return result


def real_clips() -> Iterator[Clip]:
    """HumanML3D's clip (by its joints, then with its features' contacts) and CMU's takes."""
    from pipelines.bvh_corpus import take_joints

    joints = np.load(SAMPLE / "new_joints" / "012314.npy").astype(np.float64)
    yield Clip("HumanML3D 012314", joints)
    features = np.load(SAMPLE / "new_joint_vecs" / "012314.npy")
    yield Clip("HumanML3D 012314, its contact channels", joints, features)
    for path in sorted(CMU.glob("131_0*.bvh")):
        yield Clip(f"CMU {path.stem}", on_floor(take_joints(path, units="cmu")[0].astype(np.float64)))


def bandai_clips(folder: Path, joint_map: str | None) -> list[Clip]:
    """Every BVH take under ``folder`` (the dataset's layout, or a flat folder of its files)."""
    from pipelines.bvh_corpus import take_joints

    return [
        Clip(
            f"Bandai {path.stem.split('_', 1)[-1]}",
            on_floor(take_joints(path, joint_map=joint_map)[0].astype(np.float64)),
        )
        for path in sorted(folder.glob("**/*.bvh"))
    ]


def synthetic_clips(count: int) -> list[Clip]:
    """The first ``count`` clips of the synthetic corpus of seed 0."""
    from pipelines.synthetic import make_clip

    return [Clip("synthetic corpus", make_clip(index, seed=0).joints.astype(np.float64)) for index in range(count)]


def sliding(clip: Clip, speed: float, distance: float) -> Clip:
    """``clip`` made to skate (:func:`slide_feet`); a clip with features keeps its channels."""
    slid = slide_feet(clip.joints, speed, distance)
    return Clip(f"{clip.name}, sliding", slid, clip.features, clip.joints)


def rigid_versus_decoded(noise: Sequence[float], seed: int = 0) -> str:
    """A table: clip 012314 with independent Gaussian noise of each standard deviation (metres)
    on every joint but the root in every frame, as a model's decoded joints shake, measured as
    decoded (what the evaluation measures and plants) and on one rigid skeleton (what a
    generation is delivered on): the bone-length spread, the skating of each, and after the fix."""
    from m2d2m.motion.representation.rigid import bone_length_spread, on_rigid_skeleton
    from m2d2m.motion.transforms.feet import fix_feet

    joints = np.load(SAMPLE / "new_joints" / "012314.npy").astype(np.float64)
    features = np.load(SAMPLE / "new_joint_vecs" / "012314.npy")
    rng = np.random.default_rng(seed)
    lines = [
        "| noise mm | bone spread mm | skating decoded | rigid | fixed decoded | fixed rigid |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for sigma in noise:
        decoded = joints.copy()
        decoded[:, 1:] += rng.normal(0.0, sigma, decoded[:, 1:].shape)
        rigid = on_rigid_skeleton(decoded, T2M)
        values = [skating_ratio(clip, T2M, FPS) for clip in (decoded, rigid)]
        values += [skating_ratio(fix_feet(clip, T2M, FPS, features), T2M, FPS) for clip in (decoded, rigid)]
        spread = bone_length_spread(decoded, T2M)["mean"]
        lines.append(f"| {sigma * 1000:g} | {spread:.1f} | " + " | ".join(f"{v:.3f}" for v in values) + " |")
    return "\n".join(lines)


def table(rows: Sequence[Row]) -> str:
    lines = ["| " + " | ".join(HEADER) + " |", "| " + " | ".join(["---"] * len(HEADER)) + " |"]
    return "\n".join(lines + ["| " + " | ".join(row.cells()) + " |" for row in rows])


def main(argv: Sequence[str] | None = None) -> list[Row]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--bandai", type=Path, help="a folder of Bandai Namco BVH takes (default: the fixtures')")
    parser.add_argument("--bandai-map", help="the joint map that reads them (default: the preset that fits)")
    parser.add_argument("--pool", action="store_true", help="one row for all Bandai takes (and one sliding)")
    parser.add_argument(
        "--jitter",
        type=float,
        nargs="*",
        metavar="M",
        help="also clip 012314 shaken by noise of these standard deviations (m), decoded and on one rigid skeleton",
    )
    parser.add_argument("--synthetic", type=int, default=40, help="synthetic corpus clips, one row (default 40)")
    parser.add_argument("--slide", type=float, default=0.6, help="the sliding clips' speed, m/s (default 0.6)")
    parser.add_argument(
        "--slide-distance", type=float, default=0.15, help="how far each stance slides at most, m (default 0.15)"
    )
    args = parser.parse_args(argv)
    folder = args.bandai or (BANDAI if BANDAI.is_dir() else None)
    bandai = bandai_clips(folder, args.bandai_map) if folder is not None else []
    groups = [[clip] for clip in real_clips()]  # each measured on its own row, or pooled
    groups += [bandai] if args.pool and bandai else [[clip] for clip in bandai]
    if args.synthetic:
        groups.append(synthetic_clips(args.synthetic))

    def name(group: list[Clip], suffix: str = "") -> str:
        kind = os.path.commonprefix([clip.name for clip in group]).strip()
        return f"{group[0].name}{suffix}" if len(group) == 1 else f"{kind}, {len(group)} clips{suffix}"

    rows = [measure(group, name(group)) for group in groups]
    for group in groups:
        slid = [sliding(clip, args.slide, args.slide_distance) for clip in group]
        rows.append(measure(slid, name(group, ", sliding")))
    shown = " ".join(shlex.quote(a) for a in (sys.argv[1:] if argv is None else argv))
    print(f"python bench/foot_fix.py {shown}".rstrip())
    print(table(rows))
    if args.jitter:
        print()
        print(rigid_versus_decoded(args.jitter))
    return rows


if __name__ == "__main__":
    main()
