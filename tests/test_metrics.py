"""Metrics checked against closed forms, hand-computed cases and independent SciPy computations."""

import re

import numpy as np
import pytest
import torch
from scipy import linalg
from scipy.spatial.distance import cdist

from m2d2m.evaluation.metrics import (
    dimensionless_jerk,
    diversity,
    fid,
    frame_jerk,
    jerk,
    mean_confidence_interval,
    mean_frame_jerk,
    mm_dist,
    multimodality,
    peak_jerk_and_auj,
    r_precision,
    student_t_quantile,
    transition_windows,
)


def _with_moments(rng: np.random.Generator, n: int, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """n samples whose sample mean and (N − 1) covariance are exactly ``mean`` and ``cov``."""
    z = rng.normal(size=(n, len(mean)))
    z -= z.mean(0)
    z = z @ np.linalg.inv(np.linalg.cholesky(np.cov(z, rowvar=False))).T
    return z @ np.linalg.cholesky(cov).T + mean


def _fid_with_sqrtm(a: np.ndarray, b: np.ndarray) -> float:
    """Guo et al.'s formula with SciPy's general matrix square root, as an independent check."""
    cov_a, cov_b = np.cov(a, rowvar=False), np.cov(b, rowvar=False)
    shift = a.mean(0) - b.mean(0)
    return float(shift @ shift + np.trace(cov_a + cov_b - 2 * linalg.sqrtm(cov_a @ cov_b).real))


# ----------------------------------------------------------------------------------------- FID


def test_fid_equals_the_closed_form_for_diagonal_gaussians():
    rng = np.random.default_rng(0)
    mean_a, mean_b = np.array([0.0, 1.0, -2.0]), np.array([0.5, 1.0, 0.0])
    var_a, var_b = np.array([1.0, 4.0, 0.25]), np.array([9.0, 1.0, 0.25])
    a = _with_moments(rng, 500, mean_a, np.diag(var_a))
    b = _with_moments(rng, 700, mean_b, np.diag(var_b))
    # ‖Δμ‖² + Σ (σa − σb)²  =  (0.25 + 0 + 4) + (4 + 1 + 0)
    assert fid(a, b) == pytest.approx(9.25, rel=1e-9)


def test_fid_of_large_gaussian_samples_approaches_the_closed_form():
    rng = np.random.default_rng(1)
    a = rng.normal([0.0, 0.0], [1.0, 2.0], size=(200_000, 2))
    b = rng.normal([1.0, 0.0], [3.0, 2.0], size=(200_000, 2))
    assert fid(a, b) == pytest.approx(1.0 + (1.0 - 3.0) ** 2, abs=0.05)


def test_fid_is_zero_for_a_set_with_itself_and_symmetric():
    rng = np.random.default_rng(2)
    a = rng.normal(size=(300, 8)) @ rng.normal(size=(8, 8))
    b = rng.normal(size=(200, 8)) + 0.3
    assert fid(a, a) == pytest.approx(0.0, abs=1e-8)
    assert fid(a, b) == pytest.approx(fid(b, a), rel=1e-9)


def test_fid_matches_scipy_sqrtm_on_correlated_data_and_takes_tensors():
    rng = np.random.default_rng(3)
    a = rng.normal(size=(400, 16)) @ rng.normal(size=(16, 16))
    b = rng.normal(size=(300, 16)) @ rng.normal(size=(16, 16)) + 1.0
    expected = _fid_with_sqrtm(a, b)
    assert fid(a, b) == pytest.approx(expected, rel=1e-6, abs=1e-6)
    assert fid(torch.tensor(a, dtype=torch.float64), torch.tensor(b)) == pytest.approx(expected, rel=1e-6)


def test_fid_stays_real_when_there_are_fewer_samples_than_dimensions():
    rng = np.random.default_rng(4)
    a, b = rng.normal(size=(10, 32)), rng.normal(size=(12, 32))
    value = fid(a, b)
    assert np.isfinite(value) and value > 0
    assert value == pytest.approx(_fid_with_sqrtm(a, b), rel=1e-5)


# ------------------------------------------------------------------------ diversity, MModality


def test_diversity_on_a_simplex_counts_only_distinct_pairs():
    # Rows of 2·I: every two distinct points are 2√2 apart, so each random pair adds 2√2 or 0.
    n = 12
    points = 2.0 * np.eye(n)
    values = np.array([diversity(points, pairs=n, seed=seed) for seed in range(400)])
    distinct_pairs = values * n / (2 * np.sqrt(2))
    np.testing.assert_allclose(distinct_pairs, np.round(distinct_pairs), atol=1e-9)
    assert values.max() <= 2 * np.sqrt(2) + 1e-12
    # Two independent permutations agree at a position with probability 1/n.
    assert values.mean() == pytest.approx(2 * np.sqrt(2) * (n - 1) / n, abs=0.03)


def test_diversity_is_seeded_and_invariant_to_rigid_motions():
    rng = np.random.default_rng(5)
    feats = rng.normal(size=(400, 6))
    rotation, _ = np.linalg.qr(rng.normal(size=(6, 6)))
    moved = feats @ rotation + 3.0
    assert diversity(feats, seed=7) == diversity(feats, seed=7)
    assert diversity(moved, seed=7) == pytest.approx(diversity(feats, seed=7), rel=1e-12)
    assert diversity(feats, seed=7) != diversity(feats, seed=8)


def test_multimodality_is_zero_for_repeats_and_averages_prompts():
    rng = np.random.default_rng(6)
    repeats = np.repeat(rng.normal(size=(5, 1, 4)), 12, axis=1)
    assert multimodality(repeats, pairs=10) == 0.0
    # Generations of a prompt on a scaled simplex: the index draw is shared by all prompts, so
    # prompts scaled by 1 and 3 average to exactly twice the value of scale 1 alone.
    simplex = np.eye(12)[None]
    one = multimodality(simplex, pairs=10, seed=3)
    assert one > 0
    two_prompts = np.concatenate([simplex, 3 * simplex + 5.0])
    assert multimodality(two_prompts, pairs=10, seed=3) == pytest.approx(2 * one)
    values = np.array([multimodality(simplex, pairs=12, seed=seed) for seed in range(400)])
    assert values.mean() == pytest.approx(np.sqrt(2) * 11 / 12, abs=0.03)


# ------------------------------------------------------------------- R-precision and MM-Dist


def test_r_precision_counts_known_ranks_and_drops_the_incomplete_group():
    # One-dimensional embeddings; group 1 has motions at 0, 10, 20, 30.
    motions = np.array([0.0, 10.0, 20.0, 30.0, 0.0, 10.0, 20.0, 30.0, 0.0, 10.0, 20.0])[:, None]
    texts = np.array(
        [
            0.0,  # own motion nearest: rank 0
            16.0,  # 20 (distance 4) is closer than its own 10 (distance 6): rank 1
            0.0,  # 0 and 10 are closer than its own 20: rank 2
            -100.0,  # every other motion is closer: rank 3
            0.0,
            10.0,
            20.0,
            30.0,  # group 2: all exact, rank 0
            30.0,
            30.0,
            30.0,  # incomplete group, all wrong: dropped
        ]
    )[:, None]
    expected = np.array([1 + 4, 2 + 4, 3 + 4]) / 8
    np.testing.assert_allclose(r_precision(texts, motions, top_k=3, batch=4), expected)
    np.testing.assert_allclose(r_precision(torch.tensor(texts), torch.tensor(motions), top_k=3, batch=4), expected)


def test_r_precision_breaks_ties_like_a_stable_argsort():
    motions = np.array([[0.0], [10.0]])
    texts = np.array([[5.0], [5.0]])  # each text is equally far from both motions
    # Row 0: its own motion (index 0) comes first among the tie; row 1: motion 0 precedes it.
    np.testing.assert_allclose(r_precision(texts, motions, top_k=2, batch=2), [0.5, 1.0])


def test_r_precision_matches_an_argsort_of_scipy_distances():
    rng = np.random.default_rng(7)
    motions = rng.normal(size=(100, 16))
    texts = motions + rng.normal(scale=1.2, size=(100, 16))
    hits = np.zeros(3)
    for start in range(0, 96, 32):
        order = np.argsort(cdist(texts[start : start + 32], motions[start : start + 32]), axis=1, kind="stable")
        position = np.argmax(order == np.arange(32)[:, None], axis=1)
        hits += [(position < k).sum() for k in (1, 2, 3)]
    np.testing.assert_allclose(r_precision(texts, motions), hits / 96)


def test_mm_dist_is_the_mean_matched_distance():
    texts = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 0.0]])
    motions = np.array([[3.0, 4.0], [1.0, 1.0], [2.0, 1.0]])
    assert mm_dist(texts, motions) == pytest.approx((5.0 + 0.0 + 1.0) / 3)


# ----------------------------------------------------------------------------------------- Jerk


def _cubic_clip(fps: float, frames: int, joints: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """x(t) = c·t³ along random directions with random amplitudes c, t = 1 + frame / fps."""
    rng = np.random.default_rng(8)
    t = 1.0 + np.arange(frames) / fps
    directions = rng.normal(size=(joints, 3))
    amplitudes = rng.uniform(0.1, 5.0, size=(joints, 1))
    return t, t[:, None, None] ** 3 * (amplitudes * directions)[None]


def _cubic_log_jerk(t1: float, t2: float) -> float:
    """ln((1/v_peak²) ∫ j² dt) for c·t³ on [t1, t2] with t1 ≥ 0: the jerk is 6c and
    v_peak = 3c·t2², so the ratio is 36c²(t2 − t1) / (9c²·t2⁴) = 4(t2 − t1) / t2⁴."""
    return float(np.log(4 * (t2 - t1) / t2**4))


@pytest.mark.parametrize("fps", [20.0, 200.0])
def test_jerk_of_a_cubic_matches_the_closed_form(fps):
    t, clip = _cubic_clip(fps, frames=120, joints=3)
    boundary = 60
    expected = _cubic_log_jerk(t[boundary - 20], t[boundary + 19])
    # Constant jerk and its integral are exact; the finite-difference peak speed is the speed at
    # the midpoint t2 − dt/2 of the last step, so v_peak² is low by a factor ≈ 1 − 2·dt/t2 and the
    # log high by ≈ 2·dt/t2 — a first-order error that shrinks tenfold from 20 to 200 fps.
    first_order_error = 2.0 / (fps * t[boundary + 19])
    assert jerk(clip, fps, [boundary]) - expected == pytest.approx(first_order_error, rel=0.05)


def test_jerk_averages_joints_and_boundaries_of_their_windows():
    rng = np.random.default_rng(9)
    clip = np.cumsum(rng.normal(size=(150, 4, 3)), axis=0) * 0.01
    boundaries = [40, 100]
    per_window = [np.log(dimensionless_jerk(clip[b - 20 : b + 20], 20.0)).mean() for b in boundaries]
    assert jerk(clip, 20.0, boundaries) == pytest.approx(np.mean(per_window), rel=1e-12)
    # An average, not eq. 10's literal sum: 22 copies of one joint give that joint's value.
    one = clip[:, :1]
    assert jerk(np.repeat(one, 22, axis=1), 20.0, boundaries) == pytest.approx(jerk(one, 20.0, boundaries))


def test_jerk_is_dimensionless_in_amplitude_and_shifts_by_3_ln_fps_in_time():
    rng = np.random.default_rng(10)
    t = np.arange(100)[:, None, None] / 20.0
    clip = np.sin(2.0 * t * rng.uniform(0.5, 2.0, size=(1, 5, 3)) + rng.uniform(0, 6, size=(1, 5, 3)))
    value = jerk(clip, 20.0, [30, 70])
    assert jerk(7.3 * clip + 2.0, 20.0, [30, 70]) == pytest.approx(value, rel=1e-12)
    assert value - jerk(clip, 1.0, [30, 70]) == pytest.approx(3 * np.log(20.0), rel=1e-12)


def test_a_step_at_the_boundary_is_jerkier_than_a_smooth_transition():
    t = np.arange(80) / 20.0
    smooth = np.stack([np.sin(t), np.cos(0.7 * t), 0.1 * t], axis=-1)[:, None]
    stepped = smooth.copy()
    stepped[40:] += [0.05, 0.0, 0.0]
    assert jerk(stepped, 20.0, [40]) > jerk(smooth, 20.0, [40]) + 1.0


def test_cutting_a_real_clip_raises_its_jerk_at_the_cut(sample_joints):
    cut = np.concatenate([sample_joints[:85], sample_joints[120:]])
    assert jerk(cut, 20.0, [85]) > jerk(sample_joints, 20.0, [85]) + 1.0


def test_still_joints_are_left_out_and_a_still_clip_has_no_jerk():
    t, moving = _cubic_clip(20.0, frames=80)
    still = np.zeros_like(moving)
    both = np.concatenate([moving, still], axis=1)
    assert jerk(both, 20.0, [40]) == pytest.approx(jerk(moving, 20.0, [40]), rel=1e-12)
    assert np.isnan(dimensionless_jerk(both, 20.0)[1])
    assert np.isnan(jerk(still, 20.0, [40]))
    # The threshold is per frame: a joint moving about 0.1 mm per frame counts at any fps.
    k = np.arange(80.0)[:, None, None]
    slow = (1e-4 * k + 1e-5 * np.sin(k / 5)) * np.array([1.0, 0.0, 0.0])
    for fps in (1.0, 20.0, 1000.0):
        assert np.isfinite(dimensionless_jerk(slow, fps)).all()
    # Exactly constant velocity has no jerk at all: the limit of smoothness, −inf.
    assert jerk(0.25 * k * np.array([1.0, 2.0, 0.0]), 20.0, [40]) == -np.inf


def test_transition_windows_centre_on_boundaries_and_clip_to_the_sequence():
    frames = np.arange(100)
    windows = transition_windows(frames, [50, 10, 95])
    np.testing.assert_array_equal(windows[0], np.arange(30, 70))
    np.testing.assert_array_equal(windows[1], np.arange(0, 30))
    np.testing.assert_array_equal(windows[2], np.arange(75, 100))
    features = torch.arange(40.0).reshape(20, 2)
    np.testing.assert_array_equal(transition_windows(features, [10], window=4)[0], features[8:12].numpy())


# ------------------------------------------------------------------------------- reporting


def test_mean_confidence_interval_is_students_t_over_the_repeats():
    """[1, 2, 3, 4]: s = √(5/3) (ddof 1), t(0.975, 3) = 3.182446 (any t table), so the half-width
    is 3.182446 · 1.290994 / 2 = 2.054260, against Guo's 1.96 · 1.118034 / 2 = 1.095673."""
    mean, half = mean_confidence_interval([1.0, 2.0, 3.0, 4.0])
    assert mean == 2.5 and half == pytest.approx(2.054260, abs=1e-6)
    means, halves = mean_confidence_interval(np.array([[0.7, 0.8], [0.9, 0.8]]))
    np.testing.assert_allclose(means, [0.8, 0.8])
    np.testing.assert_allclose(halves, [12.706205 * np.std([0.7, 0.9], ddof=1) / np.sqrt(2), 0.0], atol=1e-6)
    mean, half = mean_confidence_interval([3.0])
    assert mean == 3.0 and np.isnan(half)


@pytest.mark.parametrize(
    "dof, quantile",  # two-sided 95 %: Student's table (t at 0.975)
    [(1, 12.706205), (2, 4.302653), (3, 3.182446), (4, 2.776445), (9, 2.262157), (30, 2.042272), (120, 1.979930)],
)
def test_the_t_quantile_matches_students_table(dof, quantile):
    assert student_t_quantile(0.95, dof) == pytest.approx(quantile, abs=1e-6)


def test_the_t_quantile_matches_scipy_at_every_confidence_and_dof():
    stats = pytest.importorskip("scipy.stats")
    for dof in (1, 2, 5, 17, 60, 500):
        for confidence in (0.5, 0.8, 0.9, 0.95, 0.99):
            expected = stats.t.ppf(0.5 + confidence / 2, dof)
            assert student_t_quantile(confidence, dof) == pytest.approx(expected, rel=1e-9)


# ------------------------------------------------------------------------------- bad inputs


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: fid(np.zeros((5, 3)), np.zeros((5, 4))), "same feature size"),
        (lambda: fid(np.zeros((1, 3)), np.zeros((5, 3))), "at least 2 samples"),
        (lambda: fid(np.zeros(5), np.zeros((5, 1))), "2 dimensions"),
        (lambda: fid(np.full((5, 2), np.nan), np.zeros((5, 2))), "NaN"),
        (lambda: diversity(np.zeros((50, 3))), "smaller pairs"),
        (lambda: multimodality(np.zeros((4, 5, 3)), pairs=10), "at least 10 generations"),
        (lambda: multimodality(np.zeros((4, 3)), pairs=2), "3 dimensions"),
        (lambda: r_precision(np.zeros((10, 3)), np.zeros((10, 3))), "smaller batch"),
        (lambda: r_precision(np.zeros((40, 3)), np.zeros((40, 4))), "row by row"),
        (lambda: r_precision(np.zeros((40, 3)), np.zeros((40, 3)), top_k=0), "top_k"),
        (lambda: mm_dist(np.zeros((3, 2)), np.zeros((4, 2))), "row by row"),
        (lambda: jerk(np.zeros((50, 22)), 20.0, [25]), "3 dimensions"),
        (lambda: jerk(np.zeros((50, 22, 2)), 20.0, [25]), "(frames, joints, 3)"),
        (lambda: jerk(np.zeros((50, 2, 3)), 20.0, []), "at least one boundary"),
        (lambda: jerk(np.zeros((50, 2, 3)), 20.0, [50]), "outside"),
        (lambda: jerk(np.zeros((50, 2, 3)), 20.0, [2.5]), "integer"),
        (lambda: jerk(np.zeros((50, 2, 3)), 20.0, [1], window=4), "at least 4"),
        (lambda: jerk(np.zeros((50, 2, 3)), 0.0, [25]), "fps"),
        (lambda: mean_confidence_interval([]), "at least one replication"),
        (lambda: student_t_quantile(0.95, 0), "dof >= 1"),
    ],
)
def test_bad_inputs_raise_a_clear_value_error(call, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        call()


def _stepped_clip() -> np.ndarray:
    """10 frames, 2 joints: joint 0 steps 1 m along x at frame 5 (third differences 1, −2, 1 at
    frames 2..4); joint 1 follows y = 0.1·t³/6 (third difference 0.1 everywhere) and steps
    −0.5 m along z at frame 3 (−0.5, 1, −0.5 at frames 0..2)."""
    t = np.arange(10, dtype=np.float64)
    clip = np.zeros((10, 2, 3))
    clip[5:, 0, 0] = 1.0
    clip[:, 1, 1] = 0.1 * t**3 / 6
    clip[3:, 1, 2] = -0.5
    return clip


def test_frame_jerk_is_the_max_over_joints_of_the_l1_third_difference():
    # joint 0: |Δ³x| = 0 0 1 2 1 0 0; joint 1: 0.1 + |Δ³z| = 0.6 1.1 0.6 0.1 0.1 0.1 0.1
    assert frame_jerk(_stepped_clip()) == pytest.approx([0.6, 1.1, 1.0, 2.0, 1.0, 0.1, 0.1])
    assert frame_jerk(torch.as_tensor(_stepped_clip())) == pytest.approx(frame_jerk(_stepped_clip()))


def test_peak_jerk_and_auj_read_the_mean_curve_against_the_datasets_constant():
    assert peak_jerk_and_auj([[1.0, 2.0, 3.0], [3.0, 2.0, 1.0]], 1.5) == pytest.approx((2.0, 1.5))
    assert peak_jerk_and_auj([[0.0, 4.0, 0.0]], 1.0) == pytest.approx((4.0, 5.0))  # |−1| + |3| + |−1|


def test_the_datasets_constant_is_the_mean_over_every_frame_of_every_clip():
    cubic = np.zeros((4, 1, 3))
    cubic[:, 0, 1] = 0.1 * np.arange(4.0) ** 3 / 6  # one frame of jerk 0.1
    assert mean_frame_jerk([_stepped_clip(), cubic]) == pytest.approx((5.9 + 0.1) / 8)  # 7 frames + 1


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: frame_jerk(np.zeros((3, 2, 3))), "at least 4 frames"),
        (lambda: frame_jerk(np.zeros((5, 2, 2))), "(frames, joints, 3)"),
        (lambda: mean_frame_jerk([]), "at least one clip"),
        (lambda: peak_jerk_and_auj(np.zeros((0, 5)), 0.0), "at least one transition"),
    ],
)
def test_flowmdm_metrics_refuse_what_they_cannot_measure(call, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        call()
