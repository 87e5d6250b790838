"""Statistics and normalisation, checked against HumanML3D's published Mean/Std."""

import numpy as np
import torch

from m2d2m.motion.representation.normalization import Normalizer, RunningMoments, feature_groups, group_averaged_std
from m2d2m.motion.representation.skeleton import KIT, T2M


def test_groups_tile_the_feature_vector():
    for skeleton in (T2M, KIT):
        groups = feature_groups(skeleton)
        assert groups[0].start == 0 and groups[-1].stop == skeleton.feature_dim
        assert all(a.stop == b.start for a, b in zip(groups[:-1], groups[1:]))


def test_published_humanml3d_std_is_constant_within_our_groups(humanml3d_sample):
    std = np.load(humanml3d_sample / "Std.npy")
    for group in feature_groups(T2M):
        np.testing.assert_allclose(std[group], std[group][0], rtol=1e-6)
    np.testing.assert_allclose(group_averaged_std(std, T2M), std, rtol=1e-6)
    # The group values the reference notes list, in feature order.
    np.testing.assert_allclose(
        [std[g][0] for g in feature_groups(T2M)],
        [0.01283, 0.01693, 0.15377, 0.12224, 0.29969, 0.01947, 0.35593],
        atol=5e-5,
    )


def test_running_moments_match_numpy_and_merge_exactly():
    rng = np.random.default_rng(0)
    clips = [rng.normal(loc=2.0, size=(n, 6)) for n in (5, 9, 13)]
    whole = np.concatenate(clips)
    first, second = RunningMoments(6), RunningMoments(6)
    first.add(clips[0])
    for clip in clips[1:]:
        second.add(clip)
    first.merge(second)
    np.testing.assert_allclose(first.mean(), whole.mean(0), atol=1e-12)
    np.testing.assert_allclose(first.std(), whole.std(0), atol=1e-12)


def test_feat_bias_scales_only_root_and_contacts(sample_features, humanml3d_sample):
    mean = np.load(humanml3d_sample / "Mean.npy")
    std = np.load(humanml3d_sample / "Std.npy")
    normalizer = Normalizer(mean, std, feat_bias=5.0)
    expected = std.copy()
    expected[:4] /= 5.0
    expected[259:] /= 5.0
    np.testing.assert_allclose(normalizer.scale, expected, rtol=1e-6)
    normalized = normalizer.normalize(sample_features)
    np.testing.assert_allclose(normalized, (sample_features - mean) / expected, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(normalizer.denormalize(normalized), sample_features, atol=1e-5)
    as_tensor = normalizer.normalize(torch.from_numpy(sample_features))
    np.testing.assert_allclose(as_tensor.numpy(), normalized, atol=1e-6)


def test_normalizer_saves_and_loads(tmp_path):
    normalizer = Normalizer(np.arange(263, dtype=np.float32), np.ones(263, np.float32), feat_bias=3.0)
    normalizer.save(tmp_path / "stats.npz")
    loaded = Normalizer.load(tmp_path / "stats.npz")
    np.testing.assert_array_equal(loaded.mean, normalizer.mean)
    assert loaded.feat_bias == 3.0
