"""Parity of the motion representation with HumanML3D's real files, and its invariants."""

import numpy as np
import pytest
import torch

from m2d2m.motion.representation.features import (
    canonicalize,
    features_to_joints,
    gaussian_smooth,
    joints_to_features,
    mirror_caption,
    mirror_joints,
)
from m2d2m.motion.representation.rotations import qrot, quat_from_axis_angle
from m2d2m.motion.representation.skeleton import KIT, T2M
from tests.helpers import pose_clip

# The sample's joints are HumanML3D's own output, one frame shorter than the clip its features
# were computed from. The heading is smoothed with sigma 20 (kernel radius 80): feature row t
# uses the headings of frames t and t+1, so rows with t + 1 + 80 <= 169 (the last frame we have)
# see exactly the same window as the reference did. Later rows see a window clipped one frame
# earlier and may differ.
UNAFFECTED_ROWS = slice(0, 89)


def test_features_to_joints_reproduces_humanml3d_joints(sample_features, sample_joints):
    joints = features_to_joints(sample_features)
    assert joints.dtype == np.float32 and joints.shape == (170, 22, 3)
    np.testing.assert_allclose(joints, sample_joints, atol=1e-5)


def test_joints_to_features_reproduces_humanml3d_features(sample_joints, sample_features):
    features = joints_to_features(sample_joints)
    assert features.dtype == np.float32 and features.shape == (169, 263)
    reference = sample_features[:-1]
    np.testing.assert_allclose(features[UNAFFECTED_ROWS], reference[UNAFFECTED_ROWS], atol=1e-4)
    # Beyond the smoothing boundary only heading-dependent groups drift, and only a little;
    # root height and foot contacts do not depend on the heading at all.
    np.testing.assert_array_equal(features[:, 259:], reference[:, 259:])
    np.testing.assert_allclose(features[:, 3], reference[:, 3], atol=1e-5)
    assert np.abs(features - reference).max() < 0.05


def test_features_to_joints_on_torch_batches_matches_numpy_and_is_differentiable(sample_features):
    batch = torch.from_numpy(np.stack([sample_features, sample_features[::-1].copy()]))
    batch.requires_grad_(True)
    joints = features_to_joints(batch)
    assert isinstance(joints, torch.Tensor) and joints.shape == (2, 170, 22, 3)
    np.testing.assert_allclose(joints[0].detach().numpy(), features_to_joints(sample_features), atol=1e-6)
    joints.sum().backward()
    assert torch.isfinite(batch.grad).all() and batch.grad.abs().sum() > 0


def test_round_trip_preserves_canonical_positions():
    joints = pose_clip(T2M, 120, seed=1)
    recovered = features_to_joints(joints_to_features(joints))
    np.testing.assert_allclose(recovered, canonicalize(joints)[:-1], atol=1e-5)


def test_bone_lengths_become_the_target_skeleton():
    joints = pose_clip(T2M, 60, seed=2) * 1.3  # a taller person
    recovered = features_to_joints(joints_to_features(joints)).astype(np.float64)
    np.testing.assert_allclose(T2M.bone_lengths_of(recovered), np.broadcast_to(T2M.bone_lengths, (59, 22)), atol=1e-5)


def test_custom_target_offsets_are_used():
    joints = pose_clip(T2M, 40, seed=3)
    target = T2M.offsets(T2M.bone_lengths * 0.9)
    recovered = features_to_joints(joints_to_features(joints, target_offsets=target))
    np.testing.assert_allclose(T2M.bone_lengths_of(recovered.astype(np.float64))[0], T2M.bone_lengths * 0.9, atol=1e-5)


def test_features_ignore_where_the_clip_starts_and_faces():
    joints = pose_clip(T2M, 80, seed=4).astype(np.float64)
    turn = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), 2.1)
    moved = qrot(turn, joints) + np.array([3.0, 0.5, -7.0])
    np.testing.assert_allclose(joints_to_features(moved), joints_to_features(joints), atol=1e-5)


def test_mirroring_negates_the_turning_and_sideways_motion():
    # HumanML3D's target skeleton is slightly asymmetric (its left and right bones differ by
    # millimetres) and the root is scaled by the right leg, so the identity is exact only for
    # a left-right symmetric body and target.
    lengths = T2M.bone_lengths.copy()
    left, right = list(T2M.left_joints), list(T2M.right_joints)
    lengths[left] = lengths[right] = 0.5 * (lengths[left] + lengths[right])
    target = T2M.offsets(lengths)
    joints = pose_clip(T2M, 80, seed=5, lengths=lengths)
    features = joints_to_features(joints, target_offsets=target)
    mirrored = joints_to_features(mirror_joints(joints), target_offsets=target)
    np.testing.assert_allclose(mirrored[:, 0], -features[:, 0], atol=1e-5)
    np.testing.assert_allclose(mirrored[:, 1], -features[:, 1], atol=1e-5)
    np.testing.assert_allclose(mirrored[:, 2:4], features[:, 2:4], atol=1e-5)


def test_mirroring_twice_is_the_identity(sample_joints):
    once = mirror_joints(sample_joints)
    assert not np.allclose(once, sample_joints)
    np.testing.assert_array_equal(mirror_joints(once), sample_joints)
    np.testing.assert_array_equal(mirror_joints(mirror_joints(sample_joints[None]))[0], sample_joints)


def test_a_body_standing_still_has_all_feet_in_contact_and_no_velocity():
    pose = pose_clip(T2M, 2, seed=6)[:1]
    features = joints_to_features(np.repeat(pose, 30, axis=0))
    np.testing.assert_array_equal(features[:, 259:], 1.0)
    np.testing.assert_allclose(features[:, :3], 0.0, atol=1e-7)
    np.testing.assert_allclose(features[:, 193:259], 0.0, atol=1e-7)


def test_kit_skeleton_gives_251_dimensions_and_round_trips():
    joints = pose_clip(KIT, 50, seed=7)
    features = joints_to_features(joints, skeleton=KIT)
    assert features.shape == (49, 251) and KIT.feature_dim == 251
    recovered = features_to_joints(features, skeleton=KIT)
    np.testing.assert_allclose(recovered, canonicalize(joints, KIT)[:-1], atol=1e-2)  # KIT units ~ mm


def test_wrong_shapes_are_rejected_with_a_clear_message():
    with pytest.raises(ValueError, match=r"\(T, 22, 3\)"):
        joints_to_features(np.zeros((10, 21, 3)))
    with pytest.raises(ValueError, match="at least 2 frame"):
        joints_to_features(np.zeros((1, 22, 3)))
    with pytest.raises(ValueError, match="263-d"):
        features_to_joints(np.zeros((10, 251), dtype=np.float32))


def test_gaussian_smoothing_matches_scipy():
    ndimage = pytest.importorskip("scipy.ndimage")
    x = np.random.default_rng(8).normal(size=(150, 3))
    expected = ndimage.gaussian_filter1d(x, 20, axis=0, mode="nearest")
    np.testing.assert_allclose(gaussian_smooth(x, 20), expected, atol=1e-12)


@pytest.mark.parametrize(
    ("caption", "mirrored"),
    [
        ("a person turns left", "a person turns right"),
        ("A man waves his Right hand, then turns LEFT.", "A man waves his Left hand, then turns RIGHT."),
        ("walks clockwise in a circle", "walks counterclockwise in a circle"),
        ("walks counter-clockwise", "walks clockwise"),
        ("spins anticlockwise", "spins clockwise"),
        ("steps leftward with the left-hand side", "steps rightward with the right-hand side"),
        ("a/DET man/NOUN raise/VERB left/ADJ arm/NOUN", "a/DET man/NOUN raise/VERB right/ADJ arm/NOUN"),
        ("the leftover bright light", "the leftover bright light"),
    ],
)
def test_mirror_caption(caption, mirrored):
    assert mirror_caption(caption) == mirrored
