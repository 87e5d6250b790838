"""A motion on another rig (issue 40 §2), tested on a real rig unlike ours: CMU's 31-joint
skeleton of tests/fixtures/cmu-bvh. A CMU take made into our joints and retargeted back onto its
own rig gives the take's joints back; on a rig scaled up the motion scales with it; HumanML3D's
own clip on CMU's rig points every mapped bone where ours points, hands continue their forearms,
and the BVH written reads back as the rig's animation. A GLB character is a rig as its BVH is."""

from __future__ import annotations

import json
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pygltflib
import pytest

from m2d2m.motion.files.bvh_reader import BvhError, read_bvh
from m2d2m.motion.files.gltf import CLIP_ANIMATION, save_glb
from m2d2m.motion.representation.rigid import on_rigid_skeleton
from m2d2m.motion.representation.rotations import quat_to_matrix
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.motion.rigs.gltf_export import save_rig_glb
from m2d2m.motion.rigs.joint_map import PRESETS, JointMap, joint_map_for
from m2d2m.motion.rigs.retarget import Bind, Rig, Target, read_rig, read_target, retarget, retarget_to_bvh
from tests.conftest import HUMANML3D_SAMPLE
from tests.rigs import CONVENTIONS
from tests.test_bvh_reader import CMU, CMU_METRES
from tests.test_gltf import animation
from tests.test_rig_gltf import posed_world
from tests.test_up_axis import z_up_bvh

SAMPLE = HUMANML3D_SAMPLE / "new_joints" / "012314.npy"


@pytest.fixture(scope="module")
def take():
    """CMU's 131_01 in metres, its 22 T2M joints (every 4th frame, for speed) and its rig."""
    clip = read_bvh(CMU / "131_01.bvh", CMU_METRES)
    return clip.positions()[::4], PRESETS["cmu"].joints(clip)[::4], Rig.from_bvh(clip)


def single_sources(joint_map: JointMap, rig: Rig) -> dict[int, int]:
    """The rig's joints that stand for one of ours → ours."""
    return {
        rig.names.index(theirs[0]): T2M.joint_names.index(ours)
        for ours, theirs in joint_map.sources.items()
        if len(theirs) == 1
    }


def test_a_cmu_take_retargeted_onto_its_own_rig_is_the_take(take):
    positions, ours, rig = take
    motion = retarget(ours, rig, PRESETS["cmu"])
    assert motion.from_rest == frozenset()  # a rest pose hanging from its root: every bone aimed as ours
    moved = motion.positions()
    mapped = sorted(single_sources(PRESETS["cmu"], rig))
    assert np.abs(moved[:, mapped] - positions[:, mapped]).max() < 1e-6


def test_on_a_bigger_rig_the_motion_scales_with_it(take):
    positions, ours, rig = take
    bigger = replace(rig, offsets=rig.offsets * 1.3)
    moved = retarget(ours, bigger, PRESETS["cmu"]).positions()
    mapped = sorted(single_sources(PRESETS["cmu"], rig))
    assert np.abs(moved[:, mapped] - 1.3 * positions[:, mapped]).max() < 1e-6


def mapped_bones(joint_map: JointMap, rig: Rig) -> list[tuple[int, int, int, int]]:
    """Each bone of ours whose two joints the rig has, as (its parent, its child, our parent, our
    child): the rig's bone that should point where ours does."""
    theirs_of = {mine: joint for joint, mine in single_sources(joint_map, rig).items()}
    return [
        (theirs_of[int(T2M.parents[child])], theirs_of[child], int(T2M.parents[child]), child)
        for child in range(1, T2M.num_joints)
        if child in theirs_of and int(T2M.parents[child]) in theirs_of
    ]


def bone_angles(moved: np.ndarray, ours: np.ndarray, pairs: list[tuple[int, int, int, int]]) -> np.ndarray:
    """Degrees between each rig bone (a, b) and our bone (a', b'), per frame."""
    theirs = np.stack([moved[:, b] - moved[:, a] for a, b, _, _ in pairs], axis=1)
    mine = np.stack([ours[:, b] - ours[:, a] for _, _, a, b in pairs], axis=1)
    cosine = np.sum(theirs * mine, axis=-1) / np.linalg.norm(theirs, axis=-1) / np.linalg.norm(mine, axis=-1)
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


def test_humanml3ds_clip_on_cmus_rig_points_every_mapped_bone_as_ours(take):
    _, _, rig = take
    ours = np.load(SAMPLE).astype(np.float64)
    moved = retarget(ours, rig, PRESETS["cmu"]).positions()
    pairs = mapped_bones(PRESETS["cmu"], rig)
    assert len(pairs) >= 14  # legs, feet, spine, neck, head, arms
    assert bone_angles(moved, ours, pairs).max() < 1e-4
    hand, fingers, forearm = (rig.names.index(n) for n in ("LeftWrist", "LFingers", "LeftElbow"))
    assert bone_angles(moved, moved, [(hand, fingers, forearm, hand)]).max() < 1.0  # the hand continues the forearm
    feet = moved[:, [rig.names.index(n) for n in ("LeftToe", "RightToe")], 1].min(axis=1)
    scale = np.ptp(moved[:, :, 1], axis=1).mean() / np.ptp(ours[:, :, 1], axis=1).mean()
    assert abs(feet.min() - scale * ours[:, [10, 11], 1].min()) < 0.03  # on the floor as ours are


def test_the_bvh_on_the_rig_reads_back_as_its_animation(take, tmp_path):
    _, ours, rig = take
    path = retarget_to_bvh(tmp_path / "on-cmu.bvh", ours, CMU / "131_01.bvh", fps=30)
    written = read_bvh(path, CMU_METRES)  # in the rig's own units, found from its height
    assert written.names == rig.names and written.fps == pytest.approx(30.0)
    expected = retarget(ours, rig, PRESETS["cmu"]).positions()
    assert np.abs(written.positions() - expected).max() < 1e-4


def test_a_map_without_our_root_or_legs_is_one_line(take):
    _, ours, rig = take
    partial = JointMap("arms only", {"left_wrist": ("LeftWrist",)})
    with pytest.raises(ValueError, match="joint map arms only names no joint of the rig for our pelvis, left_hip"):
        retarget(ours, rig, partial)


# Run inside Blender: import a BVH with Blender's own importer (Y up in the file) and write every
# pose bone's head in world coordinates, per frame, as JSON. Debian's Blender 3.4 runs on Python
# 3.11, whose open() no longer takes the mode "rU" its BVH importer asks for: the U is dropped here
# (Blender's own builds bundle a Python that still takes it).
BLENDER_BVH_HEADS = """
import builtins, json, sys, bpy
_open = builtins.open
builtins.open = lambda file, mode="r", *args, **kwargs: _open(file, mode.replace("U", ""), *args, **kwargs)
source, out, scale, frames = sys.argv[sys.argv.index("--") + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_anim.bvh(filepath=source, global_scale=float(scale), axis_forward="-Z", axis_up="Y")
armature = next(o for o in bpy.data.objects if o.type == "ARMATURE")
heads = []
for frame in range(1, int(frames) + 1):  # the importer keys the file's first frame on frame 1
    bpy.context.scene.frame_set(frame)
    heads.append({bone.name: list(armature.matrix_world @ bone.head) for bone in armature.pose.bones})
json.dump(heads, open(out, "w"))
"""


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("blender") is None, reason="no blender here (apt-get install blender)")
def test_blender_imports_the_bvh_on_cmus_rig_with_its_joints_where_ours_put_them(take, tmp_path):
    """Issue 40's "--rig with CMU's skeleton writes a BVH Blender imports on that rig"."""
    _, _, rig = take
    ours = np.load(SAMPLE).astype(np.float64)[:40]
    path = retarget_to_bvh(tmp_path / "on-cmu.bvh", ours, CMU / "131_01.bvh")
    out = tmp_path / "heads.json"
    command = ["blender", "--background", "--factory-startup", "--python-exit-code", "1"]
    result = subprocess.run(
        [*command, "--python-expr", BLENDER_BVH_HEADS, "--", str(path), str(out), str(CMU_METRES), str(len(ours))],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    z_up = np.array([[frame[name] for name in rig.names] for frame in json.loads(out.read_text())])
    heads = np.stack([z_up[..., 0], z_up[..., 2], -z_up[..., 1]], axis=-1)  # Blender's Z up back to Y up
    expected = retarget(ours, rig, PRESETS["cmu"]).positions()
    error = np.abs(heads - expected).max()
    print(f"Blender's BVH import on CMU's rig: largest joint error {error * 1000:.3f} mm")
    assert error < 1e-3


def cmu_rig_as_glb(path, rig: Rig, seed: int = 0) -> None:
    """CMU's rig as a skinned GLB the way a DCC tool exports a character in centimetres: an
    "Armature" node scaling by 0.01 above the root, each joint node with a rest rotation of its
    own (random) and the translation that puts it where the BVH's rest pose does."""
    rng = np.random.default_rng(seed)
    quaternions = rng.normal(size=(len(rig.names), 4))
    quaternions /= np.linalg.norm(quaternions, axis=1, keepdims=True)  # w, x, y, z
    turns = quat_to_matrix(quaternions)
    rest_cm = rig.rest_positions() * 100.0
    world = np.empty_like(turns)
    nodes = [pygltflib.Node(name="Armature", scale=[0.01] * 3, children=[1])]
    for joint, parent in enumerate(rig.parents):
        above = np.eye(3) if parent < 0 else world[parent]
        world[joint] = above @ turns[joint]
        step = rest_cm[joint] - (rest_cm[parent] if parent >= 0 else 0.0)
        nodes.append(
            pygltflib.Node(
                name=rig.names[joint],
                translation=(above.T @ step).tolist(),
                rotation=quaternions[joint, [1, 2, 3, 0]].tolist(),
                children=[int(k) + 1 for k in np.flatnonzero(rig.parents == joint)],
            )
        )
    gltf = pygltflib.GLTF2(
        scenes=[pygltflib.Scene(nodes=[0])],
        nodes=nodes,
        skins=[pygltflib.Skin(joints=list(range(1, len(nodes))))],
    )
    gltf.save_binary(str(path))


def test_a_glb_characters_skeleton_is_a_rig_as_its_bvh_is(take, tmp_path):
    """CMU's rig written as a GLB in centimetres with rest rotations of its own: read back, it
    stands where the BVH's rest pose stands, and a motion retargeted onto it is the one on the BVH."""
    _, ours, rig = take
    cmu_rig_as_glb(tmp_path / "cmu.glb", rig)
    read = read_rig(tmp_path / "cmu.glb")
    assert read.names == rig.names
    np.testing.assert_allclose(read.rest_positions(), rig.rest_positions(), atol=1e-9)
    on_glb = read_bvh(retarget_to_bvh(tmp_path / "on-glb.bvh", ours, tmp_path / "cmu.glb", "cmu"))
    on_bvh = read_bvh(retarget_to_bvh(tmp_path / "on-bvh.bvh", ours, CMU / "131_01.bvh", "cmu"), CMU_METRES)
    assert np.abs(on_glb.positions() - on_bvh.positions()).max() < 1e-4


def test_our_own_glb_is_a_rig_and_a_glb_without_a_skin_is_one_line(take, tmp_path):
    """The GLB `m2d2m export` writes is SMPL-named: as a rig it takes our motion back unchanged, but
    for a lift of its feet onto its floor (under 1 cm, the same in every frame)."""
    _, ours, _ = take
    rigid = on_rigid_skeleton(ours, T2M)
    save_glb(tmp_path / "ours.glb", rigid, T2M, 20.0)
    back = read_bvh(retarget_to_bvh(tmp_path / "on-ours.bvh", rigid, tmp_path / "ours.glb", "smpl"))
    assert sorted(back.names) == sorted(T2M.joint_names)  # listed depth first, as a BVH lists them
    in_our_order = back.positions()[:, [back.names.index(name) for name in T2M.joint_names]]
    lifted = in_our_order - rigid  # stood on its floor: its rest ankles against HumanML3D's in stance
    assert np.abs(lifted - lifted[:1, :1]).max() < 1e-4 and np.abs(lifted).max() < 0.01
    pygltflib.GLTF2(nodes=[pygltflib.Node(name="hips")], scenes=[pygltflib.Scene(nodes=[0])]).save_binary(
        str(tmp_path / "bare.glb")
    )
    with pytest.raises(BvhError, match="bare.glb: no skin, so no skeleton to retarget to"):
        read_rig(tmp_path / "bare.glb")
    (tmp_path / "text.glb").write_text("not a model", encoding="utf-8")
    with pytest.raises(BvhError, match="text.glb: not a glTF file"):
        read_rig(tmp_path / "text.glb")


def test_humanml3ds_clip_on_mixamos_x_bot_points_every_mapped_bone_as_ours(tmp_path):
    """Mixamo's real X Bot (tests/fixtures/mixamo: an Armature turned a quarter about X and
    scaled to centimetres above 65 ``mixamorig:`` joints, each with its own rest rotation): the
    preset fits it, it stands 1.82 m tall in metres; on it, every mapped bone of HumanML3D's clip
    from a joint with one mapped child points where ours points, and those from the pelvis and the
    chest (several children, a best fit of the rig's own shape: hips set wider and lower than ours)
    keep one angle from ours all clip long, 16° at most, as do its feet and head (it stands at rest
    as a person stands, so they turn from its rest as ours from ours); each hand continues its
    forearm, and its BVH reads back."""
    rig_file = Path(__file__).parent / "fixtures" / "mixamo" / "xbot-skeleton.glb"
    clip = read_rig(rig_file)
    assert len(clip.names) == 65 and joint_map_for(clip).name == "mixamo"
    assert PRESETS["mixamo"].metres_per_unit(clip) == 1.0
    assert clip.rest_positions()[:, 1].max() == pytest.approx(1.82, abs=0.01)
    ours = on_rigid_skeleton(np.load(SAMPLE), T2M)
    rig = Rig.from_bvh(clip)
    motion = retarget(ours, rig, PRESETS["mixamo"])
    moved = motion.positions()
    pairs = mapped_bones(PRESETS["mixamo"], rig)
    angles = bone_angles(moved, ours, pairs)
    branching = np.array([np.count_nonzero(T2M.parents == parent) > 1 for _, _, parent, _ in pairs])
    assert len(pairs) == 21 and branching.sum() == 6  # pelvis: hips and spine; chest: neck and collars
    from_rest = np.array([child in motion.from_rest for _, _, _, child in pairs])
    assert sorted(motion.from_rest) == [T2M.joint_names.index(n) for n in ("left_foot", "right_foot", "head")]
    assert angles[:, ~branching & ~from_rest].max() < 1e-4 and np.ptp(angles[:, from_rest], axis=0).max() < 1e-4
    assert angles[:, branching].max() < 16.0 and np.ptp(angles[:, branching], axis=0).max() < 1e-4
    for side in ("Left", "Right"):
        hand, finger, forearm = (rig.names.index(f"mixamorig:{side}{n}") for n in ("Hand", "HandMiddle1", "ForeArm"))
        assert bone_angles(moved, moved, [(hand, finger, forearm, hand)]).max() < 15.0  # as the rig's rest bends it
    written = read_bvh(retarget_to_bvh(tmp_path / "on-xbot.bvh", ours, rig_file))
    assert written.names == clip.names
    assert np.abs(written.positions() - moved).max() < 1e-4


BANDAI_WALK = (
    Path(__file__).parent
    / "fixtures/bandai-namco/dataset/Bandai-Namco-Research-Motiondataset-1/data/dataset-1_walk_normal_001.bvh"
)
BANDAI_LIMBS = ("UpperLeg_L", "LowerLeg_L", "UpperArm_L", "LowerArm_L", "UpperLeg_R", "LowerLeg_R", "UpperArm_R")


def twist_from_capture(target: Target, path: Path) -> np.ndarray:
    """Degrees between each limb's world rotation in the capture at ``path`` and on ``target``
    when the capture's own joints are retargeted back onto its rig: what the rotations add to
    the joints' positions, each limb's twist about itself."""
    clip = read_bvh(path, target.metres_per_unit)
    captured, _ = clip.pose()
    moved, _ = target.retargeted(PRESETS["bandai-namco"].joints(clip)).pose()
    limbs = [clip.names.index(name) for name in BANDAI_LIMBS]
    turn = np.swapaxes(moved[:, limbs], -1, -2) @ captured[:, limbs]
    return np.degrees(np.arccos(np.clip((np.trace(turn, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)))


def test_a_rig_whose_rest_pose_lies_is_aimed_from_a_frame_of_its_file_and_keeps_its_limbs_twist():
    """Bandai Namco's rest pose lies along its bones' X axes: aimed from it, a limb's swing from a
    line leaves its twist anywhere (the capture's own walk retargeted back onto its rig: limbs a
    median 125° from the capture's rotations); aimed from its file's first frame (the default) or
    another (``rest_frame``), 5°."""
    target = read_target(BANDAI_WALK)
    assert target.bind.frame == 0 and not target.bind.turned
    from_frame = np.median(twist_from_capture(target, BANDAI_WALK))
    from_rest_pose = np.median(twist_from_capture(replace(target, bind=Bind()), BANDAI_WALK))
    later = read_target(BANDAI_WALK, rest_frame=40)
    assert later.bind.frame == 40
    print(f"limbs from the capture's, median: {from_rest_pose:.1f}° from the rest pose, {from_frame:.1f}° from frame 0")
    assert from_rest_pose > 45.0 and from_frame < 10.0 and np.median(twist_from_capture(later, BANDAI_WALK)) < 10.0
    frames = len(read_bvh(BANDAI_WALK).values)
    with pytest.raises(ValueError, match=rf"rest frame {frames}: the rig's file has {frames} frame\(s\)"):
        read_target(BANDAI_WALK, rest_frame=frames)
    cmu = read_target(CMU / "131_01.bvh").bind  # a rest pose that stands is the bind pose
    assert cmu.frame is None and cmu.rotations is None and not cmu.turned


def test_a_z_up_rig_is_turned_to_take_our_motion_and_written_back_in_its_own_axes(tmp_path):
    """A rig exported Z-up (its rest pose and motion along +Z) takes our motion as its Y-up twin
    does, the BVH in its own axes (each joint where the twin's stands, turned +90° about X); its
    GLB stands along glTF's +Y as the twin's does."""
    ours = on_rigid_skeleton(np.load(SAMPLE)[::4], T2M)
    y_up = CONVENTIONS[0].rig().write(tmp_path / "y-up.bvh")
    z_up = tmp_path / "z-up.bvh"
    z_up.write_text(z_up_bvh(y_up.read_text()), encoding="utf-8")
    assert read_target(z_up).bind.turned and not read_target(y_up).bind.turned
    on_y = read_bvh(retarget_to_bvh(tmp_path / "on-y.bvh", ours, y_up)).positions()
    on_z = read_bvh(retarget_to_bvh(tmp_path / "on-z.bvh", ours, z_up)).positions()
    np.testing.assert_allclose(on_z, np.stack([on_y[..., 0], -on_y[..., 2], on_y[..., 1]], axis=-1), atol=1e-6)
    glbs = [save_rig_glb(tmp_path / f"{rig.stem}.glb", read_target(rig), ours, 20.0) for rig in (y_up, z_up)]
    posed = [
        posed_world(g, animation(g, CLIP_ANIMATION))[..., :3, 3] for g in map(pygltflib.GLTF2.load, map(str, glbs))
    ]
    np.testing.assert_allclose(posed[1], posed[0], atol=1e-6)


def test_a_rig_with_its_bones_in_position_channels_takes_our_motion_as_its_twin(tmp_path):
    """A game studio's export: position channels on every joint, the bones in its OFFSETs too or
    only in the channels (OFFSETs zero): read with its bones either way, it is mapped and takes
    our motion as the rig written with OFFSETs only does."""
    ours = on_rigid_skeleton(np.load(SAMPLE)[::4], T2M)
    studio = next(convention for convention in CONVENTIONS if convention.name.startswith("game studio")).rig()
    plain = studio.write(tmp_path / "plain.bvh", scale=100.0)
    expected = read_bvh(retarget_to_bvh(tmp_path / "on-plain.bvh", ours, plain)).positions()
    for offsets in (True, False):
        rig_file = studio.write_translated(tmp_path / f"translated-{offsets}.bvh", offsets=offsets)
        np.testing.assert_allclose(read_bvh(rig_file).rest_positions(), read_bvh(plain).rest_positions(), atol=1e-4)
        moved = read_bvh(retarget_to_bvh(tmp_path / f"on-{offsets}.bvh", ours, rig_file)).positions()
        np.testing.assert_allclose(moved, expected, atol=1e-4)
