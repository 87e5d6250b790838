"""Which way is up in a motion capture, read from the motion rather than from the rig's rest pose.

A BVH rig's rest pose (every rotation zero) need not be a person standing: CMU's cgspeed
conversions stand in a T-pose, but the Bandai Namco Research Motion Dataset's rigs (Kobayashi et
al. 2023, arXiv:2306.08861) point every bone along its local X axis, so their rest pose lies
along +X, while their motion stands on a Y-up floor. The motion does tell: a person's head is
above their feet. :func:`stance` takes, in every frame, the vector from the mean of the feet's
joints to the head, and its per-axis median over the frames (robust to a bow, a fall or a few
frames of a jump); the world axis holding nearly all of that median is up. A motion standing
along another axis than +Y (a Z-up capture, say) is turned onto +Y by a proper rotation, never
a mirror, so its left stays its left. One rule in one place: the corpora's BVH reading
(:mod:`m2d2m.motion.rigs.joint_map`) uses it, and retargeting onto users' rigs is meant to.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m2d2m.motion.representation.skeleton import T2M, Skeleton

UP_SHARE = 0.9  # the up axis holds this share of the median head-over-feet vector (within ~26°)
TALL_PERCENTILE = 90  # the stature of a motion: its head over its feet this high in 90 % of frames

# The proper rotation (columns: where X, Y, Z go) taking each signed world axis onto +Y, turning
# about X (for ±Z, ±Y) or Z (for ±X): a Z-up capture's −Y (Blender's forward) becomes +Z.
_TO_Y_UP: dict[str, np.ndarray] = {
    "+Y": np.eye(3),
    "-Y": np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]]),
    "+Z": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
    "-Z": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),
    "+X": np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]),
    "-X": np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]]),
}


@dataclass(frozen=True)
class Stance:
    """How a motion stands: the signed world ``axis`` it stands along (``+Y``, ``+Z``…), the
    ``rotation`` (3, 3) taking that axis onto +Y, and its ``height``: the head over the feet's
    mean along that axis (:data:`TALL_PERCENTILE`), in the motion's units."""

    axis: str
    rotation: np.ndarray
    height: float

    def upright(self, positions: np.ndarray) -> np.ndarray:
        """``positions`` (..., 3) turned to stand along +Y; the same array when they already do."""
        return positions if self.axis == "+Y" else positions @ self.rotation.T


def stance(joints: np.ndarray, skeleton: Skeleton = T2M) -> Stance:
    """How ``joints`` (T, J, 3), ``skeleton``'s joints in any units, stand; ValueError in one line
    when the head is over the feet along no one world axis."""
    joints = np.asarray(joints, dtype=np.float64)
    feet = joints[:, list(skeleton.feet_left + skeleton.feet_right)].mean(axis=1)
    over = joints[:, skeleton.head_joint] - feet
    median = np.median(over, axis=0)
    length = float(np.linalg.norm(median))
    index = int(np.argmax(np.abs(median)))
    if not length > 0 or abs(median[index]) < UP_SHARE * length:
        raise ValueError(
            "cannot tell which way is up: the head is over the feet along no one axis "
            f"(median head − feet {np.array2string(median, precision=3)}); m2d2m reads motion standing along an axis"
        )
    axis = axis_of(median)
    rotation = _TO_Y_UP[axis]
    height = float(np.percentile((over @ rotation.T)[:, 1], TALL_PERCENTILE))
    return Stance(axis, rotation, height)


def axis_of(vector: np.ndarray) -> str:
    """The signed world axis (``+Y``, ``-Z``…) that holds most of ``vector``."""
    index = int(np.argmax(np.abs(vector)))
    return ("+" if vector[index] > 0 else "-") + "XYZ"[index]


def facing(axis: str) -> np.ndarray:
    """The way a character standing along ``axis`` faces when nothing else tells: the direction
    the turn onto +Y takes to +Z, our forward and glTF's (§3.4), which makes Blender's −Y the
    forward of a Z-up rig."""
    return _TO_Y_UP[axis].T @ np.array([0.0, 0.0, 1.0])
