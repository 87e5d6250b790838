"""A rig's joints as T2M's 22 (issue 39, §1 and §3): CMU's real takes through the preset map at
HumanML3D's frame counts, into features that decode back to the joints, on one rigid skeleton,
walking forward with their feet on the floor; CMU's two releases' names giving the same joints;
a user's YAML map; and bad maps or files in one sentence."""

from __future__ import annotations

import re

import numpy as np
import pytest
import yaml

from m2d2m.motion.files.bvh_reader import BvhError, read_bvh, resample
from m2d2m.motion.files.export import save_bvh
from m2d2m.motion.representation.features import canonicalize, features_to_joints, joints_to_features
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.motion.rigs.joint_map import PRESETS, JointMap, joint_map_for
from tests.test_bvh_reader import CMU, CMU_METRES, HUMANML3D_FRAMES
from tests.test_export import build_rigid_clip

# CMU's ASF bones in cgspeed's two releases: the 3dsMax-friendly names → the MotionBuilder-friendly ones
MOTIONBUILDER_NAMES = {
    "LeftHip": "LeftUpLeg", "LeftKnee": "LeftLeg", "LeftAnkle": "LeftFoot", "LeftToe": "LeftToeBase",
    "RightHip": "RightUpLeg", "RightKnee": "RightLeg", "RightAnkle": "RightFoot", "RightToe": "RightToeBase",
    "lowerback": "LowerBack", "Chest": "Spine", "Chest2": "Spine1", "lowerneck": "Neck", "Neck": "Neck1",
    "LeftCollar": "LeftShoulder", "LeftShoulder": "LeftArm", "LeftElbow": "LeftForeArm", "LeftWrist": "LeftHand",
    "RightCollar": "RightShoulder", "RightShoulder": "RightArm", "RightElbow": "RightForeArm",
    "RightWrist": "RightHand", "lhand": "LeftFingerBase", "LFingers": "LeftHandIndex1",
    "rhand": "RightFingerBase", "RFingers": "RightHandIndex1",
}  # fmt: skip


@pytest.mark.parametrize("take", sorted(HUMANML3D_FRAMES))
def test_a_real_cmu_take_becomes_t2m_features_of_a_person_walking_on_the_floor(take):
    clip = read_bvh(CMU / f"{take}.bvh", CMU_METRES)
    assert joint_map_for(clip) is PRESETS["cmu"]
    joints = resample(PRESETS["cmu"].joints(clip), clip.fps, 20.0)
    assert joints.shape == (HUMANML3D_FRAMES[take], 22, 3)
    features = joints_to_features(joints)
    body = canonicalize(joints)  # HumanML3D's target skeleton, on the floor, facing +Z at frame 0
    assert np.abs(np.asarray(features_to_joints(features)) - body[:-1]).max() < 1e-5
    assert np.ptp(T2M.bone_lengths_of(body), axis=0).max() < 1e-9
    # metres walked (or hopped) forward over the take, in the body's own frame: left and right not swapped
    forward, sideways = features[:, 2].sum(), abs(features[:, 1].sum())
    assert forward > 1.0 and forward > 2 * sideways
    feet = body[:, list(T2M.feet_left + T2M.feet_right), 1].min(axis=1)
    assert np.mean(feet < 0.1) > 0.95  # a foot (its ankle or ball joint) on the floor in nearly every frame
    assert 1.3 < np.median(body[:, T2M.head_joint, 1] - feet) < 1.7


def motionbuilder_release(take: str) -> str:
    """A take of the 3dsMax-friendly release as the MotionBuilder-friendly one writes it: its
    joints renamed, and a T-pose (every channel zero) as its first frame."""
    text = (CMU / f"{take}.bvh").read_text(encoding="utf-8")
    renamed = re.sub(r"\b(ROOT|JOINT) (\S+)", lambda m: f"{m[1]} {MOTIONBUILDER_NAMES.get(m[2], m[2])}", text)
    head, frames = renamed.split("Frame Time:")
    frame_time, first, rest = frames.lstrip().split("\n", 2)
    count = int(head.rsplit("Frames:", 1)[1])
    tpose = " ".join(["0"] * len(first.split()))
    head = head.rsplit("Frames:", 1)[0] + f"Frames: {count + 1}\n"
    return f"{head}Frame Time: {frame_time}\n{tpose}\n{first}\n{rest}"


def test_cmus_two_releases_give_the_same_joints(tmp_path):
    (tmp_path / "131_01.bvh").write_text(motionbuilder_release("131_01"), encoding="utf-8")
    theirs = read_bvh(tmp_path / "131_01.bvh", CMU_METRES)
    assert joint_map_for(theirs) is PRESETS["cmu-motionbuilder"]
    ours = read_bvh(CMU / "131_01.bvh", CMU_METRES)
    np.testing.assert_array_equal(PRESETS["cmu-motionbuilder"].joints(theirs), PRESETS["cmu"].joints(ours))


def test_a_users_yaml_map_reads_their_rig(tmp_path):
    joints, _ = build_rigid_clip(T2M, n_frames=12)
    clip = read_bvh(save_bvh(tmp_path / "mine.bvh", joints))
    mapping = {name: name for name in T2M.joint_names} | {"spine2": ["spine1", "spine3"]}
    (tmp_path / "map.yaml").write_text(yaml.safe_dump(mapping), encoding="utf-8")
    mapped = joint_map_for(clip, tmp_path / "map.yaml").joints(clip)
    expected = joints.copy()
    expected[:, 6] = (joints[:, 3] + joints[:, 9]) / 2
    assert np.abs(mapped - expected).max() < 1e-4
    assert joint_map_for(clip) is PRESETS["smpl"]  # our own BVH: SMPL's names
    assert np.abs(PRESETS["smpl"].joints(clip) - joints).max() < 1e-4


@pytest.mark.parametrize(
    "mapping, message",
    [
        ({"pelvis": "Hips"}, "it leaves out left_hip, right_hip"),
        ({**{n: n for n in T2M.joint_names}, "tail": "Tail"}, "t2m has no joint tail"),
        ({**{n: n for n in T2M.joint_names}, "head": []}, "no joint of the rig given for head"),
        (["pelvis"], "a joint map is a mapping"),
        (
            {**{n: n for n in T2M.joint_names}, "head": ["Head", ["Neck"]]},
            "head: a list of their joints holds names only",
        ),
    ],
    ids=["incomplete", "unknown joint", "empty", "a list", "a nested list"],
)
def test_a_bad_map_is_one_sentence(tmp_path, mapping, message):
    (tmp_path / "map.yaml").write_text(yaml.safe_dump(mapping), encoding="utf-8")
    with pytest.raises(ValueError, match=message) as error:
        JointMap.from_yaml(tmp_path / "map.yaml").check()  # a map that names some joints corrects the automatic one
    assert "\n" not in str(error.value)


def test_a_few_lines_of_yaml_aliases_are_refused_before_they_expand(tmp_path):
    """A billion-laughs map (each list ten of the one before) is refused as it is read."""
    lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, 9)]
    (tmp_path / "map.yaml").write_text("\n".join([*lines, "head: *a8"]) + "\n", encoding="utf-8")
    with pytest.raises(ValueError, match="a list of their joints holds names only"):
        JointMap.from_yaml(tmp_path / "map.yaml")


def test_a_bvh_without_a_mapped_joint_names_it(tmp_path):
    text = (CMU / "131_01.bvh").read_text(encoding="utf-8").replace("JOINT LeftElbow", "JOINT LeftElbo")
    (tmp_path / "cut.bvh").write_text(text, encoding="utf-8")
    with pytest.raises(BvhError, match="joint map cmu reads LeftElbow, which the BVH lacks"):
        PRESETS["cmu"].joints(read_bvh(tmp_path / "cut.bvh", CMU_METRES))
