"""Reading BVH (issue 39, §1): forward kinematics for any channel and rotation order checked against
SciPy's Euler angles and against our own writer's files; CMU's real takes (tests/fixtures/cmu-bvh)
in metres, cross-checked against the same take converted to metres by someone else, at HumanML3D's
frame counts; and every malformed file a one-sentence error."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from m2d2m.motion.files.bvh_reader import BvhError, read_bvh, resample
from m2d2m.motion.files.export import save_bvh
from m2d2m.motion.representation.skeleton import KIT, T2M
from tests.test_export import build_rigid_clip

CMU = Path(__file__).parent / "fixtures" / "cmu-bvh"
CMU_METRES = 0.056444  # cgspeed's unit: 1/0.45 inch
# HumanML3D's rows of these takes end at these 20-fps frames (its index.csv): the whole take
HUMANML3D_FRAMES = {"131_01": 166, "131_02": 208, "131_03": 184}


@pytest.mark.parametrize("skeleton", [T2M, KIT], ids=lambda s: s.name)
@pytest.mark.parametrize("rest_pose", ["skeleton", "tpose"])
def test_our_own_bvh_reads_back_as_the_joints_it_was_written_from(tmp_path, skeleton, rest_pose):
    joints, _ = build_rigid_clip(skeleton, n_frames=30)
    clip = read_bvh(save_bvh(tmp_path / "clip.bvh", joints, skeleton, fps=30.0, rest_pose=rest_pose))
    assert clip.names[0] == skeleton.joint_names[0] and sorted(clip.names) == sorted(skeleton.joint_names)
    order = [clip.joint(name) for name in skeleton.joint_names]
    assert clip.fps == pytest.approx(30.0)
    assert np.abs(clip.positions()[:, order] - joints).max() < 1e-4 * skeleton.bone_lengths.max()


@pytest.mark.parametrize("order", ["XYZ", "ZXY", "YZX", "ZYX", "XZY", "YXZ"])
def test_any_rotation_order_composes_as_the_channels_are_listed(tmp_path, order):
    """A two-joint chain whose child's rotation channels come in ``order``: the child's End Site
    lands where SciPy's intrinsic Euler rotation of that order puts it."""
    rng = np.random.default_rng(len(order) + ord(order[0]))
    angles = rng.uniform(-170, 170, size=(5, 3))
    root = rng.normal(size=(5, 3))
    channels = " ".join(f"{axis}rotation" for axis in order)
    frames = "\n".join(" ".join(f"{v:.6f}" for v in (*root[t], 0, 0, 0, *angles[t], 0, 0, 0)) for t in range(5))
    (tmp_path / "chain.bvh").write_text(
        "HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation\n"
        f" JOINT b\n {{\n  OFFSET 0 1 0\n  CHANNELS 3 {channels}\n  JOINT c\n  {{\n   OFFSET 0.3 0.5 -0.2\n"
        "   CHANNELS 3 Zrotation Yrotation Xrotation\n   End Site\n   {\n    OFFSET 0 0 1\n   }\n  }\n }\n}\n"
        f"MOTION\nFrames: 5\nFrame Time: 0.05\n{frames}\n",
        encoding="utf-8",
    )
    clip = read_bvh(tmp_path / "chain.bvh")
    expected = root + [0, 1, 0] + Rotation.from_euler(order, angles, degrees=True).apply([0.3, 0.5, -0.2])
    np.testing.assert_allclose(clip.positions()[:, clip.joint("c")], expected, atol=1e-6)
    assert clip.end_sites == {2: pytest.approx(np.array([0.0, 0.0, 1.0]))}


def test_position_channels_of_a_joint_replace_its_offset(tmp_path):
    (tmp_path / "slide.bvh").write_text(
        "HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Zposition\n JOINT b\n {\n"
        "  OFFSET 5 5 5\n  CHANNELS 6 Xposition Yposition Zposition Xrotation Yrotation Zrotation\n"
        "  End Site\n  {\n   OFFSET 0 0 1\n  }\n }\n}\nMOTION\nFrames: 1\nFrame Time: 0.1\n1 2 3 0.5 0 0 0 0 0\n",
        encoding="utf-8",
    )
    clip = read_bvh(tmp_path / "slide.bvh", metres_per_unit=0.5)  # positions and offsets alike
    np.testing.assert_allclose(clip.positions()[0], [[0.5, 1.0, 1.5], [0.75, 1.0, 1.5]])


@pytest.mark.parametrize("take", sorted(HUMANML3D_FRAMES))
def test_a_real_cmu_take_reads_in_metres_at_humanml3ds_frame_count(take):
    clip = read_bvh(CMU / f"{take}.bvh", CMU_METRES)
    assert len(clip.names) == 31 and clip.names[0] == "Hips" and clip.fps == pytest.approx(120.0, rel=1e-4)
    positions = clip.positions()
    assert len(resample(positions, clip.fps, 20.0)) == HUMANML3D_FRAMES[take]
    # a rigid skeleton: every bone keeps its length in every frame
    bones = np.linalg.norm(positions[:, 1:] - positions[:, clip.parents[1:]], axis=-1)
    assert np.ptp(bones, axis=0).max() < 1e-9
    # a person standing on CMU's floor (y = 0): the head's base 1.2–1.5 m above the lower toe, and
    # that toe joint (a few cm above the sole) below 12 cm in nearly every frame of a walk or a hop
    toes = positions[:, [clip.joint("LeftToe"), clip.joint("RightToe")], 1].min(axis=1)
    assert 1.2 < np.median(positions[:, clip.joint("Head"), 1] - toes) < 1.5
    assert toes.min() > 0.0 and np.mean(toes < 0.12) > 0.95


def test_cmus_units_agree_with_the_same_take_converted_to_metres_by_someone_else():
    """bvh11's scaled_131_01.bvh is 131_01 in metres (one frame longer): our unit conversion and
    forward kinematics give its joints to a few micrometres."""
    ours = read_bvh(CMU / "131_01.bvh", CMU_METRES).positions()
    theirs = read_bvh(CMU / "scaled_131_01.bvh").positions()
    assert np.abs(ours - theirs[: len(ours)]).max() < 1e-5


def test_resampling_takes_every_nth_frame_or_interpolates():
    positions = np.arange(10.0)[:, None, None] * np.ones((1, 2, 3))
    np.testing.assert_array_equal(resample(positions, 120.0, 20.0)[:, 0, 0], [0.0, 6.0])
    half = resample(positions, 30.0, 20.0)[:, 0, 0]  # 1.5 source frames a target frame
    np.testing.assert_allclose(half, [0.0, 1.5, 3.0, 4.5, 6.0, 7.5, 9.0])


@pytest.mark.parametrize(
    "text, message",
    [
        ("", "not a BVH file"),
        ("ROOT a { OFFSET 0 0 0 }\nMOTION\nFrames: 1\nFrame Time: 0.1\n0\n", "not a BVH file"),
        (
            "HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 1 Xposition\n}\nMOTION\nFrames: 0\nFrame Time: 0.1\n",
            "no frames",
        ),
        (
            "HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 1 Xposition\n}\nMOTION\nFrames: 1\nFrame Time: 0.1\nnan\n",
            "NaN",
        ),
        (
            "HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 1 Xposition\n}\nMOTION\nFrames: 2\nFrame Time: 0.1\n1\n",
            "2 frames",
        ),
        (
            "HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 1 Xposition\n}\nMOTION\nFrames: 1\nFrame Time: 0\n1\n",
            "Frame Time",
        ),
        (
            "HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 1 Wrotation\n}\nMOTION\nFrames: 1\nFrame Time: 0.1\n1\n",
            "unknown channel",
        ),
        ("HIERARCHY\nROOT a\n{\n OFFSET 0 0\n", "not a BVH file"),
        (
            "HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n CHANNELS 1 Xposition\nMOTION\nFrames: 1\nFrame Time: 0.1\n1\n",
            "unclosed",
        ),
        ("HIERARCHY\nJOINT a\n{\n OFFSET 0 0 0\n}\nMOTION\nFrames: 1\nFrame Time: 0.1\n\n", "wrong place"),
    ],
    ids=[
        "empty",
        "no HIERARCHY",
        "zero frames",
        "NaN",
        "fewer lines",
        "no frame time",
        "bad channel",
        "no MOTION",
        "unclosed",
        "JOINT as root",
    ],
)
def test_a_malformed_file_is_one_sentence(tmp_path, text, message):
    (tmp_path / "bad.bvh").write_text(text, encoding="utf-8")
    with pytest.raises(BvhError, match=message) as error:
        read_bvh(tmp_path / "bad.bvh")
    assert str(error.value).startswith(str(tmp_path / "bad.bvh")) and "\n" not in str(error.value)
