"""The Blender add-on (integrations/blender/m2d2m_blender, docs/generation.md "In Blender").

Fast: its pure-Python parts, imported without Blender: the rest pose sent as a BVH and read back
by m2d2m's own reader, the clip's BVH read as m2d2m reads it, the pose-bone arithmetic, the
timeline's spans and the client's one-line refusals. Slow: Debian's Blender in background mode
installs the add-on's zip and drives its operators against a server on the tests' tiny trained
model, on an armature built in the script and on CMU's rig imported by Blender's BVH importer."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import urllib.error
import zipfile
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from m2d2m.motion.files.bvh_reader import read_bvh as read_bvh_file
from orchestration.web.app import ServeSettings
from tests.live_server import live_server

ADDON = Path(__file__).resolve().parents[1] / "integrations" / "blender"
sys.path.insert(0, str(ADDON))

from m2d2m_blender import bvh, client, timeline  # noqa: E402  (the add-on's folder is no package of ours)
from pack import pack  # noqa: E402

BLENDER = shutil.which("blender")
needs_blender = pytest.mark.skipif(BLENDER is None, reason="no blender here (apt-get install blender python3-numpy)")
CMU = Path(__file__).resolve().parent / "fixtures" / "cmu-bvh" / "131_01.bvh"
SESSION = Path(__file__).resolve().parent / "blender_addon_session.py"

# three bones in Blender's axes (Z up): a root at the hips, a leg down to the floor, a spine up
BONES = [
    bvh.Bone("Hips", -1, (0.0, 0.0, 1.0), (0.0, 0.0, 1.1)),
    bvh.Bone("Left Leg", 0, (0.1, 0.0, 1.0), (0.1, 0.0, 0.1)),
    bvh.Bone("Spine", 0, (0.0, 0.0, 1.1), (0.0, 0.05, 1.5)),
]


def test_the_rest_pose_is_a_one_frame_bvh_that_m2d2m_reads_with_the_bones_where_they_stand(tmp_path):
    path = tmp_path / "rig.bvh"
    path.write_text(bvh.rest_bvh(BONES))
    rig = read_bvh_file(path)
    assert list(rig.names) == ["Hips", "Left_Leg", "Spine"]  # one word a joint
    heads_y_up = np.array([[x, z, -y] for x, y, z in (bone.head for bone in BONES)])
    np.testing.assert_allclose(rig.positions()[0], heads_y_up, atol=1e-6)
    np.testing.assert_allclose(rig.rest_positions(), heads_y_up, atol=1e-6)  # the root's OFFSET: where it stands
    np.testing.assert_allclose(rig.end_sites[1], [0.0, -0.9, 0.0], atol=1e-6)  # the leg's tail, down in Y-up
    np.testing.assert_allclose(rig.end_sites[2], [0.0, 0.4, -0.05], atol=1e-6)


def test_names_that_are_no_bvh_word_become_one_each_and_stay_distinct():
    assert bvh.bvh_names(["Bip01 L Thigh", "Bip01_L_Thigh", " ", "mixamorig:Hips"]) == [
        "Bip01_L_Thigh",
        "Bip01_L_Thigh.002",
        "bone",
        "mixamorig:Hips",
    ]


def test_a_bvh_is_read_as_m2d2m_reads_it_root_and_every_joints_turn():
    clip = bvh.read_bvh(CMU.read_text())
    reference = read_bvh_file(CMU)
    assert clip.names == list(reference.names) and clip.parents == list(reference.parents)
    world, _ = reference.pose()
    for frame in (0, 150):
        root, local = clip.pose(frame)
        np.testing.assert_allclose(root, reference.values[frame, :3])
        composed: list[np.ndarray] = []
        for joint, parent in enumerate(clip.parents):
            turn = np.array(local[joint])
            composed.append(turn if parent < 0 else composed[parent] @ turn)
        np.testing.assert_allclose(np.array(composed), world[frame], atol=1e-9)


def test_a_bvh_cut_short_is_refused_in_one_sentence():
    text = bvh.rest_bvh(BONES)
    with pytest.raises(bvh.BvhError, match=r"^the BVH says 1 frames of 12 values but holds 11 values$"):
        bvh.read_bvh(text.rsplit(" ", 1)[0])
    with pytest.raises(bvh.BvhError, match=r"^the server's answer is no BVH"):
        bvh.read_bvh('{"error": "no"}')


def test_a_turn_about_the_bvhs_up_is_a_pose_bones_turn_about_blenders_up():
    quarter = bvh.axis_rotation("Y", math.pi / 2)  # BVH's up is Y
    w, x, y, z = bvh.pose_basis(bvh.IDENTITY, quarter)  # a bone lying along Blender's axes
    np.testing.assert_allclose([w, x, y, z], [math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)], atol=1e-12)


def test_a_pose_bones_rotation_is_the_joints_turn_seen_from_its_rest_frame():
    generator = np.random.default_rng(0)
    for _ in range(20):
        rest, local = Rotation.random(2, random_state=generator).as_matrix()
        w, x, y, z = bvh.pose_basis(tuple(map(tuple, rest)), tuple(map(tuple, local)))
        basis = Rotation.from_quat([x, y, z, w]).as_matrix()
        to_bvh = np.array(bvh.TO_BVH)
        # posed, the bone's frame is the rest frame carried by the joint's turn (Blender's axes)
        np.testing.assert_allclose(rest @ basis, to_bvh.T @ local @ to_bvh @ rest, atol=1e-12)
        assert w >= 0


def test_the_root_is_moved_from_its_rest_head_in_its_own_frame():
    rest = tuple(map(tuple, Rotation.from_euler("x", 90, degrees=True).as_matrix()))  # a bone pointing up
    location = bvh.root_location(rest, (0.0, 0.0, 1.0), (0.5, 1.2, 0.0))  # BVH: 0.5 to the side, 0.2 higher
    np.testing.assert_allclose(np.array(rest) @ location, [0.5, 0.0, 0.2], atol=1e-12)


def test_quaternions_of_turns_near_half_a_turn_are_exact():
    for angle in (0.0, 1.0, math.pi - 1e-9, math.pi):
        for axis in "XYZ":
            w, x, y, z = bvh.to_quaternion(bvh.axis_rotation(axis, angle))
            assert Rotation.from_quat([x, y, z, w]).magnitude() == pytest.approx(angle, abs=1e-7)


def test_the_playhead_names_an_action_and_an_edit_replaces_its_span_and_margins():
    actions = timeline.spans([{"text": "walk", "first": 0, "end": 48}, {"text": "jump", "first": 48, "end": 72}], 1)
    assert actions == [timeline.Span("walk", 1, 49), timeline.Span("jump", 49, 73)]
    assert timeline.action_at(actions, 49) == 1
    with pytest.raises(ValueError, match=r"^the playhead \(frame 73\) is in no action of the clip; .* 1-48, 49-72$"):
        timeline.action_at(actions, 73)
    assert timeline.replaced_frames(49, 73, 24.0, 1, 73) == range(
        39, 73
    )  # 0.4 s at 24 fps before, the clip's end after
    assert timeline.fill_seconds(96, 73, 24.0) == 1.0  # frames 73 to 96 inclusive
    with pytest.raises(ValueError, match=r"past the clip's last frame \(72\)"):
        timeline.fill_seconds(72, 73, 24.0)
    assert len(timeline.marker_name("a person " * 20)) == 63


def test_the_request_is_the_list_or_one_sentence_and_zero_seconds_is_the_typical_length():
    listed = client.generation_request(
        "m2d2m", "", [("a person walks", 2.0), ("  ", 1.0), ("a person jumps", 0.0)], "", 0, 3, 24.0, "keep", True
    )
    assert listed == {
        "model": "m2d2m",
        "seed": 3,
        "fps": 24.0,
        "root": "keep",
        "plant_feet": True,
        "actions": [{"text": "a person walks", "seconds": 2.0}, {"text": "a person jumps", "seconds": None}],
    }
    one = client.generation_request("m2d2m", "tps", [], "a person walks and then sits", 6.0, 0, 30.0, "ground", False)
    assert (one["prompt"], one["seconds"], one["method"]) == ("a person walks and then sits", 6.0, "tps")
    with pytest.raises(ValueError, match=r"^type an action \(or a sentence\) to generate$"):
        client.generation_request("m2d2m", "", [], " ", 0, 0, 24.0, "keep", True)


def test_refusals_are_the_apis_sentence_and_a_server_not_running_says_how_to_start_one():
    assert client.refusal(400, b'{"error": "the rig cannot take our motions: no left foot"}') == (
        "the server refused (400): the rig cannot take our motions: no left foot"
    )
    assert client.refusal(502, b"<html>") == "the server answered 502"
    refused = urllib.error.URLError(ConnectionRefusedError(111, "Connection refused"))
    assert client.unreachable("http://127.0.0.1:8000", refused) == (
        "no m2d2m server at http://127.0.0.1:8000: start one with `m2d2m serve` (or `make serve`), or set the address"
    )


def test_the_zip_holds_the_package_as_blender_installs_it(tmp_path):
    names = zipfile.ZipFile(pack(tmp_path / "addon.zip")).namelist()
    assert "m2d2m_blender/__init__.py" in names
    assert all(name.startswith("m2d2m_blender/") and name.endswith(".py") for name in names)


def run_session(addon: Path, server: str, out: Path, armature: str) -> tuple[dict, str]:
    """tests/blender_addon_session.py in Blender's background mode with the add-on's zip installed
    into a folder of its own: what it wrote, and what Blender printed (its reports among it)."""
    env = {"BLENDER_USER_SCRIPTS": str(out / "scripts"), "PATH": "/usr/bin:/bin", "HOME": str(out)}
    command = [BLENDER, "--background", "--factory-startup", "--python-exit-code", "1", "--python", str(SESSION)]
    result = subprocess.run(
        [*command, "--", str(addon), server, str(out), armature],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
        env=env,
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return json.loads((out / "session.json").read_text()), result.stdout


def on_rig(server: str, rig_bvh: str, generation: str, out: Path) -> np.ndarray:
    """The server's clip ``generation`` on the rig sent as ``rig_bvh``, read by m2d2m's own BVH
    reader, every joint per frame in Blender's axes (Z up): where the bones must stand."""
    import urllib.request

    request = urllib.request.Request(f"{server}/api/rigs", rig_bvh.encode(), method="POST")
    rig = json.loads(urllib.request.urlopen(request).read())["id"]
    path = out / f"{generation}.bvh"
    path.write_bytes(urllib.request.urlopen(f"{server}/api/generations/{generation}/motion.bvh?rig={rig}").read())
    y_up = read_bvh_file(path).positions()
    return np.stack([y_up[..., 0], -y_up[..., 2], y_up[..., 1]], axis=-1), list(read_bvh_file(path).names)


def heads_of(state: dict, bones: list[str]) -> np.ndarray:
    """The bones' heads (T, J, 3) Blender posed in every frame of the clip."""
    return np.array([[frame[bone] for bone in bones] for frame in state["heads"]])


def check_landing(server: str, session: dict, state: dict, out: Path, frames: range) -> float:
    """The largest distance, over ``frames`` of the clip, between a bone's head as Blender poses it
    and its joint in the server's BVH of the state's generation on the rig."""
    expected, names = on_rig(server, (out / "rig.bvh").read_text(), state["record"]["generation"], out)
    posed = heads_of(state, [session["bone_of"][name] for name in names])
    return float(np.abs(posed[frames] - expected[frames]).max())


SECONDS = (2.0, 1.0, 1.5)  # the session's actions
FPS = 24


@pytest.mark.slow
@needs_blender
@pytest.mark.parametrize("armature", ["built", "cmu"])
def test_blender_generates_regenerates_and_fills_on_the_selected_armature(trained_project, tmp_path, armature):
    addon = pack(tmp_path / "m2d2m_blender.zip")
    with live_server(ServeSettings(dataset="tiny", track=False)) as (server, _):
        session, printed = run_session(addon, server, tmp_path, "built" if armature == "built" else str(CMU))
        refusals = session["refusals"]
        assert {key: refusals[key] for key in ("refresh", "generate", "regenerate", "fill")} == dict.fromkeys(
            ("refresh", "generate", "regenerate", "fill"), ""
        )
        generated, regenerated, filled = session["generated"], session["regenerated"], session["filled"]
        record = generated["record"]
        frames = record["frames"]

        # a new action at the scene's rate, every bone keyed on every frame; the one before kept
        assert record["fps"] == FPS and generated["frame_range"] == [1, frames] and len(generated["heads"]) == frames
        spans = [(action["first"], action["end"]) for action in record["actions"]]
        assert spans[0][0] == 0 and spans[-1][1] == frames
        for (first, end), seconds in zip(spans, SECONDS, strict=True):
            assert abs((end - first) - seconds * FPS) <= 0.2 * FPS  # within one step of the model (4 frames at 20 fps)
        assert set(generated["keys"].values()) == {frames}
        before = next(name for name in generated["actions"] if name != generated["action"])
        assert generated["actions"][before]["fake_user"]
        print(f"{armature}: {frames} frames at {FPS} fps for {sum(SECONDS)} s; the action before, {before!r}, kept")

        # a marker at each action's first frame, named by its text
        assert generated["markers"] == sorted([action["text"], 1 + action["first"]] for action in record["actions"])

        # every bone where the server's BVH on the rig puts its joint
        size = float(np.ptp(heads_of(generated, list(generated["heads"][0]))[0], axis=0).max())
        error = check_landing(server, session, generated, tmp_path, range(frames))
        print(f"{armature}: largest bone head error {error / size * 1000:.4f} per mille of the body's height")
        assert error < 1e-4 * size

        # feet on the floor (z = 0 of the armature: where the built person stands; CMU's rig, hanging
        # from its root, gets ours): the lowest foot joint of each frame on it, within the few cm
        # the tiny model's own toes hover (4 cm)
        feet = [bone for bone in generated["heads"][0] if bone.lower().startswith(("foot", "toe", "leftto", "rightto"))]
        lowest = heads_of(generated, feet)[..., 2].min(axis=1)
        print(
            f"{armature}: feet {feet}; lowest per frame: median {np.median(lowest) / size:.4f}, min {lowest.min() / size:.4f} heights"
        )
        assert 0 < lowest.min() and np.median(lowest) < 0.04 * size

        # Regenerate action 2: its span and the margins anew, every key outside them as it was
        every = list(generated["heads"][0])
        replaced = timeline.replaced_frames(1 + spans[1][0], 1 + spans[1][1], FPS, 1, 1 + frames)
        inside = np.arange(replaced.start - 1, replaced.stop - 1)
        outside = np.setdiff1d(np.arange(frames), inside)
        assert regenerated["record"]["actions"][1]["text"] == "a person kicks"
        assert ["a person kicks", 1 + spans[1][0]] in regenerated["markers"]
        np.testing.assert_array_equal(heads_of(regenerated, every)[outside], heads_of(generated, every)[outside])
        assert check_landing(server, session, regenerated, tmp_path, inside) < 1e-4 * size
        moved = np.abs(heads_of(regenerated, every)[inside] - heads_of(generated, every)[inside]).max()
        # the action itself sampled anew: moved by more than twice what landing may miss (the tiny
        # model's new draw moves a bone by about a millimetre, not centimetres)
        assert moved > 2e-4 * size
        print(
            f"{armature}: regenerated frames {replaced.start}-{replaced.stop - 1}; {len(outside)} frames kept bit for bit"
        )

        # Fill to here: the clip continued to the playhead, the frames before the join kept
        end = 1 + frames
        assert filled["record"]["frames"] == frames + FPS and filled["frame_range"][1] == frames + FPS
        assert filled["record"]["actions"][-1]["text"] == "a person sits down"
        kept = np.arange(0, end - 1 - round(0.4 * FPS))
        np.testing.assert_array_equal(heads_of(filled, every)[kept], heads_of(regenerated, every)[kept])
        assert (
            check_landing(server, session, filled, tmp_path, range(frames - round(0.4 * FPS), frames + FPS))
            < 1e-4 * size
        )

        # Blender's undo takes the fill back: the clip and its markers as they were before it
        assert session["undone"]["record"] == regenerated["record"]
        assert session["undone"]["markers"] == regenerated["markers"]

    # refusals, one line each in the status bar
    assert refusals["fill_without_text"] == "Error: type what happens up to the playhead in the edit's text"
    assert refusals["regenerate_nowhere"].startswith("Error: the playhead (frame 0) is in no action of the clip")
    assert refusals["unknown_words"] == ""  # sampled, with the notice as a warning
    assert "the model never read 'zorbles'" in printed
    assert refusals["unmappable"].startswith("Error: the server refused (400): the rig cannot take our motions: ")
    assert refusals["no_server"] == (
        "Error: no m2d2m server at http://127.0.0.1:9: start one with `m2d2m serve` (or `make serve`), or set the address"
    )
    assert all("\n" not in said for said in refusals.values())
    assert session["refused_changes_nothing"]  # the same action, actions and markers

    # one sentence instead of a list, with a method of the server's menu
    assert session["methods"][0] == "default" and {"tps", "independent"} <= set(session["methods"])
    assert refusals["prompt"] == ""
    assert len(session["prompted"]["actions"]) == 2 and session["prompted"]["frames"] == pytest.approx(4 * FPS, abs=5)
