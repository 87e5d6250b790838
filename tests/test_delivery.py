"""A clip delivered as an animator asks (issue 40): the order of the edits and what each leaves
(feet planted, the frame rate, a loop, the root motion), one line for a bad request, and every
option through `m2d2m export` and `m2d2m generate` into files that read back as asked: a GLB at
30 fps in place, a BVH on CMU's rig, N variations with their seeds. The foot fix's rule: a
recorded motion is exported exactly unless `--foot-fix` asks, a generated one is fixed unless
`--no-foot-fix` asks."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pygltflib
import pytest

from bench.foot_fix import slide_feet
from m2d2m.motion.clip import Motion
from m2d2m.motion.files.bvh_reader import read_bvh
from m2d2m.motion.representation.rigid import on_rigid_skeleton
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.motion.transforms.delivery import Delivery, deliver
from m2d2m.motion.transforms.feet import fix_feet, skating_ratio
from m2d2m.motion.transforms.retime import frame_count
from orchestration.cli import main
from tests.conftest import HUMANML3D_SAMPLE
from tests.test_bvh_reader import CMU
from tests.test_export import bvh_forward_kinematics, in_skeleton_order, parse_bvh
from tests.test_generate_outputs import PROMPTS, QUICK
from tests.test_gltf import accessor_data

SAMPLE = HUMANML3D_SAMPLE
RANGES = [(0, 60), (60, 170)]


@pytest.fixture(scope="module")
def clip() -> tuple[np.ndarray, np.ndarray]:
    """HumanML3D's sample clip on one rigid body (as generate hands clips over) and its features."""
    joints = on_rigid_skeleton(np.load(SAMPLE / "new_joints" / "012314.npy"), T2M)
    features = np.load(SAMPLE / "new_joint_vecs" / "012314.npy")
    return joints, features


@pytest.fixture(scope="module")
def sliding(clip) -> np.ndarray:
    """The sample clip with its planted feet made to slide (bench/foot_fix.py), as a generated
    clip's feet do: what the foot fix is for."""
    return slide_feet(clip[0], 0.6, 0.15).astype(np.float32)


def test_a_generated_clip_has_its_feet_fixed_and_nothing_else_changed(clip, sliding):
    _, features = clip
    done = deliver(sliding, 20.0, T2M, RANGES, Delivery(), features)
    assert done.fps == 20.0 and done.ranges == RANGES and done.root_track is None
    assert done.quality["skating"] < done.quality["skating_before_fix"] / 1.5
    assert done.quality["skating"] == pytest.approx(skating_ratio(done.joints, T2M, 20.0), abs=1e-6)
    legs = [4, 5, 7, 8, 10, 11]  # knees, ankles, feet: the joints the fix may move
    others = [j for j in range(22) if j not in legs]
    np.testing.assert_array_equal(done.joints[:, others], sliding[:, others])
    np.testing.assert_allclose(done.joints, fix_feet(sliding, T2M, 20.0, features), atol=1e-6)
    raw = deliver(sliding, 20.0, T2M, RANGES, Delivery(plant_feet=False), features)
    np.testing.assert_array_equal(raw.joints, sliding)


def test_a_recorded_clip_is_delivered_exactly_unless_the_fix_is_asked_for(sliding):
    """The rule lives in Delivery.plants_feet: as asked, else generated yes, recorded no."""
    assert Delivery().plants_feet(recorded=False) and not Delivery().plants_feet(recorded=True)
    assert Delivery(plant_feet=True).plants_feet(recorded=True)
    assert not Delivery(plant_feet=False).plants_feet(recorded=False)
    exact = deliver(sliding, 20.0, T2M, RANGES, Delivery(), recorded=True)
    np.testing.assert_array_equal(exact.joints, sliding)
    assert "skating" not in exact.quality
    asked = deliver(sliding, 20.0, T2M, RANGES, Delivery(plant_feet=True), recorded=True)
    np.testing.assert_allclose(asked.joints, fix_feet(sliding, T2M, 20.0), atol=1e-6)
    assert asked.quality["skating"] < asked.quality["skating_before_fix"]
    motion = Motion(np.zeros((170, 0), np.float32), sliding, 20.0, "t2m", ["a walk"], [(0, 170)])
    assert motion.delivered(Delivery(), recorded=True).settings["delivery"]["plant_feet"] is False
    assert motion.delivered(Delivery()).settings["delivery"]["plant_feet"] is True


def test_export_writes_a_recorded_motion_exactly_and_fixes_its_feet_on_request(sliding, tmp_path, capsys):
    """`m2d2m export clip.npy --out x.npy`: the file's joints bit for bit; a BVH reproduces them
    within its printed precision (six decimals); `--foot-fix` writes the fixed feet, and asking
    for both is one line."""
    source = np.load(SAMPLE / "new_joints" / "012314.npy")  # HumanML3D's own file, float32
    np.save(tmp_path / "real.npy", source)
    np.save(tmp_path / "sliding.npy", sliding)
    for name in ("real", "sliding"):
        for flags, suffix in (([], ""), (["--no-foot-fix"], ".kept")):
            out = tmp_path / f"{name}{suffix}.out.npy"
            assert main(["export", str(tmp_path / f"{name}.npy"), "--out", str(out), *flags]) == 0
            np.testing.assert_array_equal(np.load(out), np.load(tmp_path / f"{name}.npy"))
    assert main(["export", str(tmp_path / "real.npy"), "--out", str(tmp_path / "real.bvh")]) == 0
    bvh = parse_bvh(tmp_path / "real.bvh")
    positions = bvh_forward_kinematics(bvh)[0][:, in_skeleton_order(bvh, T2M)]
    assert np.abs(positions - source).max() < 1e-4  # 1e-6 of text, through 22 joints
    assert main(["export", str(tmp_path / "sliding.npy"), "--out", str(tmp_path / "fixed.npy"), "--foot-fix"]) == 0
    fixed = np.load(tmp_path / "fixed.npy")
    np.testing.assert_allclose(fixed, fix_feet(sliding, T2M, 20.0), atol=1e-6)
    assert skating_ratio(fixed, T2M, 20.0) < skating_ratio(sliding, T2M, 20.0) / 1.5
    assert main(["export", str(tmp_path / "sliding.npy"), "--out", str(tmp_path / "fixed.bvh"), "--foot-fix"]) == 0
    bvh = parse_bvh(tmp_path / "fixed.bvh")
    assert np.abs(bvh_forward_kinematics(bvh)[0][:, in_skeleton_order(bvh, T2M)] - fixed).max() < 1e-4
    capsys.readouterr()
    argv = ["export", str(tmp_path / "real.npy"), "--out", str(tmp_path / "x.npy"), "--foot-fix", "--no-foot-fix"]
    with pytest.raises(SystemExit):
        main(argv)
    assert "not allowed with argument" in capsys.readouterr().err


def test_generate_fixes_the_feet_unless_asked_not_to(clip, sliding, tmp_path, monkeypatch):
    """`m2d2m generate`: a generated clip's feet are fixed by default, by its features' contacts,
    and left as generated with --no-foot-fix (the sampler replaced by the sliding clip)."""
    import orchestration.generate.loading
    import orchestration.generate.sampling

    _, features = clip
    made = Motion(features, sliding, 20.0, "t2m", ["a person walks"], [(0, 170)], {"method": "given"})
    made = made.on_rigid_skeleton()
    monkeypatch.setattr(orchestration.generate.loading, "load_generator", lambda *args, **kwargs: None)
    monkeypatch.setattr(orchestration.generate.sampling, "generate", lambda *args, **kwargs: made)
    argv = ["generate", "a person walks", "--formats", "npy", "--no-track", "--out"]
    assert main([*argv, str(tmp_path / "fixed")]) == 0
    assert main([*argv, str(tmp_path / "raw"), "--no-foot-fix"]) == 0
    fixed, raw = (np.load(tmp_path / name / "motion.npy") for name in ("fixed", "raw"))
    np.testing.assert_array_equal(raw, made.joints)
    np.testing.assert_allclose(fixed, fix_feet(made.joints, T2M, 20.0, features), atol=1e-6)
    assert skating_ratio(fixed, T2M, 20.0) < skating_ratio(raw, T2M, 20.0) / 1.5


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


def test_a_loops_features_are_its_cycles_frames_and_a_cycle_stays_one(clip):
    """Issue 53 §1: a looped motion's features hold the cycle's frames, as its joints do (before,
    the model's 170 frames stood beside a loop of 85), the frames it plays unfaded the model's
    own; a motion already one cycle (an edit of a loop) is delivered as that loop, whole, at
    another rate too: L frames at 20 fps are 1.5 L at 30 (resampled through the next cycle's
    first frame; without it, the cycle's last interval was lost)."""
    joints, features = clip
    motion = Motion(features, joints, 20.0, T2M.name, ["walk", "turn"], RANGES)
    looped = motion.delivered(Delivery(loop=True))
    window, cut = deliver(joints, 20.0, T2M, RANGES, Delivery(loop=True), features).loop_span
    assert looped.loop and len(looped.features) == len(looped.joints) == cut - window
    np.testing.assert_array_equal(looped.features[: cut - 2 * window], features[window : cut - window])
    # its last frame faded into the frame before its first: the seam runs on, in the features too
    seam = np.abs(looped.features[-1] - features[window - 1]).max()
    assert seam < 0.01 * np.abs(features[cut - 1] - features[window - 1]).max()
    again = looped.delivered(Delivery(fps=30.0))
    cycle = frame_count(len(looped.joints), 20.0, 30.0)  # 1.5 L, half up (docs/generation.md)
    assert again.loop and again.settings["delivery"]["loop"] and len(again.joints) == cycle
    assert again.ranges[-1][1] == cycle and again.quality["loop_travel_m"] > 0
    assert len(looped.delivered(Delivery(loop=True)).joints) == len(looped.joints)  # not cut again


@pytest.mark.parametrize(
    "options, message",
    [
        ({"fps": 0}, "fps must be a frame rate from 1 to 1000"),
        ({"root": "floating"}, "root must be one of keep, in-place, ground"),
        ({"rest_pose": "apose"}, "rest pose must be one of skeleton, tpose"),
        ({"rig": "/nowhere/rig.bvh"}, "rig /nowhere/rig.bvh: no such file (a BVH or GLB)"),
        ({"joint_map": "cmu"}, "a joint map and a rest frame go with a rig"),
        ({"rest_frame": 3}, "a joint map and a rest frame go with a rig"),
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
    said = capsys.readouterr().out
    assert "joints.npy: read at 20 fps (the t2m skeleton's; --source-fps for another)" in said
    gltf, keys = glb_clip(tmp_path / "clip.glb")
    assert keys["frames"] == 255 and keys["end"] == pytest.approx(254 / 30)  # 170 frames at 20 fps: 8.5 s
    assert "root motion" in [a.name for a in gltf.animations]
    assert "root motion: taken out of the clip" in said
    rig = CMU / "131_01.bvh"
    argv = ["export", str(tmp_path / "joints.npy"), "--out", str(tmp_path / "on-cmu.bvh"), "--rig", str(rig)]
    assert main([*argv, "--joint-map", "cmu"]) == 0
    written = read_bvh(tmp_path / "on-cmu.bvh")
    assert written.names == read_bvh(rig).names and len(written.values) == 170
    assert "rest pose the rig's own (131_01.bvh)" in capsys.readouterr().out
    assert main([*argv, "--joint-map", "mixamo", "--overwrite"]) == 2
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
    assert f"{tmp_path / 'm.npy'}: read at 30 fps (its sidecar's)" in capsys.readouterr().out
    again = json.loads((tmp_path / "again.json").read_text(encoding="utf-8"))
    assert again["fps"] == 30.0 and [s["text"] for s in again["segments"]] == actions
    assert "root_motion" not in again  # kept: the clip's own path is back in its joints
    np.testing.assert_allclose(np.load(tmp_path / "again.npy"), motion.joints + motion.root_track[:, None], atol=1e-5)
    argv = ["export", str(tmp_path / "m.npy"), "--out", str(tmp_path / "again.glb"), "--root", "in-place"]
    assert main(argv) == 0
    _, keys = glb_clip(tmp_path / "again.glb")
    assert keys["frames"] == len(motion.joints) and keys["end"] == pytest.approx((len(motion.joints) - 1) / 30)
    np.save(tmp_path / "m.npy", joints)  # 170 frames now, the sidecar's 255
    capsys.readouterr()
    assert main(["export", str(tmp_path / "m.npy"), "--out", str(tmp_path / "x.bvh")]) == 2
    assert "m.json: states 255 frames, m.npy has 170; it belongs to another file" in capsys.readouterr().err


@pytest.mark.slow
def test_generate_writes_the_issues_clip_and_variations_with_their_seeds(trained_project, tmp_path, capsys):
    """`m2d2m generate "a person walks forward" "a person jumps" --out clip.glb --fps 30 --root in-place`."""
    out = tmp_path / "clip.glb"
    assert main(["generate", *PROMPTS, *QUICK, "--out", str(out), "--fps", "30", "--root", "in-place"]) == 0
    _, keys = glb_clip(out)
    assert keys["end"] == pytest.approx(71 / 30, abs=1e-6)  # two 1.2-s actions: 48 frames at 20 fps, 72 at 30
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
    assert main(["generate", "a person walks", "--out", str(tmp_path / "x.gif"), "--rig", str(CMU / "131_01.bvh")]) == 2
    assert "--rig goes with a BVH, GLB or FBX, the formats written on a rig" in capsys.readouterr().err


@pytest.mark.parametrize("root", ["keep", "in-place"])
def test_a_looped_glb_ends_on_its_first_pose_moved_on_by_a_cycle(clip, tmp_path, root):
    """Issue 53, finding 8: a looped GLB had no closing key, so an engine looping "clip" went from
    its last key to its first in no time, and a cycle lasted a frame less than the loop."""
    joints, features = clip
    motion = Motion(features, joints, 20.0, "t2m", ["a person walks"], [(0, 170)])
    looped = motion.delivered(Delivery(loop=True, root=root))
    frames, travel = len(looped.joints), looped.loop_travel
    looped.save(tmp_path, "loop", ("glb",))
    gltf = pygltflib.GLTF2().load(str(tmp_path / "loop.glb"))
    assert gltf.scenes[0].extras["num_frames"] == frames
    kept = np.zeros(3) if root == "in-place" else travel  # an in-place clip's path travels in "root motion"
    closing = {"clip": kept, "root motion": travel} if root == "in-place" else {"clip": kept}
    for name, moved in closing.items():
        animation = next(a for a in gltf.animations if a.name == name)
        assert animation.extras == {"start_frame": 0, "end_frame": frames, "closing_key": True}
        times = accessor_data(gltf, animation.samplers[0].input)
        assert len(times) == frames + 1 and times[-1] == pytest.approx(frames / 20.0)
        for channel in animation.channels:
            keys = accessor_data(gltf, animation.samplers[channel.sampler].output).astype(np.float64)
            if channel.target.path == "rotation":  # q and -q are one rotation
                assert abs(np.dot(keys[-1], keys[0])) == pytest.approx(1.0, abs=1e-6)
            else:
                assert keys[-1] == pytest.approx(keys[0] + moved, abs=1e-5)
    actions = [a for a in gltf.animations if a.name == "a person walks"]
    assert all(accessor_data(gltf, a.samplers[0].input).shape[0] <= frames for a in actions)


def test_a_loop_exported_from_its_npy_closes_as_it_was_delivered(clip, tmp_path):
    """A loop's sidecar says it is one: `m2d2m export` of its .npy to GLB closes the loop again
    (the export had no closing key without --loop)."""
    joints, features = clip
    looped = Motion(features, joints, 20.0, "t2m", ["a person walks"], [(0, 170)]).delivered(Delivery(loop=True))
    looped.save(tmp_path, "loop", ("npy", "glb"))
    assert main(["export", str(tmp_path / "loop.npy"), "--out", str(tmp_path / "again.glb")]) == 0
    for name in ("loop.glb", "again.glb"):
        gltf = pygltflib.GLTF2().load(str(tmp_path / name))
        clip_animation = next(a for a in gltf.animations if a.name == "clip")
        assert clip_animation.extras["closing_key"] is True
        assert len(accessor_data(gltf, clip_animation.samplers[0].input)) == len(looped.joints) + 1


def test_a_span_sampled_without_text_is_named_in_every_file(clip, tmp_path):
    """Issue 53, finding 8: a gap filled without text (`--fill-to` with no prompt) was a nameless
    span on the page's timeline, in the GLB's animations and in the sidecar."""
    joints, features = clip
    ranges = [(0, 60), (60, 100), (100, 170)]
    motion = Motion(features, joints, 20.0, "t2m", ["a person walks", "", "a person sits down"], ranges)
    assert [text for _, _, text in motion.segments] == ["a person walks", "transition", "a person sits down"]
    motion.save(tmp_path, "filled", ("npy", "glb"))
    sidecar = json.loads((tmp_path / "filled.json").read_text(encoding="utf-8"))
    assert [s["text"] for s in sidecar["segments"]] == ["a person walks", "transition", "a person sits down"]
    gltf = pygltflib.GLTF2().load(str(tmp_path / "filled.glb"))
    assert [a.name for a in gltf.animations] == ["clip", "a person walks", "transition", "a person sits down"]
    assert motion.actions[1] == ""  # what an edit samples it with again: the model's null condition
