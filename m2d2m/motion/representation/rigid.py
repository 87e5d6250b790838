"""One rigid body per clip: the bone-length spread of joint positions, and the joints put on one
rigid skeleton so that every file of a clip shows the same body.

Joints decoded from HumanML3D features are root-relative positions, not rotations of a skeleton,
so nothing keeps a bone's length from frame to frame (a generated four-action clip measured up to
35 mm of standard deviation on one bone). A BVH has one skeleton — fixed offsets, rotations per
frame — so a BVH fitted to such joints cannot place them where the ``.npy`` and the GIF have them.
:func:`on_rigid_skeleton` removes the difference before any file is written.

The rigid bodies are those of the BVH hierarchy (:mod:`m2d2m.motion.files.export`): a joint with one
child turns its bone freely, and the children of a joint with several (T2M's pelvis and upper
spine) move as one rigid shape, their generalised-Procrustes mean (Gower, 1975).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from m2d2m.motion.representation.skeleton import Skeleton

_PROCRUSTES_ITERATIONS = 3
_SHORTEST_BONE = 1e-9  # a bone this short has no direction: it takes its rest direction


def best_fit_rotation(rest: np.ndarray, actual: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) minimising Σ‖R·rest_n − actual_n‖² (Kabsch, via SVD)
    for point sets rest (N, 3) and actual (..., N, 3) without translation (both are offsets)."""
    cov = np.einsum("ni,...nj->...ij", rest, actual)
    u, _, vt = np.linalg.svd(cov)
    v, ut = np.swapaxes(vt, -1, -2), np.swapaxes(u, -1, -2)
    reflect = np.where(np.linalg.det(v @ ut) < 0, -1.0, 1.0)  # keep a proper rotation
    v[..., :, 2] *= reflect[..., None]
    return v @ ut


def rigid_shape(actual: np.ndarray, start: np.ndarray) -> np.ndarray:
    """The rigid shape (N, 3) that best explains the offsets ``actual`` (T, N, 3) of every frame
    up to a rotation: alternate the per-frame best-fit rotation and the mean shape in the part's
    frame, from ``start`` (one round is exact when the part is rigid)."""
    shape = start
    for _ in range(_PROCRUSTES_ITERATIONS):
        rot = best_fit_rotation(shape, actual)
        shape = np.einsum("tji,tnj->ni", rot, actual) / len(actual)
    return shape


def children(skeleton: Skeleton | np.ndarray) -> list[list[int]]:
    """Each joint's child joints, of a skeleton or of any rig's parents array (-1 for the root)."""
    parents = np.asarray(skeleton.parents if isinstance(skeleton, Skeleton) else skeleton)
    return [np.flatnonzero(parents == j).tolist() for j in range(len(parents))]


def bone_length_spread(joints: np.ndarray, skeleton: Skeleton) -> dict[str, float]:
    """How far a clip is from one skeleton: each bone's standard deviation of length over the
    frames, in millimetres, as the mean and the max over bones (0 for a rigid body)."""
    lengths = skeleton.bone_lengths_of(skeleton.check_joints(joints))[:, skeleton.bones]
    spread = lengths.std(axis=0) * skeleton.metres_per_unit * 1000.0
    return {"mean": float(spread.mean()), "max": float(spread.max())}


def on_rigid_skeleton(
    joints: np.ndarray,
    skeleton: Skeleton,
    bone_lengths: np.ndarray | None = None,
    shapes: dict[int, np.ndarray] | None = None,
) -> np.ndarray:
    """Joints (T, J, 3) on one rigid skeleton with ``bone_lengths`` (default: the skeleton's
    target lengths, to which the data pipeline retargets every corpus clip — HumanML3D's
    ``uniform_skeleton`` — so they are the body the model was trained on).

    Walking the tree from the root: the root path is kept; a joint with one child keeps its
    bone's direction in every frame and gets the bone's length; the children of a joint with
    several become one rigid shape — ``shapes[joint]`` when given (another clip's body, as
    :func:`rigid_shapes` measured it), else their mean shape here (directions scaled to the
    lengths first) — turned in each frame by its best-fit rotation onto the frame's directions.
    """
    joints = skeleton.check_joints(joints)
    lengths = np.asarray(skeleton.bone_lengths if bone_lengths is None else bone_lengths, dtype=np.float64)
    out = np.empty_like(joints)
    root = int(np.flatnonzero(skeleton.parents < 0)[0])
    out[:, root] = joints[:, root]
    shapes = shapes or {}
    for joint, kids, bones in _scaled_bones(joints, skeleton, lengths):
        if len(kids) > 1:
            shape = shapes[joint] if joint in shapes else _mean_shape(bones, skeleton, lengths, kids)
            bones = np.einsum("tij,nj->tni", best_fit_rotation(shape, bones), shape)
        out[:, kids] = out[:, [joint]] + bones
    return out


def rigid_shapes(
    joints: np.ndarray, skeleton: Skeleton, bone_lengths: np.ndarray | None = None
) -> dict[int, np.ndarray]:
    """The rigid shape :func:`on_rigid_skeleton` gives the children of each joint with several
    (T2M's pelvis and upper spine) for ``joints``: given back to it for another clip, that clip's
    frames come out as these would (an edit's kept frames as its source had them)."""
    joints = skeleton.check_joints(joints)
    lengths = np.asarray(skeleton.bone_lengths if bone_lengths is None else bone_lengths, dtype=np.float64)
    return {
        joint: _mean_shape(bones, skeleton, lengths, kids)
        for joint, kids, bones in _scaled_bones(joints, skeleton, lengths)
        if len(kids) > 1
    }


def _scaled_bones(
    joints: np.ndarray, skeleton: Skeleton, lengths: np.ndarray
) -> Iterator[tuple[int, list[int], np.ndarray]]:
    """For each joint with children, root first: the joint, its children and their bones (T, N, 3),
    each in its direction in the frame (its rest direction where it has none) at its length."""
    kids_of = children(skeleton)
    root = int(np.flatnonzero(skeleton.parents < 0)[0])
    for joint in [root, *skeleton.bones.tolist()]:
        kids = kids_of[joint]
        if not kids:
            continue
        delta = joints[:, kids] - joints[:, [joint]]
        norm = np.linalg.norm(delta, axis=-1, keepdims=True)
        direction = np.where(
            norm > _SHORTEST_BONE, delta / np.maximum(norm, _SHORTEST_BONE), skeleton.raw_offsets[kids]
        )
        yield joint, kids, direction * lengths[kids, None]


def _mean_shape(bones: np.ndarray, skeleton: Skeleton, lengths: np.ndarray, kids: list[int]) -> np.ndarray:
    """The rigid mean shape of ``bones`` (T, N, 3), each bone at its length."""
    shape = rigid_shape(bones, skeleton.offsets(lengths)[kids])
    return shape * lengths[kids, None] / np.maximum(np.linalg.norm(shape, axis=-1, keepdims=True), _SHORTEST_BONE)
