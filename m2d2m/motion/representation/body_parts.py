"""The body split into parts, as sets of feature dimensions of HumanML3D's representation
(docs/body-parts.md has the joint lists and the dimension ranges for both skeletons).

MMM's upper-body editing (Pinyoanuntapong et al., CVPR 2024, §3.3 "Upper Body Editing") tokenizes
the upper and the lower body apart; MotionDiffuse's body-part control (Zhang et al. 2022) mixes
per-part predictions with feature masks. Both need the same thing: which of the 263 (T2M) or 251
(KIT) dimensions belong to which part. A part is a set of joints; it owns each of its joints' RIC
position (3), 6D rotation (6) and velocity (3) dimensions. The root's four dimensions (yaw
velocity, linear velocity, height) and the four foot contacts go with the lower body, which carries
the body through space — MMM's split (107 + 156 dimensions on T2M).

The parts of a skeleton partition its dimensions, so :func:`split` and :func:`merge` are inverses.
"""

from __future__ import annotations

from functools import cache

import numpy as np

from m2d2m.motion.representation.skeleton import KIT, SKELETONS, T2M, Skeleton

FULL = "full"  # the whole body: every dimension, the default of a tokenizer
UPPER, LOWER = "upper", "lower"
PARTS = (UPPER, LOWER)

# The joints of each part. T2M: SMPL's legs and pelvis below, the spine from spine1 up above
# (MMM's split); KIT: the root and both legs below, torso, head and arms above.
PART_JOINTS: dict[str, dict[str, tuple[int, ...]]] = {
    T2M.name: {LOWER: (0, 1, 2, 4, 5, 7, 8, 10, 11), UPPER: (3, 6, 9, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21)},
    KIT.name: {LOWER: (0, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20), UPPER: (1, 2, 3, 4, 5, 6, 7, 8, 9, 10)},
}
ROOT_PART = LOWER  # the part that owns the root's 4 dimensions and the 4 foot contacts


def joint_dims(skeleton: Skeleton, joint: int) -> np.ndarray:
    """The feature dimensions of one joint: its RIC position and 6D rotation (joints 1..J−1 only)
    and its velocity (every joint), in the layout of docs/representation.md."""
    j = skeleton.num_joints
    if not 0 <= joint < j:
        raise ValueError(f"skeleton {skeleton.name!r} has joints 0..{j - 1}, not {joint}")
    velocity = 4 + 9 * (j - 1) + 3 * joint
    dims = list(range(velocity, velocity + 3))
    if joint > 0:
        position, rotation = 4 + 3 * (joint - 1), 4 + 3 * (j - 1) + 6 * (joint - 1)
        dims = list(range(position, position + 3)) + list(range(rotation, rotation + 6)) + dims
    return np.asarray(dims, dtype=np.int64)


@cache
def _part_dims(skeleton_name: str, part: str) -> tuple[int, ...]:
    skeleton = SKELETONS[skeleton_name]
    dims = [joint_dims(skeleton, joint) for joint in PART_JOINTS[skeleton_name][part]]
    if part == ROOT_PART:
        width = skeleton.feature_dim
        dims += [np.arange(4), np.arange(width - 4, width)]
    return tuple(int(d) for d in np.sort(np.concatenate(dims)))


def part_dims(skeleton: Skeleton, part: str) -> np.ndarray:
    """The sorted feature dimensions of ``part`` (``full``: all of them); ValueError for a part
    the skeleton does not have."""
    if part == FULL:
        return np.arange(skeleton.feature_dim)
    if skeleton.name not in PART_JOINTS or part not in PART_JOINTS[skeleton.name]:
        raise ValueError(
            f"unknown body part {part!r} for skeleton {skeleton.name!r}: choose one of {', '.join((FULL, *PARTS))}"
        )
    return np.asarray(_part_dims(skeleton.name, part), dtype=np.int64)


def part_mask(skeleton: Skeleton, part: str) -> np.ndarray:
    """(D,) bool, True on ``part``'s dimensions."""
    mask = np.zeros(skeleton.feature_dim, dtype=bool)
    mask[part_dims(skeleton, part)] = True
    return mask


def part_joints(skeleton: Skeleton, part: str) -> np.ndarray:
    """The joints of ``part`` (``full``: every joint)."""
    if part == FULL:
        return np.arange(skeleton.num_joints)
    part_dims(skeleton, part)  # the one check of the name
    return np.asarray(PART_JOINTS[skeleton.name][part], dtype=np.int64)


def skeleton_of_width(width: int) -> Skeleton:
    """The skeleton whose features are ``width`` wide (263: T2M, 251: KIT)."""
    for skeleton in SKELETONS.values():
        if skeleton.feature_dim == width:
            return skeleton
    raise ValueError(
        f"no skeleton has {width}-d features; body parts are defined for "
        + ", ".join(f"{s.name} ({s.feature_dim})" for s in SKELETONS.values())
    )


def split(features: np.ndarray, skeleton: Skeleton) -> dict[str, np.ndarray]:
    """Each part's columns of ``features`` (..., D), by part name."""
    if features.shape[-1] != skeleton.feature_dim:
        raise ValueError(
            f"expected {skeleton.feature_dim}-d features of skeleton {skeleton.name!r}, got {features.shape[-1]}"
        )
    return {part: features[..., part_dims(skeleton, part)] for part in PARTS}


def merge(parts: dict[str, np.ndarray], skeleton: Skeleton) -> np.ndarray:
    """Full features (..., D) from every part's columns: the inverse of :func:`split`."""
    missing = sorted(set(PARTS) - set(parts))
    if missing:
        raise ValueError(f"merging needs every body part; {', '.join(missing)} missing")
    first = parts[PARTS[0]]
    merged = np.zeros(first.shape[:-1] + (skeleton.feature_dim,), dtype=first.dtype)
    for part in PARTS:
        merged[..., part_dims(skeleton, part)] = parts[part]
    return merged
