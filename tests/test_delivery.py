"""A clip delivered as an animator asks (issue 40): the order of the edits and what each leaves
(feet planted, the frame rate, a loop, the root motion), one line for a bad request, and every
option through `m2d2m export` and `m2d2m generate` into files that read back as asked: a GLB at
30 fps in place, a BVH on CMU's rig, N variations with their seeds."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pygltflib
import pytest

from m2d2m.motion.bvh_reader import read_bvh
from m2d2m.motion.clip import Motion
from m2d2m.motion.delivery import Delivery, deliver
from m2d2m.motion.feet import skating_ratio
from m2d2m.motion.rigid import on_rigid_skeleton
from m2d2m.motion.skeleton import T2M
from orchestration.cli import main
from tests.conftest import HUMANML3D_SAMPLE
from tests.test_bvh_reader import CMU
from tests.test_generate_outputs import PROMPTS, QUICK

SAMPLE = HUMANML3D_SAMPLE
RANGES = [(0, 60), (60, 170)]


@pytest.fixture(scope="module")
def clip() -> tuple[np.ndarray, np.ndarray]:
    """HumanML3D's sample clip on one rigid body (as generate hands clips over) and its features."""
    joints = on_rigid_skeleton(np.load(SAMPLE / "new_joints" / "012314.npy"), T2M)
    features = np.load(SAMPLE / "new_joint_vecs" / "012314.npy")
    return joints, features


def test_the_default_plants_the_feet_and_changes_nothing_else(clip):
    joints, features = clip
    done = deliver(joints, 20.0, T2M, RANGES, Delivery(), features)
    assert done.fps == 20.0 and done.ranges == RANGES and done.root_track is None
    assert done.quality["skating"] <= done.quality["skating_before_fix"]
    assert done.quality["skating"] == pytest.approx(skating_ratio(done.joints, T2M, 20.0), abs=1e-6)
    legs = [4, 5, 7, 8, 10, 11]  # knees, ankles, feet: the joints the fix may move
    others = [j for j in range(22) if j not in legs]
    np.testing.assert_allclose(done.joints[:, others], joints[:, others], atol=1e-6)
    raw = deliver(joints, 20.0, T2M, RANGES, Delivery(plant_feet=False), features)
    np.testing.assert_allclose(raw.joints, joints, atol=1e-6)


def test_frame_rate_loop_and_root_follow_each_other_with_the_actions(clip):
    joints, features = clip
    done = deliver(joints, 20.0, T2M, RANGES, Delivery(fps=30, loop=True, root="in-place"), features)
    assert done.fps == 30.0
    assert 0 < len(done.joints) < 170 * 1.5  # one cycle, cut from the clip at 30 fps
    assert done.ranges and all(0 <= a < b <= len(done.joints) for a, b in done.ranges)
    assert len(done.kept) == len(done.ranges) and set(done.kept) <= {0, 1} and done.kept == sorted(done.kept)
    np.testing.assert_allclose(done.joints[:, 0, [0, 2]], 0.0, atol=1e-6)  # in place
    assert done.root_track is not None and done.root_track.shape == (len(done.joints), 3)
    assert "loop_travel_m" in done.quality


@pytest.mark.parametrize(
    "options, message",
    [
        ({"fps": 0}, "fps must be a frame rate from 1 to 1000"),
        ({"root": "floating"}, "root must be one of keep, in-place, ground"),
        ({"rest_pose": "apose"}, "rest pose must be one of skeleton, tpose"),
        ({"rig": "/nowhere/rig.bvh"}, "rig /nowhere/rig.bvh: no such file (a BVH or GLB)"),
        ({"joint_map": "cmu"}, "a joint map goes with a rig"),
    ],
)
def test_a_delivery_no_clip_can_take_is_one_line(options, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        Delivery(**options)


def glb_clip(path: Path) -> tuple[pygltflib.GLTF2, dict]:
    """The file, and its "clip" animation's key times."""
    gltf = pygltflib.GLTF2().load(str(path))
    animation = next(a for a in gltf.animations if a.name == "clip")
    sampler = animation.samplers[animation.channels[0].sampler]
    return gltf, {"frames": gltf.accessors[sampler.input].count, "end": gltf.accessors[sampler.input].max[0]}


def test_export_writes_a_glb_at_30_fps_in_place_and_a_bvh_on_cmus_rig(clip, tmp_path, capsys):
    joints, _ = clip
    np.save(tmp_path / "joints.npy", joints)
    assert (
        main(
            [
                "export",
                str(tmp_path / "joints.npy"),
                "--out",
                str(tmp_path / "clip.glb"),
                "--fps",
                "30",
                "--root",
                "in-place",
            ]
        )
        == 0
    )
    gltf, keys = glb_clip(tmp_path / "clip.glb")
    assert keys["frames"] == 254 and keys["end"] == pytest.approx(253 / 30)  # 170 frames at 20 fps
    assert "root motion" in [a.name for a in gltf.animations]
    assert "root motion: taken out of the clip" in capsys.readouterr().out
    rig = CMU / "131_01.bvh"
    argv = ["export", str(tmp_path / "joints.npy"), "--out", str(tmp_path / "on-cmu.bvh"), "--rig", str(rig)]
    assert main([*argv, "--joint-map", "cmu"]) == 0
    written = read_bvh(tmp_path / "on-cmu.bvh")
    assert written.names == read_bvh(rig).names and len(written.values) == 170
    assert "rest pose the rig's own (131_01.bvh)" in capsys.readouterr().out
    assert main([*argv, "--joint-map", "mixamo"]) == 2
    assert "joint map mixamo reads mixamorig:Head, mixamorig:Hips" in capsys.readouterr().err


def test_a_motion_saves_its_root_track_beside_the_npy(clip, tmp_path):
    joints, features = clip
    motion = Motion(features, joints, 20.0, "t2m", ["a person walks"], [(0, 170)]).delivered(Delivery(root="in-place"))
    files = motion.save(tmp_path, "m", ("npy", "glb"))
    sidecar = json.loads((tmp_path / "m.json").read_text(encoding="utf-8"))
    assert sidecar["root_motion"] == "m.root_motion.npy"
    track = np.load(tmp_path / "m.root_motion.npy")
    np.testing.assert_allclose(np.load(files["npy"]) + track[:, None], motion.joints + motion.root_track[:, None])
    assert motion.settings["delivery"]["root"] == "in-place"


def test_export_reads_what_an_npys_sidecar_says(clip, tmp_path, capsys):
    """An npy of ours at 30 fps, in place, with two actions: exported again it keeps its rate and
    actions, its root motion is put back (in place again on request), and a sidecar of another
    file is one line."""
    joints, features = clip
    actions = ["a person walks", "a person stops"]
    motion = Motion(features, joints, 20.0, "t2m", actions, RANGES).delivered(Delivery(fps=30.0, root="in-place"))
    motion.save(tmp_path, "m", ("npy",))
    assert main(["export", str(tmp_path / "m.npy"), "--out", str(tmp_path / "again.npy"), "--no-foot-fix"]) == 0
    again = json.loads((tmp_path / "again.json").read_text(encoding="utf-8"))
    assert again["fps"] == 30.0 and [s["text"] for s in again["segments"]] == actions
    assert "root_motion" not in again  # kept: the clip's own path is back in its joints
    np.testing.assert_allclose(np.load(tmp_path / "again.npy"), motion.joints + motion.root_track[:, None], atol=1e-5)
    argv = ["export", str(tmp_path / "m.npy"), "--out", str(tmp_path / "again.glb"), "--root", "in-place"]
    assert main(argv) == 0
    _, keys = glb_clip(tmp_path / "again.glb")
    assert keys["frames"] == len(motion.joints) and keys["end"] == pytest.approx((len(motion.joints) - 1) / 30)
    np.save(tmp_path / "m.npy", joints)  # 170 frames now, the sidecar's 254
    capsys.readouterr()
    assert main(["export", str(tmp_path / "m.npy"), "--out", str(tmp_path / "x.bvh")]) == 2
    assert "m.json: states 254 frames, m.npy has 170; it belongs to another file" in capsys.readouterr().err


@pytest.mark.slow
def test_generate_writes_the_issues_clip_and_variations_with_their_seeds(trained_project, tmp_path, capsys):
    """`m2d2m generate "a person walks forward" "a person jumps" --out clip.glb --fps 30 --root in-place`."""
    out = tmp_path / "clip.glb"
    assert main(["generate", *PROMPTS, *QUICK, "--out", str(out), "--fps", "30", "--root", "in-place"]) == 0
    _, keys = glb_clip(out)
    assert keys["end"] == pytest.approx(70 / 30, abs=1e-6)  # two 1.2-s actions: 48 frames at 20 fps, 71 at 30
    folder = tmp_path / "picks"
    assert (
        main(
            ["generate", *PROMPTS, *QUICK, "--out", str(folder), "--formats", "npy", "--variations", "2", "--seed", "7"]
        )
        == 0
    )
    first, second = (np.load(folder / f"motion-seed{seed}.npy") for seed in (7, 8))
    assert first.shape == second.shape and not np.allclose(first, second)


def test_a_delivery_the_clip_cannot_take_is_one_line(clip, tmp_path, capsys):
    joints, _ = clip
    np.save(tmp_path / "short.npy", joints[:12])
    assert main(["export", str(tmp_path / "short.npy"), "--out", str(tmp_path / "x.glb"), "--loop"]) == 2
    assert "a loop needs at least 15 frames (0.75 s), got 12" in capsys.readouterr().err
    assert main(["generate", "a person walks", "--out", str(tmp_path / "x.glb"), "--rig", str(CMU / "131_01.bvh")]) == 2
    assert "--rig goes with a BVH, the format written on a rig" in capsys.readouterr().err
