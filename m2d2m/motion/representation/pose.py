"""A clip as a rig animates it: rest offsets, the root's path and every joint's rotation relative
to its parent, made from joint positions, and forward kinematics back to them.

Every format that animates a skeleton (BVH, glTF, FBX) and every edit that must keep bone lengths
(resampling in time by slerp, retargeting) works on this form; the positions are what the models
make. Joint positions carry no twist about a bone, so the rotations are reconstructed by inverse
kinematics: a joint with one child gets the swing that turns the rest bone onto the actual bone,
measured in its parent's frame (so a limb inherits its parent's twist and the choice stays
continuous, flipping only when a bone points exactly opposite to its rest direction relative to
its parent); a joint with several children (T2M's pelvis and upper spine) gets the best-fit
(Kabsch) rotation of its rest child offsets onto the actual ones.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m2d2m.motion.representation.rigid import best_fit_rotation, children, rigid_shape
from m2d2m.motion.representation.rotations import qbetween, quat_to_matrix
from m2d2m.motion.representation.skeleton import Skeleton

REST_POSES = ("skeleton", "tpose")  # a rig's bind pose: HumanML3D's rest directions, or a T-pose


@dataclass(frozen=True)
class Pose:
    """``offsets`` (J, 3) each joint's rest offset from its parent (the root's is zero), ``root``
    (T, 3) the root's position in every frame, ``local`` (T, J, 3, 3) each joint's rotation
    relative to its parent's frame (the root's relative to the world), acting on column vectors."""

    skeleton: Skeleton
    offsets: np.ndarray
    root: np.ndarray
    local: np.ndarray

    def world_rotations(self) -> np.ndarray:
        """(T, J, 3, 3) every joint's rotation in the world."""
        world = np.empty_like(self.local)
        for joint in topological_order(self.skeleton):
            parent = self.skeleton.parents[joint]
            world[:, joint] = self.local[:, joint] if parent < 0 else world[:, parent] @ self.local[:, joint]
        return world

    def joints(self) -> np.ndarray:
        """(T, J, 3) every joint's world position: forward kinematics of the rig."""
        world = self.world_rotations()
        positions = np.empty((len(self.root), len(self.offsets), 3))
        for joint in topological_order(self.skeleton):
            parent = self.skeleton.parents[joint]
            if parent < 0:
                positions[:, joint] = self.root
            else:
                positions[:, joint] = positions[:, parent] + world[:, parent] @ self.offsets[joint]
        return positions


def topological_order(skeleton: Skeleton) -> list[int]:
    """Root first, then every joint after its parent."""
    return [int(np.flatnonzero(skeleton.parents < 0)[0])] + skeleton.bones.tolist()


def rest_offsets(
    joints: np.ndarray, skeleton: Skeleton, bone_lengths: np.ndarray | None = None, rest_pose: str = "skeleton"
) -> np.ndarray:
    """A bind pose for ``joints``: the clip's own bone lengths (averaged over frames) unless
    ``bone_lengths`` are given, in the directions of ``rest_pose`` (``skeleton``: HumanML3D's,
    arms hanging from the collars; ``tpose``: arms out, head up, what retargeting tools expect).
    The children of a joint with several (T2M's pelvis and chest) keep the clip's own rigid shape
    (:func:`m2d2m.motion.representation.rigid.rigid_shape`), turned as close to the rest directions as it goes,
    so that forward kinematics reproduces the clip (real, SMPL-derived hips sit below the pelvis)."""
    if rest_pose not in REST_POSES:
        raise ValueError(f"rest_pose must be one of {', '.join(REST_POSES)}, got {rest_pose!r}")
    if bone_lengths is None:
        bone_lengths = skeleton.bone_lengths_of(joints).mean(axis=0)
    lengths = np.asarray(bone_lengths, dtype=np.float64)
    offsets = skeleton.tpose_offsets(lengths) if rest_pose == "tpose" else skeleton.offsets(lengths)
    for joint, kids in enumerate(children(skeleton)):
        if len(kids) < 2:
            continue
        shape = rigid_shape(joints[:, kids] - joints[:, [joint]], offsets[kids])
        offsets[kids] = shape @ best_fit_rotation(offsets[kids], shape)
    return offsets


def pose_of(
    joints: np.ndarray, skeleton: Skeleton, bone_lengths: np.ndarray | None = None, rest_pose: str = "skeleton"
) -> Pose:
    """The rig's animation of joint positions (T, J, 3) on the bind pose of :func:`rest_offsets`."""
    joints = np.asarray(skeleton.check_joints(joints), dtype=np.float64)
    offsets = rest_offsets(joints, skeleton, bone_lengths, rest_pose)
    return Pose(skeleton, offsets, joints[:, 0].copy(), local_rotations(joints, skeleton, offsets))


def local_rotations(joints: np.ndarray, skeleton: Skeleton, offsets: np.ndarray) -> np.ndarray:
    """Rotation matrices (T, J, 3, 3) of every joint relative to its parent joint that turn the
    rest ``offsets`` onto the clip's bones."""
    n_frames, n_joints = joints.shape[:2]
    kids_of = children(skeleton)
    world = np.empty((n_frames, n_joints, 3, 3))
    local = np.empty_like(world)
    identity = np.broadcast_to(np.eye(3), (n_frames, 3, 3))
    for joint in topological_order(skeleton):
        parent = skeleton.parents[joint]
        parent_world = identity if parent < 0 else world[:, parent]
        kids = kids_of[joint]
        if len(kids) > 1:
            world[:, joint] = best_fit_rotation(offsets[kids], joints[:, kids] - joints[:, [joint]])
            local[:, joint] = np.swapaxes(parent_world, -1, -2) @ world[:, joint]
        elif len(kids) == 1:
            bone = joints[:, kids[0]] - joints[:, joint]
            in_parent = np.einsum("tji,tj->ti", parent_world, bone)
            local[:, joint] = quat_to_matrix(qbetween(offsets[kids[0]], in_parent))
            world[:, joint] = parent_world @ local[:, joint]
        else:  # a leaf: nothing below it to turn, so it follows its parent
            local[:, joint] = np.eye(3)
            world[:, joint] = parent_world
    return local
