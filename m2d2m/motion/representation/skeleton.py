"""The two skeletons of the motion-language corpora: HumanML3D's ``T2M`` and KIT-ML's ``KIT``.

A :class:`Skeleton` holds every constant the representation needs (facts from HumanML3D's
``paramUtil.py`` and ``motion_representation.ipynb``) and the swing-only kinematics that
HumanML3D uses: inverse kinematics from joint positions to per-joint quaternions and the forward
kinematics that undoes it. All kinematics are vectorised over frames and joints.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from m2d2m.motion.representation.rotations import dot, normalize, qbetween, qinv, qmul, qrot


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A kinematic tree with HumanML3D's processing constants.

    ``raw_offsets`` are the rest-pose bone directions (unit axes) and ``bone_lengths`` the
    default target lengths of the bone from each joint's parent (0 for the root), in the
    corpus's units. ``face_joints`` is HumanML3D's ``face_joint_indx`` (r_hip, l_hip, r_shoulder,
    l_shoulder), ``feet_left`` / ``feet_right`` the joints whose velocity gives foot contacts.
    """

    name: str
    joint_names: tuple[str, ...]
    chains: tuple[tuple[int, ...], ...]
    raw_offsets: np.ndarray = field(repr=False)
    bone_lengths: np.ndarray = field(repr=False)
    fps: float
    face_joints: tuple[int, int, int, int]
    feet_left: tuple[int, int]
    feet_right: tuple[int, int]
    leg_joints: tuple[int, int]
    contact_threshold: float
    left_joints: tuple[int, ...]
    right_joints: tuple[int, ...]
    metres_per_unit: float = 1.0
    # bone directions that differ from ``raw_offsets`` in a T-pose: HumanML3D's rest hangs the arms
    # down from the collars and points the head bone forward, where animation tools expect the arms
    # straight out to the sides and the head up (a rig's bind pose; issue 38)
    tpose_changes: tuple[tuple[int, tuple[float, float, float]], ...] = ()

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def feature_dim(self) -> int:
        """``4 + (J−1)·3 + (J−1)·6 + J·3 + 4``: 263 for T2M, 251 for KIT."""
        j = self.num_joints
        return 4 + (j - 1) * 9 + j * 3 + 4

    @cached_property
    def parents(self) -> np.ndarray:
        """Parent of each joint (−1 for the root), derived from the chains."""
        parents = np.full(self.num_joints, -1, dtype=np.int64)
        for chain in self.chains:
            for parent, child in zip(chain[:-1], chain[1:]):
                parents[child] = parent
        return parents

    @cached_property
    def bones(self) -> np.ndarray:
        """Joints that have a parent, in an order where every parent comes before its children."""
        return np.array([c for chain in self.chains for c in chain[1:]], dtype=np.int64)

    @cached_property
    def ancestors(self) -> np.ndarray:
        """(J, J) matrix with 1 at [j, b] when the bone ending at joint b lies on the path from
        the root to joint j: joint positions are ``root + ancestors @ bone_vectors``."""
        matrix = np.zeros((self.num_joints, self.num_joints))
        for bone in self.bones:
            matrix[bone] = matrix[self.parents[bone]]
            matrix[bone, bone] = 1.0
        return matrix

    @cached_property
    def swing_parents(self) -> np.ndarray:
        """Whose rotation a joint's local rotation is relative to, for each joint in :attr:`bones`.

        HumanML3D restarts every chain from the root heading, so the first bone of a chain (for
        T2M, the arms that branch off the spine at joint 9) is relative to the root (−1), not to
        the bone that ends at the chain's first joint.
        """
        relative_to = np.full(self.num_joints, -1, dtype=np.int64)
        for chain in self.chains:
            for parent, child in zip(chain[1:-1], chain[2:]):
                relative_to[child] = parent
        return relative_to[self.bones]

    @cached_property
    def mirror_permutation(self) -> np.ndarray:
        """Joint index map that swaps the left and right sides."""
        perm = np.arange(self.num_joints)
        perm[list(self.left_joints)] = self.right_joints
        perm[list(self.right_joints)] = self.left_joints
        return perm

    def check_joints(self, joints: np.ndarray, min_frames: int = 1) -> np.ndarray:
        """Float64 joint positions (T, J, 3) of this skeleton, or a ValueError saying what is off."""
        joints = np.asarray(joints, dtype=np.float64)
        if joints.ndim != 3 or joints.shape[1:] != (self.num_joints, 3):
            raise ValueError(
                f"expected joints of shape (T, {self.num_joints}, 3) for skeleton {self.name!r}, got {joints.shape}"
            )
        if len(joints) < min_frames:
            raise ValueError(f"need at least {min_frames} frame(s), got {len(joints)}")
        if not np.isfinite(joints).all():
            raise ValueError("joints contain NaN or infinite values")
        return joints

    def offsets(self, bone_lengths: np.ndarray | None = None) -> np.ndarray:
        """Rest-pose offsets (J, 3): raw direction × bone length (the defaults when not given)."""
        lengths = self.bone_lengths if bone_lengths is None else np.asarray(bone_lengths)
        return self.raw_offsets * lengths[..., None]

    def tpose_offsets(self, bone_lengths: np.ndarray | None = None) -> np.ndarray:
        """T-pose offsets (J, 3): :meth:`offsets` with the arms out to the sides and the head up."""
        offsets = self.offsets(bone_lengths)
        for joint, direction in self.tpose_changes:
            offsets[joint] = np.asarray(direction) * np.linalg.norm(offsets[joint])
        return offsets

    @cached_property
    def head_joint(self) -> int:
        """The highest leaf of the rest pose: where a head is drawn to make a figure readable."""
        rest = np.zeros((self.num_joints, 3))
        for joint in self.bones:
            rest[joint] = rest[self.parents[joint]] + self.offsets()[joint]
        leaves = np.setdiff1d(np.arange(self.num_joints), self.parents)
        return int(leaves[np.argmax(rest[leaves, 1])])

    def bone_lengths_of(self, joints: np.ndarray) -> np.ndarray:
        """Bone lengths (..., J) of joint positions (..., J, 3); 0 at the root."""
        lengths = np.zeros(joints.shape[:-1])
        bones = self.bones
        delta = joints[..., bones, :] - joints[..., self.parents[bones], :]
        lengths[..., bones] = np.sqrt(dot(delta, delta))
        return lengths

    def leg_length(self, bone_lengths: np.ndarray) -> float:
        """Thigh + shin, HumanML3D's scale reference for retargeting to the target skeleton."""
        return float(bone_lengths[self.leg_joints[0]] + bone_lengths[self.leg_joints[1]])

    def inverse_kinematics(self, joints: np.ndarray, root_quat: np.ndarray) -> np.ndarray:
        """Swing-only local rotations (..., J, 4) of joint positions (..., J, 3).

        Every bone's global rotation is the shortest arc from its raw direction to its actual
        direction; the local rotation stored at the bone's child joint is that global rotation
        relative to :attr:`swing_parents`. Joint 0 holds ``root_quat`` (HumanML3D: the rotation
        taking the body's forward direction onto +Z). No twist is recovered.
        """
        bones = self.bones
        direction = joints[..., bones, :] - joints[..., self.parents[bones], :]
        direction = normalize(direction)
        global_rot = np.empty(joints.shape[:-1] + (4,))
        global_rot[..., 0, :] = root_quat
        global_rot[..., bones, :] = qbetween(self.raw_offsets[bones], direction)
        relative_to = np.where(self.swing_parents < 0, 0, self.swing_parents)
        local = np.empty_like(global_rot)
        local[..., 0, :] = root_quat
        local[..., bones, :] = qmul(qinv(global_rot[..., relative_to, :]), global_rot[..., bones, :])
        return local

    def forward_kinematics(
        self, local_rot: np.ndarray, root_position: np.ndarray, offsets: np.ndarray | None = None
    ) -> np.ndarray:
        """Joint positions (..., J, 3) from local rotations (..., J, 4) in HumanML3D's convention
        (the inverse of :meth:`inverse_kinematics`), root positions (..., 3) and offsets (J, 3)."""
        offsets = self.offsets() if offsets is None else offsets
        global_rot = np.empty_like(local_rot)
        joints = np.empty(local_rot.shape[:-1] + (3,))
        joints[..., 0, :] = root_position
        for chain in self.chains:
            rot = local_rot[..., 0, :]
            for parent, child in zip(chain[:-1], chain[1:]):
                rot = qmul(rot, local_rot[..., child, :])
                global_rot[..., child, :] = rot
                joints[..., child, :] = joints[..., parent, :] + qrot(rot, offsets[child])
        return joints


_X, _Y, _Z = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)
_NX, _NY = (-1.0, 0.0, 0.0), (0.0, -1.0, 0.0)

T2M = Skeleton(
    name="t2m",
    joint_names=(
        "pelvis",
        "left_hip",
        "right_hip",
        "spine1",
        "left_knee",
        "right_knee",
        "spine2",
        "left_ankle",
        "right_ankle",
        "spine3",
        "left_foot",
        "right_foot",
        "neck",
        "left_collar",
        "right_collar",
        "head",
        "left_shoulder",
        "right_shoulder",
        "left_elbow",
        "right_elbow",
        "left_wrist",
        "right_wrist",
    ),
    chains=(
        (0, 2, 5, 8, 11),
        (0, 1, 4, 7, 10),
        (0, 3, 6, 9, 12, 15),
        (9, 14, 17, 19, 21),
        (9, 13, 16, 18, 20),
    ),
    raw_offsets=np.array(
        [
            (0.0, 0.0, 0.0),
            _X,
            _NX,
            _Y,
            _NY,
            _NY,
            _Y,
            _NY,
            _NY,
            _Y,
            _Z,
            _Z,
            _Y,
            _X,
            _NX,
            _Z,
            _NY,
            _NY,
            _NY,
            _NY,
            _NY,
            _NY,
        ]
    ),
    # Bone lengths of HumanML3D's target skeleton (first frame of clip 000021), in metres, as
    # measured on the processed sample clip 012314 (identical in every frame to 2.5e-7).
    bone_lengths=np.array(
        [
            0.0,
            0.103074,
            0.109883,
            0.131568,
            0.393623,
            0.390188,
            0.143190,
            0.432433,
            0.425643,
            0.057365,
            0.143382,
            0.149419,
            0.219360,
            0.137487,
            0.143383,
            0.103039,
            0.131614,
            0.122984,
            0.256840,
            0.263092,
            0.266012,
            0.269876,
        ]
    ),
    fps=20.0,
    face_joints=(2, 1, 17, 16),
    feet_left=(7, 10),
    feet_right=(8, 11),
    leg_joints=(5, 8),
    contact_threshold=0.002,
    left_joints=(1, 4, 7, 10, 13, 16, 18, 20),
    right_joints=(2, 5, 8, 11, 14, 17, 19, 21),
    # the character's left is +X: shoulder to elbow to wrist along +X (left) and −X (right)
    tpose_changes=((15, _Y), (16, _X), (18, _X), (20, _X), (17, _NX), (19, _NX), (21, _NX)),
)

KIT = Skeleton(
    name="kit",
    joint_names=(
        "root",
        "BP",
        "BT",
        "BLN",
        "BUN",
        "LS",
        "LE",
        "LW",
        "RS",
        "RE",
        "RW",
        "LH",
        "LK",
        "LA",
        "LMrot",
        "LF",
        "RH",
        "RK",
        "RA",
        "RMrot",
        "RF",
    ),
    chains=(
        (0, 11, 12, 13, 14, 15),
        (0, 16, 17, 18, 19, 20),
        (0, 1, 2, 3, 4),
        (3, 5, 6, 7),
        (3, 8, 9, 10),
    ),
    raw_offsets=np.array(
        [(0.0, 0.0, 0.0), _Y, _Y, _Y, _Y, _X, _NY, _NY, _NX, _NY, _NY, _X, _NY, _NY, _Z, _Z, _NX, _NY, _NY, _Z, _Z]
    ),
    # KIT's target skeleton (first frame of clip 03950) is not public. These defaults are
    # adult proportions close to the T2M target, in KIT's units (about 640 per metre, SINC's
    # 480/0.75): right for synthetic data and tests; for real KIT-ML pass the corpus's own target.
    bone_lengths=np.array(
        [
            0.0,
            0.13,
            0.20,
            0.22,
            0.10,
            0.18,
            0.26,
            0.27,
            0.18,
            0.26,
            0.27,
            0.10,
            0.39,
            0.43,
            0.07,
            0.07,
            0.10,
            0.39,
            0.43,
            0.07,
            0.07,
        ]
    )
    * 640.0,
    fps=12.5,
    face_joints=(11, 16, 5, 8),
    feet_left=(19, 20),
    feet_right=(14, 15),
    leg_joints=(17, 18),
    contact_threshold=0.05,
    left_joints=(5, 6, 7, 11, 12, 13, 14, 15),
    right_joints=(8, 9, 10, 16, 17, 18, 19, 20),
    metres_per_unit=1.0 / 640.0,
    tpose_changes=((6, _X), (7, _X), (9, _NX), (10, _NX)),  # elbows and wrists; KIT's head (BUN) is up already
)

SKELETONS: dict[str, Skeleton] = {s.name: s for s in (T2M, KIT)}
