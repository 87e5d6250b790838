"""BVH and .npy export: the written BVH is parsed back by an independent reader and its forward
kinematics must reproduce the joints it was made from."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from m2d2m.motion.files.export import save_bvh, save_motion_npy
from m2d2m.motion.representation.rigid import best_fit_rotation
from m2d2m.motion.representation.skeleton import KIT, T2M, Skeleton


@dataclass
class Bvh:
    names: list[str]
    parents: list[int]
    offsets: np.ndarray  # (J, 3)
    channels: list[list[str]]
    end_sites: dict[int, np.ndarray]  # joint -> End Site offset
    frame_time: float
    motion: np.ndarray  # (T, channels)


def parse_bvh(path: Path) -> Bvh:
    """A small BVH reader, written for these tests only."""
    tokens = path.read_text().split()
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[list[str]] = []
    end_sites: dict[int, np.ndarray] = {}
    stack: list[int] = []
    pos = tokens.index("HIERARCHY") + 1
    while tokens[pos] != "MOTION":
        token = tokens[pos]
        if token in ("ROOT", "JOINT"):
            names.append(tokens[pos + 1])
            parents.append(stack[-1] if stack else -1)
            assert tokens[pos + 2] == "{" and tokens[pos + 3] == "OFFSET"
            offsets.append([float(x) for x in tokens[pos + 4 : pos + 7]])
            assert tokens[pos + 7] == "CHANNELS"
            count = int(tokens[pos + 8])
            channels.append(tokens[pos + 9 : pos + 9 + count])
            stack.append(len(names) - 1)
            pos += 9 + count
        elif token == "End":
            assert tokens[pos + 1 : pos + 4] == ["Site", "{", "OFFSET"] and tokens[pos + 7] == "}"
            end_sites[stack[-1]] = np.array([float(x) for x in tokens[pos + 4 : pos + 7]])
            pos += 8
        elif token == "}":
            stack.pop()
            pos += 1
        else:
            raise AssertionError(f"unexpected token {token!r}")
    assert not stack
    assert tokens[pos + 1] == "Frames:" and tokens[pos + 3 : pos + 5] == ["Frame", "Time:"]
    n_frames, frame_time = int(tokens[pos + 2]), float(tokens[pos + 5])
    values = np.array(tokens[pos + 6 :], dtype=np.float64)
    motion = values.reshape(n_frames, sum(len(c) for c in channels))
    return Bvh(names, parents, np.array(offsets), channels, end_sites, frame_time, motion)


def in_skeleton_order(bvh: Bvh, skeleton: Skeleton) -> list[int]:
    """File index of each skeleton joint (BVH lists joints depth first), checking the names."""
    assert sorted(bvh.names) == sorted(skeleton.joint_names)
    return [bvh.names.index(name) for name in skeleton.joint_names]


def axis_rotation(axis: str, degrees: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) about one coordinate axis."""
    a = np.radians(degrees)
    c, s, one, zero = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    rows = {
        "X": [[one, zero, zero], [zero, c, -s], [zero, s, c]],
        "Y": [[c, zero, s], [zero, one, zero], [-s, zero, c]],
        "Z": [[c, -s, zero], [s, c, zero], [zero, zero, one]],
    }[axis]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def bvh_forward_kinematics(bvh: Bvh) -> tuple[np.ndarray, np.ndarray]:
    """World joint positions (T, J, 3) and rotations (T, J, 3, 3) of a parsed BVH file."""
    n_frames, n_joints = len(bvh.motion), len(bvh.names)
    positions = np.zeros((n_frames, n_joints, 3))
    rotations = np.zeros((n_frames, n_joints, 3, 3))
    column = 0
    for joint, (parent, chans) in enumerate(zip(bvh.parents, bvh.channels)):
        local = np.broadcast_to(np.eye(3), (n_frames, 3, 3))
        translation = bvh.offsets[joint] + np.zeros((n_frames, 3))
        for name in chans:
            values = bvh.motion[:, column]
            column += 1
            if name.endswith("position"):
                translation[:, "XYZ".index(name[0])] += values
            else:
                local = local @ axis_rotation(name[0], values)
        if parent < 0:
            positions[:, joint], rotations[:, joint] = translation, local
        else:
            positions[:, joint] = positions[:, parent] + np.einsum("tij,tj->ti", rotations[:, parent], translation)
            rotations[:, joint] = rotations[:, parent] @ local
    return positions, rotations


def build_rigid_clip(skeleton: Skeleton, n_frames: int = 60, seed: int = 0):
    """Joints (T, J, 3) and root rotations (T, 3, 3) of a T-pose body moved by smooth random
    joint rotations (BVH semantics: a joint's rotation turns all its children)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames)[:, None, None] / 20.0
    amplitude = rng.uniform(10.0, 45.0, (1, skeleton.num_joints, 3))
    phase = rng.uniform(0.0, 2 * np.pi, (1, skeleton.num_joints, 3))
    angles = amplitude * np.sin(2 * np.pi * 0.4 * t + phase)
    angles[:, 0, 0] += np.linspace(0.0, 270.0, n_frames)  # the root turns well past 180°
    local = axis_rotation("Z", angles[..., 0]) @ axis_rotation("Y", angles[..., 1]) @ axis_rotation("X", angles[..., 2])
    offsets = skeleton.offsets()
    scale = skeleton.bone_lengths.max()
    root_path = np.stack(
        [
            np.linspace(0, 4 * scale, n_frames),
            2 * scale + 0.1 * scale * np.sin(t[:, 0, 0]),
            np.linspace(0, -3 * scale, n_frames),
        ],
        axis=1,
    )
    world = np.empty_like(local)
    joints = np.empty((n_frames, skeleton.num_joints, 3))
    world[:, 0], joints[:, 0] = local[:, 0], root_path
    for joint in skeleton.bones:
        parent = skeleton.parents[joint]
        world[:, joint] = world[:, parent] @ local[:, joint]
        joints[:, joint] = joints[:, parent] + world[:, parent] @ offsets[joint]
    return joints, world[:, 0]


@pytest.mark.parametrize("skeleton", [T2M, KIT], ids=lambda s: s.name)
def test_bvh_reproduces_rigid_fk_clip(tmp_path: Path, skeleton: Skeleton) -> None:
    joints, root_rotation = build_rigid_clip(skeleton)
    path = save_bvh(tmp_path / "clip.bvh", joints, skeleton, fps=25.0)
    bvh = parse_bvh(path)

    order = in_skeleton_order(bvh, skeleton)
    assert [bvh.names[p] if p >= 0 else None for p in np.array(bvh.parents)[order]] == [
        skeleton.joint_names[p] if p >= 0 else None for p in skeleton.parents
    ]
    assert bvh.frame_time == pytest.approx(1 / 25.0)
    assert len(bvh.motion) == len(joints)
    assert bvh.channels[0] == ["Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation"]
    assert all(c == ["Zrotation", "Yrotation", "Xrotation"] for c in bvh.channels[1:])
    unit = skeleton.bone_lengths.max()  # tolerances relative to the body, so KIT's units work
    np.testing.assert_allclose(bvh.offsets[order[1:]], skeleton.offsets()[1:], atol=1e-5 * unit)

    positions, rotations = bvh_forward_kinematics(bvh)
    assert np.abs(positions[:, order] - joints).max() < 1e-4 * unit
    # The root rotation is fully determined (Kabsch on three children): the Euler angles
    # written as text must give back the same matrices.
    assert np.abs(rotations[:, 0] - root_rotation).max() < 1e-5


def test_bvh_reproduces_real_clip(tmp_path: Path, sample_joints: np.ndarray) -> None:
    joints = sample_joints.astype(np.float64)
    bvh = parse_bvh(save_bvh(tmp_path / "012314.bvh", joints))
    positions, rotations = bvh_forward_kinematics(bvh)
    error = np.linalg.norm(positions[:, in_skeleton_order(bvh, T2M)] - joints, axis=-1).max()
    # The clip's bones and its pelvis/chest shapes are rigid to ~1e-7 m, so what is left is
    # the 1e-6 rounding of the text: far below a millimetre.
    assert error < 1e-4, f"max FK error {error:.2e} m"
    assert bvh.frame_time == pytest.approx(0.05)
    assert len(bvh.motion) == 170 and len(bvh.names) == 22

    # No flips: a flip is a jump of nearly 180° in one frame; the fastest real change in this
    # clip is the right forearm turning 66° between two frames (a fast arm swing near frame 26).
    local = np.swapaxes(rotations[:, np.array(bvh.parents[1:])], -1, -2) @ rotations[:, 1:]
    step = np.swapaxes(local[:-1], -1, -2) @ local[1:]
    cos_step = (np.trace(step, axis1=-2, axis2=-1) - 1) / 2
    step_degrees = np.degrees(np.arccos(np.clip(cos_step, -1, 1)))
    assert step_degrees.max() < 90.0
    # Euler channels are unwrapped, so a curve never jumps by a full turn.
    assert np.abs(np.diff(bvh.motion[:, 3:], axis=0)).max() < 180.0


@pytest.mark.parametrize("skeleton", [T2M, KIT], ids=lambda s: s.name)
def test_a_tpose_rest_has_the_arms_out_and_the_head_up_and_still_reproduces_the_clip(tmp_path, skeleton) -> None:
    """Issue 38, item 13: the only rest pose hung the arms down from the collars and pointed the head
    bone forward; animation tools expect a T-pose bind pose."""
    joints, _ = build_rigid_clip(skeleton, seed=1)
    bvh = parse_bvh(save_bvh(tmp_path / "t.bvh", joints, skeleton, rest_pose="tpose"))
    offsets = bvh.offsets[in_skeleton_order(bvh, skeleton)]
    directions = offsets / np.maximum(np.linalg.norm(offsets, axis=-1, keepdims=True), 1e-12)
    left, right = (
        skeleton.joint_names.index(n) for n in (("left_wrist", "right_wrist") if skeleton is T2M else ("LW", "RW"))
    )
    elbows = [skeleton.parents[left], skeleton.parents[right]]
    np.testing.assert_allclose(directions[[left, elbows[0]]], [[1, 0, 0]] * 2, atol=1e-9)  # the character's left: +X
    np.testing.assert_allclose(directions[[right, elbows[1]]], [[-1, 0, 0]] * 2, atol=1e-9)
    assert directions[skeleton.head_joint, 1] == pytest.approx(1.0)
    unit = skeleton.bone_lengths.max()
    np.testing.assert_allclose(
        np.linalg.norm(offsets, axis=-1)[1:], skeleton.bone_lengths_of(joints)[0, 1:], atol=1e-5 * unit
    )
    positions, _ = bvh_forward_kinematics(bvh)
    assert np.abs(positions[:, in_skeleton_order(bvh, skeleton)] - joints).max() < 1e-4 * unit
    leaves = {bvh.names[j] for j in bvh.end_sites}
    assert skeleton.joint_names[skeleton.head_joint] in leaves
    for j, end in bvh.end_sites.items():  # End Sites continue the leaf bone
        np.testing.assert_allclose(end, 0.5 * bvh.offsets[j], atol=1e-6)


def test_a_real_clip_on_a_tpose_rest_comes_back_below_a_millimetre(tmp_path, sample_joints) -> None:
    joints = sample_joints.astype(np.float64)
    bvh = parse_bvh(save_bvh(tmp_path / "012314.bvh", joints, rest_pose="tpose"))
    positions, _ = bvh_forward_kinematics(bvh)
    assert np.linalg.norm(positions[:, in_skeleton_order(bvh, T2M)] - joints, axis=-1).max() < 1e-4


def test_bvh_rejects_bad_input(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="shape"):
        save_bvh(tmp_path / "x.bvh", np.zeros((10, 21, 3)))
    with pytest.raises(ValueError, match="rest_pose"):
        save_bvh(tmp_path / "x.bvh", build_rigid_clip(T2M, 5)[0], rest_pose="apose")


def test_best_fit_rotation_recovers_rotation() -> None:
    rng = np.random.default_rng(3)
    rest = rng.normal(size=(4, 3))
    truth = axis_rotation("Z", np.array([30.0, 200.0])) @ axis_rotation("X", np.array([-80, 10.0]))
    fitted = best_fit_rotation(rest, rest @ np.swapaxes(truth, -1, -2))
    np.testing.assert_allclose(fitted, truth, atol=1e-10)
    assert np.allclose(np.linalg.det(fitted), 1.0)


def test_save_motion_npy_writes_conventions(tmp_path: Path, sample_joints: np.ndarray) -> None:
    joints = sample_joints
    segments = [(0, 80, "a person walks forward"), (80, 170, "turns around")]
    npy = save_motion_npy(tmp_path / "out" / "motion.npy", joints, segments=segments)
    assert npy == tmp_path / "out" / "motion.npy"
    np.testing.assert_array_equal(np.load(npy), joints.astype(np.float32))
    meta = json.loads(npy.with_suffix(".json").read_text())
    assert meta["joint_names"] == list(T2M.joint_names)
    assert meta["parents"][:4] == [-1, 0, 0, 0]
    assert meta["units"] == "metre" and meta["axes"]["up"] == "+Y" and meta["axes"]["left"] == "+X"
    assert meta["fps"] == 20.0 and meta["num_frames"] == 170 and meta["duration_s"] == 8.5
    assert meta["segments"][1] == {"start_frame": 80, "end_frame": 170, "text": "turns around"}
    with pytest.raises(ValueError, match="segment"):
        save_motion_npy(tmp_path / "bad", joints, segments=[(100, 200, "too long")])


def test_export_and_generate_say_the_rate_and_the_rest_pose(tmp_path, monkeypatch, capsys, sample_joints) -> None:
    """Blender plays a BVH at its scene's 24 fps unless "Update Scene FPS" is ticked: the command
    that writes one says its rate and bind pose, and `--rest tpose` chooses the T-pose."""
    from orchestration.cli import main

    monkeypatch.chdir(tmp_path)
    np.save(tmp_path / "clip.npy", sample_joints[:20])
    assert main(["export", "clip.npy", "--out", "clip.bvh", "--rest", "tpose"]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == (
        "clip.bvh: 20 fps (Frame Time 0.0500 s; in Blender's BVH import tick 'Update Scene FPS' or it plays "
        "at the scene's rate), rest pose a T-pose"
    )
    bvh = parse_bvh(tmp_path / "clip.bvh")
    wrist = bvh.offsets[bvh.names.index("left_wrist")]
    assert wrist[0] > 0 and abs(wrist[1]) < 1e-9 and bvh.frame_time == pytest.approx(0.05)
    assert main(["export", "clip.npy", "--out", "plain.bvh", "--fps", "30"]) == 0
    assert "plain.bvh: 30 fps" in capsys.readouterr().out
    assert parse_bvh(tmp_path / "plain.bvh").offsets[bvh.names.index("left_wrist")][1] < 0  # hanging down
