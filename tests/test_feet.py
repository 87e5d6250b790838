"""Feet that stay planted (m2d2m/motion/transforms/feet.py): the two-bone IK against closed forms, GMD's
skating ratio by hand, contacts judged by the joints, and the fix: real motion (HumanML3D's clip
012314, CMU's and Bandai Namco's takes) left within the issue's bounds, motion made to slide
brought back near its clean skating, a synthetic walk whose stance feet slide, a pivot left alone."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bench.foot_fix import CMU, off_ground, on_floor, slide_feet
from m2d2m.evaluation.measurements import with_planted_feet
from m2d2m.evaluation.sequence_metrics import measure_sequences
from m2d2m.motion.clip import Motion
from m2d2m.motion.representation.features import joints_to_features
from m2d2m.motion.representation.skeleton import KIT, T2M, Skeleton
from m2d2m.motion.transforms.feet import (
    FREE_SPEED_M_S,
    SLIDE_TOLERANCE_M,
    KeptFrames,
    contact_runs,
    fix_feet,
    foot_contacts,
    hold_while_grounded,
    moving_average,
    plant_feet,
    skating_ratio,
    step_speeds,
    two_bone_ik,
)
from pipelines.bvh_corpus import take_joints

FPS = 20.0
LEGS = [4, 7, 10, 5, 8, 11]  # T2M's knees, ankles and toes: what planting may move


def random_legs(rng: np.random.Generator, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``count`` bent legs (hip, knee, ankle) of random bone lengths and directions."""
    hip = rng.normal(size=(count, 3))
    knee = hip + rng.uniform(0.3, 0.5, (count, 1)) * unit(rng.normal(size=(count, 3)))
    ankle = knee + rng.uniform(0.3, 0.5, (count, 1)) * unit(rng.normal(size=(count, 3)))
    return hip, knee, ankle


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_a_reachable_target_is_reached_with_exact_bones_and_the_knee_in_its_plane():
    rng = np.random.default_rng(0)
    hip, knee, ankle = random_legs(rng, 200)
    thigh, shin = np.linalg.norm(knee - hip, axis=-1), np.linalg.norm(ankle - knee, axis=-1)
    reach = rng.uniform(np.abs(thigh - shin) + 0.01, thigh + shin - 0.01)
    target = hip + reach[:, None] * unit(rng.normal(size=(200, 3)))

    new_knee, new_ankle = two_bone_ik(hip, knee, ankle, target)

    np.testing.assert_allclose(new_ankle, target, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(new_knee - hip, axis=-1), thigh, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(new_ankle - new_knee, axis=-1), shin, rtol=1e-12)
    # the knee lies in the plane of the hip–target line and the old knee, on the old knee's side
    volume = np.einsum("ni,ni->n", np.cross(target - hip, knee - hip), new_knee - hip)
    np.testing.assert_allclose(volume, 0.0, atol=1e-12)
    line = unit(target - hip)
    old_side = (knee - hip) - np.einsum("ni,ni->n", knee - hip, line)[:, None] * line
    assert (np.einsum("ni,ni->n", new_knee - hip, old_side) > 0).all()


def test_the_target_it_started_from_gives_the_leg_back():
    hip, knee, ankle = random_legs(np.random.default_rng(1), 50)
    new_knee, new_ankle = two_bone_ik(hip, knee, ankle, ankle)
    np.testing.assert_allclose(new_knee, knee, atol=1e-12)
    np.testing.assert_allclose(new_ankle, ankle, atol=1e-12)


@pytest.mark.parametrize("scale", [2.0, 0.3], ids=["too far", "too near"])
def test_an_unreachable_target_gives_the_nearest_reachable_point(scale):
    """The reachable ankles form a shell about the hip; none of 20,000 sampled in it is nearer to
    the target than the one returned, which lies on the hip–target ray."""
    rng = np.random.default_rng(2)
    hip, knee, ankle = random_legs(rng, 1)
    thigh, shin = np.linalg.norm(knee - hip), np.linalg.norm(ankle - knee)
    direction = unit(rng.normal(size=(1, 3)))
    limit = thigh + shin if scale > 1 else abs(thigh - shin)
    target = hip + scale * limit * direction

    new_knee, new_ankle = two_bone_ik(hip, knee, ankle, target)

    np.testing.assert_allclose(new_ankle, hip + limit * direction, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(new_knee - hip), thigh, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(new_ankle - new_knee), shin, rtol=1e-12)
    samples = hip + rng.uniform(abs(thigh - shin), thigh + shin, (20000, 1)) * unit(rng.normal(size=(20000, 3)))
    assert np.linalg.norm(samples - target, axis=-1).min() >= np.linalg.norm(new_ankle - target) - 1e-12


def rest_pose(skeleton: Skeleton) -> np.ndarray:
    """Joint positions (J, 3) of the skeleton's rest pose, root at the origin."""
    pose = np.zeros((skeleton.num_joints, 3))
    for joint in skeleton.bones:
        pose[joint] = pose[skeleton.parents[joint]] + skeleton.offsets()[joint]
    return pose


def walk(slide: float, seconds: float = 3.0, speed: float = 0.8) -> np.ndarray:
    """T2M walking along +Z at ``speed`` m/s, 20 fps, one step a second per foot (12 stance
    frames, 8 swing), the upper body in its rest pose. Each stance foot slides forward at
    ``slide`` m/s about its footprint, which is under the hip at mid-stance; the knees come from
    the law of cosines in the sagittal plane, as angles (this test's own solution), so every bone
    has its skeleton length in every frame."""
    frames = np.arange(int(seconds * FPS))
    time = frames / FPS
    joints = rest_pose(T2M)[None] + np.stack([0 * time, np.full(len(time), 0.8), speed * time], -1)[:, None]
    lengths = T2M.bone_lengths
    for hip, knee, ankle, toe, delay in ((1, 4, 7, 10, 0), (2, 5, 8, 11, 10)):
        phase = (frames + delay) % 20
        middle = ((frames + delay) // 20 * 20 - delay + 5.5) / FPS  # this step's mid-stance
        lift_off = speed * middle + slide * 5.5 / FPS  # where the stance ends
        touch_down = speed * (middle + 1.0) - slide * 5.5 / FPS  # where the next one starts
        s = (phase - 11) / 9.0  # swing progress at phases 12..19
        swinging = phase >= 12
        eased = lift_off + s * s * (3 - 2 * s) * (touch_down - lift_off)
        ankle_z = np.where(swinging, eased, speed * middle + slide * (time - middle))
        ankle_y = np.where(swinging, 0.08 + 0.12 * np.sin(np.pi * s), 0.08)
        joints[:, ankle] = np.stack([joints[:, hip, 0], ankle_y, ankle_z], -1)
        drop = 0.06  # the toe below the ankle
        joints[:, toe] = joints[:, ankle] + [0.0, -drop, np.sqrt(lengths[toe] ** 2 - drop**2)]
        dz, dy = ankle_z - joints[:, hip, 2], ankle_y - joints[:, hip, 1]
        reach, thigh, shin = np.hypot(dz, dy), lengths[knee], lengths[ankle]
        assert (reach < thigh + shin).all(), "the walk must be reachable"
        angle = np.arctan2(dy, dz) + np.arccos((thigh**2 + reach**2 - shin**2) / (2 * thigh * reach))
        joints[:, knee] = joints[:, hip] + thigh * np.stack([0 * time, np.sin(angle), np.cos(angle)], -1)
    return joints


def test_the_synthetic_walk_is_rigid_and_does_not_skate_until_its_stance_feet_slide():
    clean, sliding = walk(0.0), walk(0.6)
    for joints in (clean, sliding):
        np.testing.assert_allclose(
            T2M.bone_lengths_of(joints)[:, T2M.bones],
            np.broadcast_to(T2M.bone_lengths[T2M.bones], (len(joints), len(T2M.bones))),
            atol=1e-12,
        )
    assert skating_ratio(clean, T2M, FPS) == 0.0
    assert skating_ratio(sliding, T2M, FPS) > 0.9  # a stance toe slides at 0.6 m/s in nearly every step


def test_planting_stops_the_slide_and_moves_nothing_but_the_legs():
    """Stance feet sliding at 0.6 m/s (27 cm over a contact run): planted, each toe travels at
    most its tolerance either way and the creep a real foot is allowed over the run."""
    sliding = walk(0.6)
    planted = plant_feet(sliding, T2M, FPS)

    assert skating_ratio(planted, T2M, FPS) == 0.0
    others = np.setdiff1d(np.arange(T2M.num_joints), LEGS)
    np.testing.assert_array_equal(planted[:, others], sliding[:, others])
    np.testing.assert_allclose(T2M.bone_lengths_of(planted), T2M.bone_lengths_of(sliding), atol=1e-12)
    contacts = foot_contacts(sliding, T2M, FPS)
    for channel, toe in ((1, 10), (3, 11)):
        for first, end in contact_runs(contacts[:, channel]):
            if end - first < 10:  # the clip's cut ends
                continue
            seconds = (end - first - 1) / FPS
            travel = np.abs(planted[end - 1, toe, 2] - planted[first, toe, 2])
            assert travel <= 2 * SLIDE_TOLERANCE_M + FREE_SPEED_M_S * seconds + 1e-9
            assert np.abs(sliding[end - 1, toe, 2] - sliding[first, toe, 2]) == pytest.approx(0.6 * seconds)


def test_kept_frames_come_out_as_given_and_a_run_crossing_into_them_holds_their_lock():
    """Issue 53 §7: an edit's result, its frames from 26 on new (stance feet sliding at 0.3 m/s
    where the source's slid at 0.6), its kept frames the source's as delivered: planted again
    whole, the left stance that crosses frame 26 moves the kept frames by 3.75 mm; told which
    frames are kept, the fix leaves them bit for bit and holds the new frames of that stance
    within the tolerance and a real foot's creep of where the kept frames stand."""
    source = walk(0.6)
    delivered = plant_feet(source, T2M, FPS)
    edited = source.copy()
    edited[26:] = walk(0.3)[26:]
    kept = np.arange(len(edited)) < 26
    assert np.abs(plant_feet(edited, T2M, FPS)[kept] - delivered[kept]).max() > 3e-3

    fixed = plant_feet(edited, T2M, FPS, kept=KeptFrames(kept, delivered))

    np.testing.assert_array_equal(fixed[kept], delivered[kept])
    drift = np.abs(fixed[26:32, 10, 2] - fixed[25, 10, 2])  # the left toe, to the stance's end (frame 31)
    assert (drift <= SLIDE_TOLERANCE_M + FREE_SPEED_M_S * np.arange(1, 7) / FPS + 1e-9).all()
    assert np.abs(edited[31, 10, 2] - edited[25, 10, 2]) > SLIDE_TOLERANCE_M + 6 * FREE_SPEED_M_S / FPS
    np.testing.assert_allclose(T2M.bone_lengths_of(fixed), T2M.bone_lengths_of(edited), atol=1e-12)


def test_planting_a_clip_without_contacts_changes_nothing():
    sliding = walk(0.6)
    untouched = plant_feet(sliding, T2M, FPS, np.zeros((len(sliding), 4), dtype=bool))
    np.testing.assert_array_equal(untouched, sliding)


def test_planting_works_on_kit_whose_contact_pair_is_below_the_ankle():
    """KIT's contact joints (19, 20) and (14, 15) hang below the ankles (18, 13): the whole foot
    turns with the pair, and every bone keeps its length."""
    frames = 12
    rest = rest_pose(KIT)
    drift = np.stack([np.linspace(0, 200, frames), np.zeros(frames), np.linspace(0, 400, frames)], -1)  # 0.8 m/s
    joints = rest[None] + drift[:, None]  # a standing figure gliding over the ground (KIT's units)
    planted = plant_feet(joints, KIT, KIT.fps, np.ones((frames, 4), dtype=bool))
    np.testing.assert_allclose(KIT.bone_lengths_of(planted), KIT.bone_lengths_of(joints), atol=1e-9)
    moved = np.flatnonzero(np.abs(planted - joints).max(axis=(0, 2)) > 0)
    assert set(moved) <= {12, 13, 14, 15, 17, 18, 19, 20}  # knees, ankles and feet
    glide = np.linalg.norm(np.diff(joints[:, 20, [0, 2]], axis=0), axis=-1).sum()
    assert np.linalg.norm(np.diff(planted[:, 20, [0, 2]], axis=0), axis=-1).sum() < glide / 2


def test_skating_ratio_by_hand():
    """Seven frames: the left toe moves 1, 4, 4, 4, 1, 0 cm along x (0.2, 0.8, 0.8, 0.8, 0.2, 0
    m/s), low (2 cm) but for frame 5 (6 cm); the right toe bobs up and down at 0.8 m/s but never
    moves over the ground. 5-step means with zeros beyond the ends: 0.36, 0.52, 0.56, 0.52, 0.36,
    0.2. Steps 1, 2 and 3 are low in both frames and above 0.5 m/s both ways: 3 of 6."""
    joints = np.zeros((7, T2M.num_joints, 3))
    joints[:, 10, 0] = [0.0, 0.01, 0.05, 0.09, 0.13, 0.14, 0.14]
    joints[:, 10, 1] = [0.02, 0.02, 0.02, 0.02, 0.02, 0.06, 0.02]
    joints[:, 11, 1] = [0.0, 0.04, 0.0, 0.04, 0.0, 0.04, 0.0]
    assert skating_ratio(joints, T2M, FPS) == pytest.approx(3 / 6)
    assert skating_ratio(joints, T2M, FPS, speed=0.53) == pytest.approx(1 / 6)  # only step 2's mean clears it
    assert skating_ratio(joints, T2M, FPS, height=0.01) == 0.0
    assert np.isnan(skating_ratio(joints[:1], T2M, FPS))


@pytest.mark.parametrize("window", [5, 4, 1])
def test_the_moving_average_is_scipys_uniform_filter_with_zeros_beyond_the_ends(window):
    ndimage = pytest.importorskip("scipy.ndimage")
    values = np.random.default_rng(3).normal(size=(2, 23))
    expected = ndimage.uniform_filter1d(values, size=window, axis=-1, mode="constant")
    np.testing.assert_allclose(moving_average(values, window), expected, atol=1e-12)


def test_the_real_clips_contacts_from_its_features_are_those_of_its_joints(sample_joints, sample_features):
    """HumanML3D's features carry the contacts of the joints they were made from (its rule, at
    its frame rate): the two agree on every frame of clip 012314."""
    from_features = foot_contacts(sample_joints, T2M, FPS, sample_features)
    np.testing.assert_array_equal(foot_contacts(sample_joints, T2M, FPS), from_features)
    assert from_features.mean() > 0.5  # a clip that stands more than it steps


def test_the_real_clip_is_left_exactly_as_it_is(sample_joints, sample_features):
    """Clip 012314 skates in 23 of its 169 steps by GMD's measure, all of them low swings and
    shuffles, none a foot sliding in contact: the fix leaves every joint where it is, with its
    own contacts and with the joints' (the first version moved its left knee 170 mm)."""
    assert skating_ratio(sample_joints, T2M, FPS) == pytest.approx(23 / 169)
    for features in (sample_features, None):
        np.testing.assert_array_equal(fix_feet(sample_joints, T2M, FPS, features), sample_joints)


def test_a_contact_is_held_on_while_its_foot_is_grounded_and_a_grounded_gap_closes():
    """Runs at 3–4 and 9–10, the foot grounded on 0–2, 5–6 and 8, at most 2 frames each way: the
    first grows to 1–6, the second back to 8 (7 is in the air) and not on (11 is in the air)."""
    flags = np.zeros(12, dtype=bool)
    flags[[3, 4, 9, 10]] = True
    grounded = np.zeros(12, dtype=bool)
    grounded[[0, 1, 2, 5, 6, 8]] = True
    held = hold_while_grounded(flags, grounded, limit=2)
    np.testing.assert_array_equal(np.flatnonzero(held), [1, 2, 3, 4, 5, 6, 8, 9, 10])
    # a grounded gap of 2 * limit frames closes (one contact); one frame longer, or with a frame in
    # the air, stays open: two steps
    for gap, lifted, closed in ((4, None, True), (5, None, False), (4, 3, False)):
        flags = np.zeros(12, dtype=bool)
        flags[[1, 2 + gap]] = True
        grounded = np.ones(12, dtype=bool)
        if lifted is not None:
            grounded[lifted] = False
        held = hold_while_grounded(flags, grounded, limit=2)
        assert held[1 : 3 + gap].all() == closed, (gap, lifted)


def test_every_evaluation_measures_skating(sample_joints):
    values = measure_sequences([(sample_joints, [])], T2M)
    assert values["skating"] == [skating_ratio(sample_joints, T2M, FPS)]


def test_contacts_at_another_frame_rate_keep_the_speed_threshold():
    """HumanML3D's 0.002 m² per frame at 20 fps is 0.894 m/s: a toe at 0.85 m/s touches, at
    0.95 m/s does not, whether sampled at 20 or 60 fps."""
    for fps in (20.0, 60.0):
        time = np.arange(10) / fps
        joints = np.zeros((10, T2M.num_joints, 3))
        joints[:, 10, 0] = 0.85 * time
        joints[:, 11, 0] = 0.95 * time
        contacts = foot_contacts(joints, T2M, fps)
        assert contacts[:, 1].all() and not contacts[:, 3].any()


def test_a_straight_leg_bends_towards_the_pole():
    hip, knee, ankle = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.6, 0.0]), np.array([0.0, 0.1, 0.0])
    target = np.array([0.0, 0.4, 0.0])
    new_knee, new_ankle = two_bone_ik(hip, knee, ankle, target, pole=np.array([0.0, 0.0, 1.0]))
    np.testing.assert_allclose(new_ankle, target, atol=1e-12)
    # thigh 0.4 and shin 0.5 over 0.6: cos α = (0.16 + 0.36 − 0.25) / (2·0.4·0.6) = 0.5625
    cos = 0.27 / 0.48
    np.testing.assert_allclose(new_knee, [0.0, 1.0 - 0.4 * cos, 0.4 * np.sqrt(1 - cos**2)], atol=1e-12)


def test_the_planted_row_adds_to_the_models_features_what_the_fix_changed(sample_joints, sample_features):
    """The evaluation's planted row (m2d2m/evaluation/measurements.py): the fix a delivery runs,
    the contact channels the model's; for a clip whose features are its joints' own, the rest
    equals the planted joints' features, so the row differs from a re-derivation only where a
    model's features disagree with its joints; and where nothing is planted, nothing changes.
    The clip is 012314 with its planted feet made to slide, as a generated clip's do."""
    joints = slide_feet(sample_joints, 0.6, 0.15)
    derived = joints_to_features(joints, T2M)
    features = np.concatenate([derived, derived[-1:]]).astype(np.float32)
    features[:, -4:] = sample_features[:, -4:]  # HumanML3D's contacts of this clip, which the fix plants
    motion = Motion(features, joints, FPS, T2M.name, ["walk"], [(0, len(joints))])
    planted = with_planted_feet(motion, T2M)
    np.testing.assert_array_equal(planted.joints, fix_feet(joints, T2M, FPS, features))
    np.testing.assert_array_equal(planted.features[:, -4:], features[:, -4:])
    np.testing.assert_allclose(planted.features[:-1, :-4], joints_to_features(planted.joints, T2M)[:, :-4], atol=1e-4)
    assert np.abs(planted.features - features).max() > 0.01  # the fix did change the legs
    real = replace(motion, joints=np.asarray(sample_joints, dtype=np.float64))  # whose feet do not slide
    np.testing.assert_array_equal(with_planted_feet(real, T2M).features, features)


# ------------------------------------------------------------------ real motion and sliding motion


def displacement(fixed: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """(T, J) how far the fix moved each joint."""
    return np.linalg.norm(np.asarray(fixed, dtype=np.float64) - joints, axis=-1)


def within_the_issues_bounds(joints: np.ndarray, fixed: np.ndarray) -> None:
    """No joint moved more than 1 cm at the 95th percentile of frames, none of a foot's leg more
    than 3 cm in a frame where that foot is off the ground (bench/foot_fix.py's rule)."""
    moved = displacement(fixed, joints)
    assert np.percentile(moved.max(axis=1), 95) <= 0.01
    swinging = off_ground(joints)
    for side, legs in enumerate(([4, 7, 10], [5, 8, 11])):
        assert moved[swinging[:, side]][:, legs].max(initial=0.0) <= 0.03


def cmu_take(name: str) -> np.ndarray:
    return on_floor(take_joints(CMU / f"{name}.bvh", units="cmu")[0].astype(np.float64))


CMU_TAKES = ("131_01", "131_02", "131_03")
BANDAI = Path(__file__).resolve().parent / "fixtures" / "bandai-namco"


@pytest.mark.parametrize("take", CMU_TAKES)
def test_real_cmu_takes_are_left_within_the_bounds(take):
    """CMU's subject 131 walks, hops and dances ("Michael Jackson styled": feet that swivel on the
    heel and the ball, and glide), real feet the first version moved 9–21 cm."""
    joints = cmu_take(take)
    fixed = fix_feet(joints, T2M, FPS)
    within_the_issues_bounds(joints, fixed)
    assert (displacement(fixed, joints).max(axis=1) > 0.01).mean() < 0.05
    assert skating_ratio(fixed, T2M, FPS) <= skating_ratio(joints, T2M, FPS) + 1e-9


@pytest.mark.skipif(not BANDAI.is_dir(), reason="no Bandai Namco fixtures in tests/fixtures/bandai-namco")
def test_real_bandai_namco_takes_are_left_within_the_bounds():
    takes = sorted(BANDAI.glob("**/*.bvh"))  # laid out as the dataset's repository is
    assert takes
    for path in takes:
        joints = on_floor(take_joints(path)[0].astype(np.float64))
        within_the_issues_bounds(joints, fix_feet(joints, T2M, FPS))


def test_motion_made_to_slide_is_brought_back_near_its_clean_skating(sample_joints, sample_features):
    """HumanML3D's clip and CMU's takes with every planted stretch of each foot made to slide
    15 cm at 0.6 m/s (bench/foot_fix.py's slide_feet): fixed, they skate within 1.5 times what
    the clean clips do, and each less than it did sliding."""
    clean = [np.asarray(sample_joints, dtype=np.float64), *(cmu_take(t) for t in CMU_TAKES)]
    clean_skating, before, after = [], [], []
    for joints in clean:
        sliding = slide_feet(joints, 0.6, 0.15)
        fixed = fix_feet(sliding, T2M, FPS)
        clean_skating.append(skating_ratio(joints, T2M, FPS))
        before.append(skating_ratio(sliding, T2M, FPS))
        after.append(skating_ratio(fixed, T2M, FPS))
        np.testing.assert_allclose(T2M.bone_lengths_of(fixed), T2M.bone_lengths_of(sliding), atol=1e-9)
    assert all(a < b for a, b in zip(after, before)), (after, before)
    assert sum(before) > 1.8 * sum(clean_skating)  # the slide shows in the measure
    assert sum(after) <= 1.5 * sum(clean_skating), (after, clean_skating)


def test_synthetic_corpus_clips_made_to_slide_are_fixed_and_left_alone_otherwise():
    """The synthetic corpus (skating 0.007 over 40 clips): untouched as it is, its slid clips
    brought back within 1.5 times its skating."""
    from pipelines.synthetic import make_clip

    clips = [make_clip(index, seed=0).joints.astype(np.float64) for index in range(40)]
    clean, after = [], []
    for joints in clips:
        np.testing.assert_array_equal(fix_feet(joints, T2M, FPS), joints)
        clean.append(skating_ratio(joints, T2M, FPS))
        after.append(skating_ratio(fix_feet(slide_feet(joints, 0.6, 0.15), T2M, FPS), T2M, FPS))
    assert np.mean(after) <= 1.5 * np.mean(clean) + 1e-9, (np.mean(after), np.mean(clean))


# ----------------------------------------------------------------------- contacts judged by the joints


def standing(frames: int = 20) -> np.ndarray:
    """T2M in its rest pose, feet on the floor, for ``frames`` frames."""
    pose = rest_pose(T2M)
    pose[:, 1] -= pose[[7, 8, 10, 11], 1].min()
    return np.repeat(pose[None], frames, axis=0)


def channels(contacts: np.ndarray) -> np.ndarray:
    """Features whose contact channels are ``contacts`` (T, 4), the rest zeros."""
    features = np.zeros((len(contacts), T2M.feature_dim), dtype=np.float32)
    features[:, -4:] = contacts
    return features


def test_a_channel_saying_contact_in_the_air_is_overruled_and_a_still_low_foot_touches():
    """A model's channel saying "contact" while the left foot is 20 cm up and swinging at 3 m/s is
    wrong; the right foot low and still touches whatever its channel says."""
    joints = standing()
    swing = np.arange(20) / FPS * 3.0
    joints[:, [7, 10]] += np.stack([np.zeros(20), np.full(20, 0.2), swing], -1)[:, None]
    said = np.zeros((20, 4))
    said[:, :2] = 1.0  # the left foot "touches"; the right one does not
    contacts = foot_contacts(joints, T2M, FPS, channels(said))
    assert not contacts[:, :2].any() and contacts[:, 2:].all()


def test_a_small_real_step_is_not_a_contact_even_where_humanml3ds_rule_says_so():
    """The left foot steps 12 cm forward at 0.6 m/s, lifting 3 cm: HumanML3D's rule (slower than
    0.89 m/s) calls it touching throughout, the joints' heights do not, so it is not pinned."""
    joints = standing(24)
    s = np.clip((np.arange(24) - 8) / 4.0, 0.0, 1.0)  # the step over frames 8-12
    joints[:, [7, 10], 2] += 0.12 * s[:, None]
    joints[:, [7, 10], 1] += 0.03 * np.sin(np.pi * s)[:, None]
    contacts = foot_contacts(joints, T2M, FPS)
    assert not contacts[10, :2].any()
    np.testing.assert_array_equal(fix_feet(joints, T2M, FPS), joints)


def test_a_models_foot_it_calls_planted_sliding_faster_than_a_contact_is_believed_and_held():
    """The generated skating of the real-motion models: the left foot slides 36 cm at 1.2 m/s (faster
    than HumanML3D's rule lets a contact be) lifting 2 cm, and the model's channel says it is planted:
    the foot is in contact while it slides and creeps no faster than a real foot there. Without the
    channel the same joints are a step, and nothing moves."""
    joints = standing(30)
    s = np.clip((np.arange(30) - 5) / 6.0, 0.0, 1.0)  # 6 cm a frame over frames 5-11 at 20 fps
    joints[:, [7, 10], 2] += 0.36 * s[:, None]
    joints[:, [7, 10], 1] += 0.02 * np.sin(np.pi * s)[:, None]
    said = np.zeros((30, 4))
    said[:, :2] = 1.0
    assert foot_contacts(joints, T2M, FPS, channels(said))[5:11, :2].all()
    fixed = fix_feet(joints, T2M, FPS, channels(said))
    creep = step_speeds(fixed[6:11, 10], FPS)  # once the 2 cm it may stray is used up
    assert creep.max() <= FREE_SPEED_M_S + 1e-9 and step_speeds(joints[5:11, 10], FPS).min() > 1.0
    assert skating_ratio(fixed, T2M, FPS) < skating_ratio(joints, T2M, FPS) / 2
    np.testing.assert_array_equal(fix_feet(joints, T2M, FPS, channels(np.zeros((30, 4)))), joints)


@pytest.mark.parametrize("pivot, frames, held", [("heel", 6, 0), ("tip", 3, 1)])
def test_a_foot_turning_on_its_heel_or_its_toes_is_no_slide(pivot, frames, held):
    """The left foot turns 60° about a vertical axis through the heel over 0.3 s (its ball sweeps
    at 0.5 m/s), or through the tip of its toes over 0.15 s (the ball at 0.4 m/s, the heel too fast
    to touch): the joint on the ground moves, but the foot keeps a point still, so nothing moves."""
    joints = standing(24)
    heel, ball = joints[0, 7].copy(), joints[0, 10].copy()
    flat = (ball - heel) * np.array([1.0, 0.0, 1.0])
    centre = heel if pivot == "heel" else ball + 0.4 * np.linalg.norm(ball - heel) * flat / np.linalg.norm(flat)
    angle = np.radians(60.0) * np.clip((np.arange(24) - 6) / frames, 0.0, 1.0)
    cos, sin = np.cos(angle), np.sin(angle)
    for joint in (7, 10):
        offset = joints[0, joint] - centre
        joints[:, joint, 0] = centre[0] + cos * offset[0] + sin * offset[2]
        joints[:, joint, 2] = centre[2] - sin * offset[0] + cos * offset[2]
    ball_speed = np.linalg.norm(np.diff(joints[:, 10, [0, 2]], axis=0), axis=-1).max() * FPS
    assert 0.3 < ball_speed < 0.89  # a slide, were the foot not turning
    assert foot_contacts(joints, T2M, FPS)[:, held].all()
    np.testing.assert_array_equal(fix_feet(joints, T2M, FPS), joints)
