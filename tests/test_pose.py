"""The rig's form of a clip (m2d2m/motion/representation/pose.py): forward kinematics of the rotations made from
a rigid clip gives the clip back, on either bind pose, and the bind pose keeps the clip's bones."""

from __future__ import annotations

import numpy as np
import pytest

from m2d2m.motion.representation.pose import pose_of
from m2d2m.motion.representation.skeleton import KIT, T2M
from tests.test_export import build_rigid_clip


@pytest.mark.parametrize("skeleton", [T2M, KIT], ids=lambda s: s.name)
@pytest.mark.parametrize("rest_pose", ["skeleton", "tpose"])
def test_forward_kinematics_of_the_pose_is_the_clip(skeleton, rest_pose):
    joints, _ = build_rigid_clip(skeleton, n_frames=25)
    pose = pose_of(joints, skeleton, rest_pose=rest_pose)
    assert np.abs(pose.joints() - joints).max() < 1e-6 * skeleton.bone_lengths.max()
    bones = skeleton.bones
    np.testing.assert_allclose(
        np.linalg.norm(pose.offsets[bones], axis=-1), skeleton.bone_lengths_of(joints)[0, bones], rtol=1e-6
    )
    rotations = pose.local
    np.testing.assert_allclose(
        rotations @ np.swapaxes(rotations, -1, -2), np.broadcast_to(np.eye(3), rotations.shape), atol=1e-9
    )
    np.testing.assert_allclose(np.linalg.det(rotations), 1.0, atol=1e-9)


def test_an_unknown_bind_pose_is_refused():
    joints, _ = build_rigid_clip(T2M, n_frames=3)
    with pytest.raises(ValueError, match="rest_pose must be one of skeleton, tpose"):
        pose_of(joints, T2M, rest_pose="apose")
