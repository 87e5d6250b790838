"""Export of joint positions for tools outside M2D2M: BVH for animation software, and ``.npy``
with a JSON sidecar that states every convention (users ask for both; see users.md §3.3). The BVH's
rotations are the rig's animation of the positions (:mod:`m2d2m.motion.representation.pose`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

import numpy as np

from m2d2m.atomic import atomic_path
from m2d2m.motion.files.sidecar import Sidecar
from m2d2m.motion.representation.pose import pose_of
from m2d2m.motion.representation.rigid import children
from m2d2m.motion.representation.rotations import matrix_to_euler
from m2d2m.motion.representation.skeleton import T2M, Skeleton

EULER_ORDER = "ZYX"  # BVH channels Zrotation Yrotation Xrotation: R = Rz · Ry · Rx


def save_bvh(
    path: str | Path,
    joints: np.ndarray,
    skeleton: Skeleton = T2M,
    fps: float | None = None,
    bone_lengths: np.ndarray | None = None,
    rest_pose: str = "skeleton",
) -> Path:
    """Write joint positions (T, J, 3) as a BVH file and return its path.

    Positions (root channels and OFFSETs) are in the clip's units — metres for T2M, so import
    into Blender at scale 1 — with +Y up; the character faces +Z (Blender's importer converts
    to its Z-up axes). The frame time is ``1 / fps`` (default: the skeleton's, 20 fps for T2M);
    BVH has no other place for the rate, and Blender uses it only with "Update Scene FPS".
    Rotations are in degrees, channels ``Zrotation Yrotation Xrotation`` on every joint.

    The rest pose (the OFFSETs, a rig's bind pose) has the clip's own bone lengths (averaged over
    frames) unless ``bone_lengths`` are given, in the directions of ``rest_pose``: ``skeleton``
    (HumanML3D's: arms hanging from the collars, the head bone forward) or ``tpose`` (arms out
    to the sides, the head up: what retargeting tools expect; :meth:`Skeleton.tpose_offsets`).
    Either way the children of a joint with several (T2M's pelvis and chest) keep the clip's own
    rigid shape, turned as close to the rest directions as it goes — real (SMPL-derived) hips sit
    below the pelvis — so forward kinematics of the file reproduces the clip. Twist about bones
    is not recoverable from positions: it is inherited from the parent.
    """
    pose = pose_of(joints, skeleton, bone_lengths, rest_pose)
    leaves = [joint for joint, kids in enumerate(children(skeleton)) if not kids]
    return write_bvh(
        path,
        skeleton.joint_names,
        skeleton.parents,
        pose.offsets,
        pose.root,
        pose.local,
        float(skeleton.fps if fps is None else fps),
        # an End Site half the last bone again, so the leaf bone shows its direction
        end_sites={leaf: 0.5 * pose.offsets[leaf] for leaf in leaves},
    )


def write_bvh(
    path: str | Path,
    names: Sequence[str],
    parents: np.ndarray,
    offsets: np.ndarray,
    root: np.ndarray,
    local: np.ndarray,
    fps: float,
    end_sites: dict[int, np.ndarray] | None = None,
) -> Path:
    """Write any rig's animation as BVH: joints ``names`` with ``parents`` (-1 for the root),
    rest ``offsets`` (J, 3), the root's positions (T, 3) and every joint's rotation relative to its
    parent (T, J, 3, 3); ``end_sites`` the End Site offset of the leaves that have one. The root
    has channels ``Xposition Yposition Zposition`` and every joint ``Zrotation Yrotation
    Xrotation`` (degrees, unwrapped into continuous curves for interpolation)."""
    angles = np.degrees(matrix_to_euler(local, EULER_ORDER))
    angles = np.unwrap(angles, axis=0, period=360.0)
    kids_of = children(parents)
    order = _depth_first(kids_of, int(np.flatnonzero(np.asarray(parents) < 0)[0]))
    motion = np.concatenate([root, angles[:, order].reshape(len(root), -1)], axis=1)
    path = Path(path)
    with atomic_path(path) as partial, partial.open("w") as f:
        f.write("HIERARCHY\n")
        _write_joint(f, names, kids_of, offsets, end_sites or {}, joint=order[0], depth=0)
        f.write(f"MOTION\nFrames: {len(root)}\nFrame Time: {1.0 / fps:.8f}\n")
        np.savetxt(f, motion, fmt="%.6f")
    return path


def save_motion_npy(
    path: str | Path,
    joints: np.ndarray,
    fps: float | None = None,
    skeleton: Skeleton = T2M,
    segments: Sequence[tuple[int, int, str]] | None = None,
    quality: dict[str, float] | None = None,
    root_track: np.ndarray | None = None,
    loop: bool = False,
) -> Path:
    """Write ``<name>.npy`` (float32, T × J × 3) and its :class:`~m2d2m.motion.files.sidecar.Sidecar`
    ``<name>.json`` beside it stating the ``(start, end, text)`` segments (``end`` exclusive),
    ``quality`` figures of how the joints were made, the root motion an in-place clip took out
    (``<name>.root_motion.npy``, T × 3) and whether it is one cycle of a loop (its last frame runs
    on into its first); return the ``.npy`` path."""
    joints = skeleton.check_joints(joints).astype(np.float32)
    fps = float(skeleton.fps if fps is None else fps)
    n_frames = len(joints)
    segments = list(segments or [])
    for start, end, _ in segments:
        if not 0 <= start < end <= n_frames:
            raise ValueError(f"segment ({start}, {end}) must satisfy 0 <= start < end <= {n_frames}")
    npy = Path(path).with_suffix(".npy")
    with atomic_path(npy) as partial:
        np.save(partial, joints)
    track = npy.with_suffix(".root_motion.npy") if root_track is not None else None
    if track is not None:
        with atomic_path(track) as partial:
            np.save(partial, np.asarray(root_track, dtype=np.float32))
    stated = Sidecar(
        npy.name,
        skeleton.name,
        fps,
        n_frames,
        segments,
        dict(quality or {}),
        None if track is None else track.name,
        loop,
    )
    stated.write(npy.parent)
    return npy


def _depth_first(kids_of: list[list[int]], root: int) -> list[int]:
    """Joints in the order BVH lists them (and their channels)."""
    order, stack = [], [root]
    while stack:
        joint = stack.pop()
        order.append(joint)
        stack.extend(reversed(kids_of[joint]))
    return order


def _write_joint(
    f: TextIO,
    names: Sequence[str],
    kids_of: list[list[int]],
    offsets: np.ndarray,
    end_sites: dict[int, np.ndarray],
    joint: int,
    depth: int,
) -> None:
    """Write one joint's HIERARCHY block and, recursively, its descendants'."""
    pad = "\t" * depth
    if depth == 0:
        f.write(f"{pad}ROOT {names[joint]}\n{pad}{{\n{pad}\tOFFSET 0.000000 0.000000 0.000000\n")
        f.write(f"{pad}\tCHANNELS 6 Xposition Yposition Zposition {_rotation_channels()}\n")
    else:
        f.write(f"{pad}JOINT {names[joint]}\n{pad}{{\n{pad}\tOFFSET {_triple(offsets[joint])}\n")
        f.write(f"{pad}\tCHANNELS 3 {_rotation_channels()}\n")
    for kid in kids_of[joint]:
        _write_joint(f, names, kids_of, offsets, end_sites, kid, depth + 1)
    if joint in end_sites:
        end = _triple(end_sites[joint])
        f.write(f"{pad}\tEnd Site\n{pad}\t{{\n{pad}\t\tOFFSET {end}\n{pad}\t}}\n")
    f.write(f"{pad}}}\n")


def _rotation_channels() -> str:
    return " ".join(f"{axis}rotation" for axis in EULER_ORDER)


def _triple(v: np.ndarray) -> str:
    return " ".join(f"{x:.6f}" for x in v)
