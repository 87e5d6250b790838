"""Frame rate, root motion and loops (m2d2m/motion/transforms/retime.py): a resampled clip passes through the
source's poses at the instants both rates share and keeps its bones, slerp is the geodesic one,
root motion comes off and goes back exactly, and a loop's seam is as smooth as the clip itself
where a loop without the cross-fade is not."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from m2d2m.motion.representation.pose import pose_of
from m2d2m.motion.representation.rigid import on_rigid_skeleton
from m2d2m.motion.representation.rotations import matrix_to_quat
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.motion.transforms.retime import (
    frame_count,
    make_loop,
    resample,
    resample_pose,
    resample_ranges,
    root_motion,
    source_positions,
)
from tests.conftest import HUMANML3D_SAMPLE
from tests.test_export import build_rigid_clip

SAMPLE = HUMANML3D_SAMPLE / "new_joints" / "012314.npy"


@pytest.fixture(scope="module")
def real_clip() -> np.ndarray:
    """HumanML3D's clip 012314 (170 frames at 20 fps, float32, metres), as the corpus ships it."""
    return np.load(SAMPLE)


@pytest.mark.parametrize("target, source_step, target_step", [(60, 1, 3), (30, 2, 3), (24, 5, 6), (25, 4, 5)])
def test_resampled_joints_are_the_sources_at_shared_instants(real_clip, target, source_step, target_step):
    """On one rigid body, as a generated motion's joints are (Motion.on_rigid_skeleton)."""
    source = on_rigid_skeleton(real_clip, T2M)
    out = resample(source, T2M, 20, target)
    shared = min(len(source[::source_step]), len(out[::target_step]))
    assert shared >= len(source) // source_step  # every shared instant up to the clip's end
    assert np.abs(out[::target_step][:shared] - source[::source_step][:shared]).max() < 1e-6
    lengths = T2M.bone_lengths_of(out)[:, T2M.bones]
    np.testing.assert_allclose(lengths, np.broadcast_to(T2M.bone_lengths[T2M.bones], lengths.shape), atol=1e-9)


def test_a_rigid_clip_comes_back_exactly_and_the_same_rate_changes_nothing():
    joints, _ = build_rigid_clip(T2M, n_frames=40)
    assert np.abs(resample(joints, T2M, 20, 40)[::2] - joints).max() < 1e-9
    assert np.abs(resample(joints, T2M, 20, 20) - joints).max() < 1e-9


@pytest.mark.parametrize("target, frames", [(24, 204), (25, 213), (30, 255), (60, 510), (10, 85), (29.97, 255)])
def test_a_clip_keeps_its_length_in_seconds_at_every_rate(real_clip, target, frames):
    """Issue 53 §6: T seconds at F fps are T·F frames, as an animation tool counts them (10 s at 30
    fps: 300 frames, not 299). The 170 frames at 20 fps last 8.5 s; at each rate the clip has the
    frames of 8.5 s (rounded, half up), frame k at k / target, and the instants after the last
    source frame (8.45 s) hold it."""
    assert len(resample(real_clip, T2M, 20, target)) == frames == frame_count(len(real_clip), 20, target)
    assert abs(frames / target - len(real_clip) / 20) <= 0.5 / target
    expected = np.minimum(np.arange(frames) * 20 / target, len(real_clip) - 1)
    np.testing.assert_allclose(source_positions(len(real_clip), 20, target), expected)
    assert frame_count(200, 20, 30) == 300 and frame_count(200, 20, 60) == 600 and frame_count(300, 30, 20) == 200


def test_halfway_rotations_are_the_geodesic_midpoints_scipy_slerps():
    joints, _ = build_rigid_clip(T2M, n_frames=12)
    pose = pose_of(joints, T2M)
    halves = resample_pose(pose, 20, 40)
    times = np.arange(len(joints), dtype=np.float64)
    for joint in range(T2M.num_joints):
        keys = Rotation.from_matrix(pose.local[:, joint])
        reference = Slerp(times, keys)(times[:-1] + 0.5).as_matrix()
        np.testing.assert_allclose(halves.local[1:-1:2, joint], reference, atol=1e-9)
        middle = Rotation.from_matrix(halves.local[1:-1:2, joint])
        to_middle = (keys[:-1].inv() * middle).magnitude()
        np.testing.assert_allclose(to_middle, (middle.inv() * keys[1:]).magnitude(), atol=1e-9)
        np.testing.assert_allclose(2 * to_middle, (keys[:-1].inv() * keys[1:]).magnitude(), atol=1e-9)
    np.testing.assert_allclose(halves.root[1:-1:2], (pose.root[:-1] + pose.root[1:]) / 2, atol=1e-12)


def test_quaternions_of_matrices_agree_with_scipy_also_at_half_turns():
    half_turns = Rotation.from_rotvec(np.pi * np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [0.6, 0.8, 0]]))
    rotations = Rotation.concatenate([Rotation.random(500, random_state=0), half_turns, Rotation.identity(1)])
    ours = matrix_to_quat(rotations.as_matrix())
    theirs = rotations.as_quat()[:, [3, 0, 1, 2]]  # scipy stores (x, y, z, w)
    np.testing.assert_allclose(np.abs(np.sum(ours * theirs, axis=-1)), 1.0, atol=1e-12)  # q and −q: one rotation


@pytest.mark.parametrize("fps, target", [(20, 0), (20, -24), (20, float("nan")), (20, 1e6), (0, 30)])
def test_a_rate_that_is_no_frame_rate_is_refused_in_one_line(real_clip, fps, target):
    with pytest.raises(ValueError, match=r"^(target_)?fps must be a frame rate from 1 to 1000 frames per second, got"):
        resample(real_clip, T2M, fps, target)


def test_action_ranges_follow_the_rate_and_stay_valid():
    assert resample_ranges([(0, 40), (40, 100)], 20, 60, 298) == [(0, 120), (120, 298)]
    assert resample_ranges([(0, 40), (50, 100)], 20, 30, 149) == [(0, 60), (75, 149)]
    # a one-frame action at 60 fps still gets a frame at 20 fps, and nothing runs past the end
    assert resample_ranges([(0, 10), (10, 11), (11, 30)], 60, 20, 10) == [(0, 4), (4, 5), (5, 10)]
    assert resample_ranges([(0, 2), (2, 4), (4, 6)], 60, 1, 3) == [(0, 1), (1, 2), (2, 3)]
    with pytest.raises(ValueError, match="3 actions do not fit in 2 frames at 1 fps"):
        resample_ranges([(0, 2), (2, 4), (4, 6)], 60, 1, 2)


def test_in_place_keeps_the_body_over_the_origin_and_returns_the_path(real_clip):
    joints, track = root_motion(real_clip, "in-place")
    np.testing.assert_array_equal(joints[:, 0, [0, 2]], 0.0)
    np.testing.assert_array_equal(joints[:, 0, 1], real_clip[:, 0, 1])  # the body still bobs
    np.testing.assert_allclose(joints - joints[:, :1], real_clip - real_clip[:, :1], atol=1e-12)
    np.testing.assert_array_equal(track[:, 1], 0.0)
    np.testing.assert_array_equal(track[:, [0, 2]], real_clip[:, 0, [0, 2]])
    np.testing.assert_array_equal(joints + track[:, None], real_clip)  # exactly: float32 differences fit float64


def test_keep_changes_nothing_and_an_unknown_mode_is_refused(real_clip):
    joints, track = root_motion(real_clip, "keep")
    np.testing.assert_array_equal(joints, real_clip)
    assert track is None
    with pytest.raises(ValueError, match="root mode must be one of keep, in-place, ground, got 'float'"):
        root_motion(real_clip, "float")


def test_ground_moves_the_whole_clip_once_so_a_jump_stays_in_the_air(real_clip):
    jumping = real_clip.astype(np.float64) + [0.0, 0.5, 0.0]  # floating half a metre up...
    jumping[60:70] += [0.0, 0.3, 0.0]  # ...and 30 cm higher still for half a second
    grounded, track = root_motion(jumping, "ground")
    assert track is None
    assert grounded[..., 1].min() == 0.0
    shift = grounded - jumping
    np.testing.assert_array_equal(shift, np.broadcast_to(shift[0, 0], shift.shape))  # one shift, up or down only
    np.testing.assert_array_equal(shift[0, 0, [0, 2]], 0.0)
    np.testing.assert_allclose(grounded[60:70, :, 1].min(), 0.3 + real_clip[60:70, :, 1].min(), atol=1e-6)


def jerk(joints: np.ndarray, fps: float) -> np.ndarray:
    """Per frame t, the mean over joints of |x[t+3] − 3x[t+2] + 3x[t+1] − x[t]|·fps³ (m/s³)."""
    return np.linalg.norm(np.diff(joints, 3, axis=0), axis=-1).mean(axis=1) * fps**3


def acceleration(joints: np.ndarray, fps: float) -> np.ndarray:
    """Per frame t, the mean over joints of |x[t+2] − 2x[t+1] + x[t]|·fps² (m/s²)."""
    return np.linalg.norm(np.diff(joints, 2, axis=0), axis=-1).mean(axis=1) * fps**2


def seam_figures(cycle: np.ndarray, travel: np.ndarray, fps: float) -> tuple[float, float]:
    """The largest jerk and acceleration over the differences that reach across the seam of
    ``cycle`` played twice, the second time moved by ``travel``."""
    twice, frames = np.concatenate([cycle, cycle + travel]), len(cycle)
    return jerk(twice, fps)[frames - 3 : frames].max(), acceleration(twice, fps)[frames - 2 : frames].max()


@pytest.mark.parametrize("clip", ["humanml3d", "rigid"])
def test_a_loops_seam_is_as_smooth_as_the_clip_where_a_cut_without_fade_is_not(real_clip, clip):
    """The bound: across the seam the cross-fade has ended, so the seam shows the clip's own
    motion around the loop's first frame plus what the fade adds (which :func:`loop_cut` keeps
    small); on these clips that stays under the clip's 95th-percentile jerk (measured: 134 against
    377 m/s³ on HumanML3D's clip, 23 against 52 on the synthetic one), and the fade itself adds no
    jerk beyond the clip's largest. The same frames looped without the fade jump by 10 to 100
    times that jerk."""
    joints = real_clip.astype(np.float64) if clip == "humanml3d" else build_rigid_clip(T2M, n_frames=120)[0]
    loop = make_loop(joints, 20, T2M)
    first, end = loop.span
    assert 5 <= first <= 20 and end - first >= (len(joints) - first) / 2 and len(loop.joints) == end - first
    assert loop.travel[1] == 0.0
    clip_jerk, clip_acceleration = jerk(joints, 20), acceleration(joints, 20)
    seam_jerk, seam_acceleration = seam_figures(loop.joints, loop.travel, 20)
    assert seam_jerk <= np.percentile(clip_jerk, 95)
    assert seam_acceleration <= np.percentile(clip_acceleration, 95)  # velocity continuous across the seam
    # the clip's frames come back through FK, a micrometre off: 1e-6 m × 20³ is 0.008 m/s³ of jerk
    assert jerk(np.concatenate([loop.joints, loop.joints + loop.travel]), 20).max() <= clip_jerk.max() + 0.1
    assert seam_figures(joints[first:end], loop.travel, 20)[0] > 10 * np.percentile(clip_jerk, 95)
    lengths = T2M.bone_lengths_of(loop.joints)[:, T2M.bones]
    assert lengths.std(axis=0).max() < 1e-9
    in_place, _ = root_motion(loop.joints, "in-place")
    assert seam_figures(in_place, np.zeros(3), 20)[0] <= np.percentile(clip_jerk, 95)  # seamless in place too


def test_a_loop_at_another_rate_chooses_the_same_cut_in_seconds(real_clip):
    at_20 = make_loop(real_clip, 20, T2M)
    at_30 = make_loop(resample(real_clip, T2M, 20, 30), 30, T2M)
    assert 2 * np.array(at_30.span) == pytest.approx(3 * np.array(at_20.span))


def test_a_clip_too_short_to_loop_is_refused(real_clip):
    with pytest.raises(ValueError, match="a loop needs at least 15 frames \\(0.75 s\\), got 14"):
        make_loop(real_clip[:14], 20, T2M)
