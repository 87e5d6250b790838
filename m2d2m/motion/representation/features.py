"""HumanML3D's motion representation: joints ⇄ 263-d (T2M) / 251-d (KIT) features, and mirroring.

Feature layout per frame, J joints (docs/representation.md, "Feature layout"; HumanML3D's
``motion_representation.ipynb``, EricGuo5513/HumanML3D)::

    [0]                 root angular velocity about Y (HALF the per-frame yaw change, rad)
    [1:3]               root linear velocity (x, z) in the heading frame of the next frame
    [3]                 root height
    [4 : 4+3(J−1)]      root-relative joint positions in the heading frame (RIC), joints 1..J−1
    [.. : +6(J−1)]      continuous-6D local rotations of joints 1..J−1
    [.. : +3J]          joint velocities in the heading frame, joints 0..J−1
    [−4:]               foot contacts: left (2 joints), right (2 joints)

The numbers must match HumanML3D's, quirks included, so that its Mean/Std, pretrained VQ-VAEs
and evaluators stay valid: the heading used for features comes from the *left−right* hips plus
the *right−left* shoulders (a swapped unpacking in the reference IK), it is Gaussian-smoothed over
time with sigma 20 frames, frame 0's heading is forced to identity, and dimension 0 is
``arcsin(q_y)`` of the per-frame heading change, i.e. half the yaw angle.
"""

from __future__ import annotations

import re

import numpy as np
import torch

from m2d2m.motion.representation.rotations import cross, dot, normalize, qbetween, qinv, qmul, qrot, quat_to_cont6d
from m2d2m.motion.representation.skeleton import T2M, Skeleton
from m2d2m.motion.representation.smoothing import gaussian_smooth

HEADING_SMOOTHING_SIGMA = 20.0
_UP = np.array([0.0, 1.0, 0.0])
_FORWARD = np.array([0.0, 0.0, 1.0])


def _heading_forward(joints: np.ndarray, hip_a: int, hip_b: int, skeleton: Skeleton) -> np.ndarray:
    """Unnormalised horizontal forward direction: up × (hip_a − hip_b + r_shoulder − l_shoulder)."""
    r_shoulder, l_shoulder = skeleton.face_joints[2], skeleton.face_joints[3]
    across = (joints[..., hip_a, :] - joints[..., hip_b, :]) + (joints[..., r_shoulder, :] - joints[..., l_shoulder, :])
    return cross(_UP, normalize(across))


def facing_direction(joints: np.ndarray, skeleton: Skeleton = T2M) -> np.ndarray:
    """The body's horizontal forward direction (..., 3), unit length, from hips and shoulders."""
    r_hip, l_hip = skeleton.face_joints[0], skeleton.face_joints[1]
    return normalize(_heading_forward(joints, r_hip, l_hip, skeleton))


def retarget(joints: np.ndarray, skeleton: Skeleton, bone_lengths: np.ndarray) -> np.ndarray:
    """Keep every bone's direction, give it the target length, and scale the root trajectory by
    the ratio of leg lengths (HumanML3D's ``uniform_skeleton``, whose IK→FK does exactly this)."""
    source_lengths = skeleton.bone_lengths_of(joints[0])
    scale = skeleton.leg_length(bone_lengths) / skeleton.leg_length(source_lengths)
    bones = skeleton.bones
    direction = np.zeros_like(joints)
    delta = joints[:, bones] - joints[:, skeleton.parents[bones]]
    direction[:, bones] = normalize(delta)
    bone_vectors = direction * bone_lengths[:, None]
    return joints[:, :1] * scale + skeleton.ancestors @ bone_vectors


def canonicalize(joints: np.ndarray, skeleton: Skeleton = T2M, target_offsets: np.ndarray | None = None) -> np.ndarray:
    """HumanML3D's global positions: target skeleton, feet on the floor, frame-0 root above the
    origin, frame-0 body facing +Z. Returns float64 (T, J, 3)."""
    positions = np.asarray(joints, dtype=np.float64)
    lengths = (
        skeleton.bone_lengths
        if target_offsets is None
        else np.linalg.norm(np.asarray(target_offsets, dtype=np.float64), axis=-1)
    )
    positions = retarget(positions, skeleton, lengths)
    positions[..., 1] -= positions[..., 1].min()
    positions -= positions[0, 0] * np.array([1.0, 0.0, 1.0])
    face_z = qbetween(facing_direction(positions[0], skeleton), _FORWARD)
    return qrot(face_z, positions)


def heading_quaternions(positions: np.ndarray, skeleton: Skeleton = T2M) -> np.ndarray:
    """Per-frame root rotation taking the (smoothed) body forward onto +Z, frame 0 = identity.

    Uses the reference's swapped hips (left − right) on purpose; see the module docstring.
    """
    r_hip, l_hip = skeleton.face_joints[0], skeleton.face_joints[1]
    forward = _heading_forward(positions, l_hip, r_hip, skeleton)
    forward = normalize(gaussian_smooth(forward, HEADING_SMOOTHING_SIGMA))
    heading = qbetween(forward, _FORWARD)
    heading[0] = (1.0, 0.0, 0.0, 0.0)
    return heading


def foot_contacts(positions: np.ndarray, skeleton: Skeleton = T2M) -> np.ndarray:
    """(T−1, 4) contact flags [left..., right...]: squared displacement to the next frame below
    the skeleton's threshold."""
    feet = list(skeleton.feet_left + skeleton.feet_right)
    step = positions[1:, feet] - positions[:-1, feet]
    return (dot(step, step) < skeleton.contact_threshold).astype(np.float64)


def joints_to_features(
    joints: np.ndarray, skeleton: Skeleton = T2M, target_offsets: np.ndarray | None = None
) -> np.ndarray:
    """HumanML3D features (T−1, D) float32 of one clip of joint positions (T, J, 3).

    ``target_offsets`` (J, 3) overrides the skeleton's default target bone lengths (for KIT-ML,
    the corpus's own reference skeleton). Computation runs in float64, vectorised over frames.
    """
    skeleton.check_joints(joints, min_frames=2)  # velocities need two frames
    positions = canonicalize(joints, skeleton, target_offsets)
    num_frames = len(positions)

    heading = heading_quaternions(positions, skeleton)
    local_rot = skeleton.inverse_kinematics(positions, heading)
    rotations_6d = quat_to_cont6d(local_rot[:, 1:]).reshape(num_frames, -1)

    root = positions[:, 0]
    root_velocity = qrot(heading[1:], root[1:] - root[:-1])[:, [0, 2]]
    heading_change = qmul(heading[1:], qinv(heading[:-1]))
    root_yaw_velocity = np.arcsin(np.clip(heading_change[:, 2:3], -1.0, 1.0))

    centred = positions - root[:, None] * np.array([1.0, 0.0, 1.0])
    ric = qrot(heading[:, None], centred)
    local_velocity = qrot(heading[:-1, None], positions[1:] - positions[:-1])

    features = np.concatenate(
        [
            root_yaw_velocity,
            root_velocity,
            ric[:-1, 0, 1:2],
            ric[:-1, 1:].reshape(num_frames - 1, -1),
            rotations_6d[:-1],
            local_velocity.reshape(num_frames - 1, -1),
            foot_contacts(positions, skeleton),
        ],
        axis=-1,
    )
    return features.astype(np.float32)


def _recover_from_ric(features: torch.Tensor, num_joints: int) -> torch.Tensor:
    yaw_velocity = features[..., 0]
    # The heading of frame t is the sum of the half-angles before it.
    half_yaw = torch.cumsum(torch.nn.functional.pad(yaw_velocity[..., :-1], (1, 0)), dim=-1)
    # Undoing the heading is a rotation by −2·half_yaw about Y (the heading quaternion
    # (cos h, 0, sin h, 0) turns by 2h): x' = x cos − z sin, z' = x sin + z cos at angle 2h.
    cos, sin = torch.cos(2 * half_yaw), torch.sin(2 * half_yaw)

    def to_world(x: torch.Tensor, z: torch.Tensor, c: torch.Tensor, s: torch.Tensor):
        return x * c - z * s, x * s + z * c

    step = torch.nn.functional.pad(features[..., :-1, 1:3], (0, 0, 1, 0))
    step_x, step_z = to_world(step[..., 0], step[..., 1], cos, sin)
    root_x, root_z = torch.cumsum(step_x, dim=-1), torch.cumsum(step_z, dim=-1)
    root = torch.stack([root_x, features[..., 3], root_z], dim=-1)

    ric = features[..., 4 : 4 + (num_joints - 1) * 3].unflatten(-1, (num_joints - 1, 3))
    x, z = to_world(ric[..., 0], ric[..., 2], cos[..., None], sin[..., None])
    others = torch.stack([x + root_x[..., None], ric[..., 1], z + root_z[..., None]], dim=-1)
    return torch.cat([root[..., None, :], others], dim=-2)


def features_to_joints(features: np.ndarray | torch.Tensor, skeleton: Skeleton = T2M):
    """Joint positions (..., T, J, 3) from features (..., T, D) — HumanML3D's ``recover_from_ric``.

    Integrates the root's yaw and velocity and places the RIC positions around it. Accepts a
    NumPy array (returns one) or a tensor on any device (differentiable; returns a tensor).
    """
    if features.shape[-1] != skeleton.feature_dim:
        raise ValueError(
            f"expected {skeleton.feature_dim}-d features for skeleton {skeleton.name!r}, got {features.shape[-1]}"
        )
    if isinstance(features, torch.Tensor):
        return _recover_from_ric(features, skeleton.num_joints)
    return _recover_from_ric(torch.from_numpy(np.asarray(features)), skeleton.num_joints).numpy()


def mirror_joints(joints: np.ndarray, skeleton: Skeleton = T2M) -> np.ndarray:
    """Left–right mirror image (..., T, J, 3): x negated, left and right joints swapped."""
    mirrored = np.asarray(joints)[..., skeleton.mirror_permutation, :].copy()
    mirrored[..., 0] *= -1
    return mirrored


_MIRROR_WORDS = {
    "left": "right",
    "right": "left",
    "leftward": "rightward",
    "rightward": "leftward",
    "leftwards": "rightwards",
    "rightwards": "leftwards",
    "lefthand": "righthand",
    "righthand": "lefthand",
    "clockwise": "counterclockwise",
    "counterclockwise": "clockwise",
    "counter-clockwise": "clockwise",
    "anticlockwise": "clockwise",
    "anti-clockwise": "clockwise",
}
_MIRROR_PATTERN = re.compile(
    r"(?<!\w)(" + "|".join(sorted(map(re.escape, _MIRROR_WORDS), key=len, reverse=True)) + r")(?!\w)",
    re.IGNORECASE,
)


def _match_case(word: str, template: str) -> str:
    if template.isupper() and len(template) > 1:
        return word.upper()
    if template[:1].isupper():
        return word[:1].upper() + word[1:]
    return word


def mirror_caption(text: str) -> str:
    """The caption of the mirrored motion: left↔right, clockwise↔counterclockwise and their
    variants swapped as whole words, case and everything else kept (works on tagged tokens too:
    ``left/ADJ`` → ``right/ADJ``)."""
    return _MIRROR_PATTERN.sub(lambda m: _match_case(_MIRROR_WORDS[m.group(1).lower()], m.group(1)), text)
