"""Joining separately generated motions: the SLERP baseline of TEACH (Athanasiou et al. 2022;
athn-nik/teach, its SLERP baseline)
on joint positions.

Each motion after the first is turned about the vertical axis so that its first frame faces where
the previous motion's last frame faces, and moved so that its root starts where the previous
root ended (TEACH's body alignment). The gap between the two poses is then filled with ``window``
frames: local joint rotations (recovered by the skeleton's inverse kinematics, relative to the
body's facing) are interpolated by quaternion SLERP and the root position linearly, at weights
linspace(0, 1, window + 2) without the two ends, and forward kinematics rebuilds the joints
with the previous motion's bone lengths.
"""

from __future__ import annotations

import numpy as np

from m2d2m.motion.representation.features import facing_direction
from m2d2m.motion.representation.rotations import qbetween, qinv, qrot, qslerp, quat_from_axis_angle
from m2d2m.motion.representation.skeleton import Skeleton

_UP = np.array([0.0, 1.0, 0.0])
_FORWARD = np.array([0.0, 0.0, 1.0])


def _yaw(direction: np.ndarray) -> float:
    return float(np.arctan2(direction[0], direction[2]))


def align(motion: np.ndarray, anchor: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """``motion`` (F, J, 3) turned about +Y and shifted horizontally so that its first frame faces
    and stands where the pose ``anchor`` (J, 3) does; heights are kept."""
    turn = _yaw(facing_direction(anchor, skeleton)) - _yaw(facing_direction(motion[0], skeleton))
    rotation = quat_from_axis_angle(_UP, np.array(turn))
    start = motion[0, 0] * np.array([1.0, 0.0, 1.0])
    turned = qrot(np.broadcast_to(rotation, motion.shape[:-1] + (4,)), motion - start)
    return turned + anchor[0] * np.array([1.0, 0.0, 1.0])


def bridge(last: np.ndarray, first: np.ndarray, window: int, skeleton: Skeleton) -> np.ndarray:
    """``window`` poses (window, J, 3) between the pose ``last`` and the (aligned) pose ``first``."""
    if window < 1:
        return np.zeros((0,) + last.shape)
    poses = np.stack([last, first])
    # root rotation = the body's facing, so that the local rotations are relative to the body
    facing = qinv(qbetween(facing_direction(poses, skeleton), _FORWARD))
    local = skeleton.inverse_kinematics(poses, facing)
    weights = np.linspace(0.0, 1.0, window + 2)[1:-1]
    rotations = qslerp(local[0][None], local[1][None], weights[:, None])
    roots = (1.0 - weights)[:, None] * last[0] + weights[:, None] * first[0]
    offsets = skeleton.offsets(skeleton.bone_lengths_of(last))
    return skeleton.forward_kinematics(rotations, roots, offsets)


def slerp_join(motions: list[np.ndarray], window: int, skeleton: Skeleton) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """Motions joined with aligned bodies and ``window`` interpolated frames between neighbours;
    returns the joints and each motion's (first, end) frames in them."""
    if not motions:
        raise ValueError("need at least one motion to join")
    pieces = [np.asarray(motions[0], dtype=np.float64)]
    ranges = [(0, len(motions[0]))]
    for motion in motions[1:]:
        previous = pieces[-1][-1]
        aligned = align(np.asarray(motion, dtype=np.float64), previous, skeleton)
        pieces.append(bridge(previous, aligned[0], window, skeleton))
        start = ranges[-1][1] + window
        pieces.append(aligned)
        ranges.append((start, start + len(motion)))
    return np.concatenate(pieces), ranges
