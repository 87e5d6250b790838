"""A rig's joints mapped onto ours from its names and hierarchy (issue 52 §1–§3;
m2d2m/motion/rigs/auto_map.py): every naming convention of tests/rigs.py maps each of our 22 joints to
the right joint, fingers, twist bones, IK helpers and props passed over; the real rigs of
tests/fixtures map as their presets do; a rig without toes, collars, a neck or with one spine
joint still maps, and our motion goes onto a toe-less rig with its toe's direction on the foot;
a rig without names maps by its hierarchy and rest pose, Z-up too; a YAML corrects some joints and
is refused in one line where it names a joint twice; and `m2d2m rig` prints the mapping and
writes it as a YAML that reads back as the same map."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from m2d2m.motion.files.bvh_reader import BvhClip, BvhError, read_bvh, read_bvh_header
from m2d2m.motion.files.export import save_bvh
from m2d2m.motion.representation.rigid import on_rigid_skeleton
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.motion.rigs.auto_map import DERIVED, GUESSED, MISSING, NAME, auto_map
from m2d2m.motion.rigs.joint_map import PRESETS, JointMap, joint_map_for
from m2d2m.motion.rigs.retarget import Rig, read_rig, retarget, retarget_to_bvh
from orchestration.cli import main
from pipelines.bvh_corpus import take_joints
from tests.conftest import HUMANML3D_SAMPLE
from tests.rigs import CONVENTIONS, MIXAMO_LIMBS, Convention, without
from tests.test_bvh_reader import CMU, CMU_METRES
from tests.test_export import axis_rotation
from tests.test_joint_map import motionbuilder_release
from tests.test_up_axis import z_up_bvh

# Our joints at the end of the bones that turn from a standing character's rest (m2d2m.motion.rigs.retarget.stands_at_rest)
FEET_AND_HEAD = frozenset(T2M.joint_names.index(name) for name in ("left_foot", "right_foot", "head"))
BY_NAME = {convention.name: convention for convention in CONVENTIONS}
BANDAI_TAKE = next((Path(__file__).parent / "fixtures" / "bandai-namco").rglob("*walk*.bvh"))
XBOT = Path(__file__).parent / "fixtures" / "mixamo" / "xbot-skeleton.glb"
TOELESS = BY_NAME["perception neuron (no toes)"]
MINIMAL = Convention(  # one spine joint, no neck, no clavicles, no toes
    "minimal",
    "Hips",
    ("Spine",),
    (),
    "Head",
    without(MIXAMO_LIMBS, "clavicle", "toe"),
    expected={
        "spine1": ("Hips", "Spine"),
        "spine2": ("Hips", "Spine", "Spine"),
        "spine3": ("Spine",),
        "neck": ("Spine", "Head"),
    },
)
NO_SPINE = Convention(  # the arms and the head on the neck, straight above the pelvis
    "no spine joint",
    "Hips",
    (),
    ("Neck",),
    "Head",
    dict(BY_NAME["rokoko (Mixamo names)"].side, clavicle="{Side}Shoulder", toe_end=None),
    arms_on="Neck",
    expected={"spine1": ("Hips", "Hips", "Neck"), "spine2": ("Hips", "Neck"), "spine3": ("Hips", "Neck", "Neck")},
)


def sources(found) -> dict[str, tuple[str, ...]]:
    return {joint: f.theirs for joint, f in found.items()}


def anonymous(clip: BvhClip, renamed: dict[str, str] | None = None) -> tuple[BvhClip, dict[str, str]]:
    """``clip`` with its joints named as Blender names new bones (Bone, Bone.001, …), or as ``renamed``."""
    renamed = renamed or {name: "Bone" if i == 0 else f"Bone.{i:03d}" for i, name in enumerate(clip.names)}
    return replace(clip, names=tuple(renamed[name] for name in clip.names)), renamed


@pytest.mark.parametrize("convention", [*CONVENTIONS, MINIMAL, NO_SPINE], ids=lambda c: c.name)
def test_a_convention_maps_every_joint_to_the_right_one(convention, tmp_path):
    rig = convention.rig()
    found = auto_map(rig.clip())
    assert sources(found) == convention.expected_map()
    single = {joint for joint, theirs in convention.expected_map().items() if len(theirs) == 1}
    toeless = "toe" not in convention.side
    derived = set(T2M.joint_names) - single | ({"left_foot", "right_foot"} if toeless else set())
    assert {joint for joint, f in found.items() if f.how == DERIVED} == derived
    guessed = {"pelvis", "neck", "head"} if convention.name.startswith("blender") else set()
    assert {joint for joint, f in found.items() if f.how == GUESSED} == guessed
    assert all(f.how == NAME for joint, f in found.items() if joint not in derived | guessed)
    assert all(f.why for f in found.values() if f.how != NAME)
    # the same from the file's header alone, and the map the file is read with
    path = rig.write(tmp_path / "rig.bvh", scale=100.0)
    header = read_bvh_header(path)
    np.testing.assert_allclose(header.rest_positions(), read_bvh(path).rest_positions())
    assert sources(auto_map(header)) == convention.expected_map()
    mapping = joint_map_for(read_bvh(path))
    assert mapping.sources == convention.expected_map()
    assert set(mapping.offsets) == ({"left_foot", "right_foot"} if toeless else set())


def test_3ds_max_biped_names_with_spaces_map_as_with_underscores():
    """Biped's own names have spaces (``Bip01 L Thigh``); a GLB keeps them, a BVH cannot."""
    clip = BY_NAME["3ds max biped"].rig().clip()
    spaced = replace(clip, names=tuple(name.replace("_", " ") for name in clip.names))
    expected = {joint: tuple(n.replace("_", " ") for n in theirs) for joint, theirs in sources(auto_map(clip)).items()}
    assert sources(auto_map(spaced)) == expected and expected["left_hip"] == ("Bip01 L Thigh",)


def cmu_motionbuilder(folder: Path) -> BvhClip:
    (folder / "131_01.bvh").write_text(motionbuilder_release("131_01"), encoding="utf-8")
    return read_bvh(folder / "131_01.bvh", CMU_METRES)


def our_own_bvh(folder: Path) -> BvhClip:
    return read_bvh(save_bvh(folder / "ours.bvh", np.load(HUMANML3D_SAMPLE / "new_joints" / "012314.npy")[:2]))


@pytest.mark.parametrize(
    "rig, preset",
    [
        (lambda folder: read_bvh(CMU / "131_01.bvh", CMU_METRES), "cmu"),
        (lambda folder: read_bvh_header(CMU / "131_02.bvh"), "cmu"),
        (cmu_motionbuilder, "cmu-motionbuilder"),
        (lambda folder: read_rig(XBOT), "mixamo"),
        (our_own_bvh, "smpl"),
    ],
    ids=["cmu", "cmu header", "cmu-motionbuilder", "mixamo x bot", "smpl (our own bvh)"],
)
def test_the_real_rigs_map_as_their_presets(rig, preset, tmp_path):
    assert sources(auto_map(rig(tmp_path))) == PRESETS[preset].sources


def test_bandai_namcos_rig_maps_as_its_preset_but_for_the_collars():
    """The preset makes each collar the midpoint of Bandai's clavicle (``Shoulder_L``, 5 cm off
    the midline) and shoulder, to land as far out as SMPL's (7.6 cm against 7.2); the automatic
    map takes a clavicle that stands off the chest as the collar itself, as Mixamo's preset does
    with its clavicle 4.6 cm off the midline."""
    found = auto_map(read_bvh_header(BANDAI_TAKE))
    preset = PRESETS["bandai-namco"].sources
    collars = {"left_collar": ("Shoulder_L",), "right_collar": ("Shoulder_R",)}
    assert sources(found) == preset | collars
    assert all(
        preset[joint] == collars[joint] + (collars[joint][0].replace("Shoulder", "UpperArm"),) for joint in collars
    )


def test_a_rig_without_names_maps_by_its_hierarchy_and_rest_pose_z_up_too(tmp_path):
    """Unity's rig with every joint renamed Bone, Bone.NNN (as Blender names new bones): the
    pelvis is where three long branches part, the chest where three more do, the wrists where the
    arms branch into fingers, the sides from the rest pose. Written Z-up, the same; and without
    toes, forward is Blender's −Y, so the derived foot lies ahead of the ankle and below it."""
    convention = BY_NAME["unity (Mecanim)"]
    clip, renamed = anonymous(convention.rig().clip())
    expected = {joint: tuple(renamed[n] for n in theirs) for joint, theirs in convention.expected_map().items()}
    found = auto_map(clip)
    assert sources(found) == expected
    assert {f.how for f in found.values()} == {GUESSED}
    assert "its side by the rest pose" in found["left_elbow"].why
    z_up = tmp_path / "z-up.bvh"
    z_up.write_text(z_up_bvh(convention.rig().write(tmp_path / "y-up.bvh").read_text()), encoding="utf-8")
    z_clip, _ = anonymous(read_bvh(z_up), renamed)
    assert sources(auto_map(z_clip)) == expected
    toeless = replace(convention, side={slot: name for slot, name in convention.side.items() if slot != "toe"})
    toeless.rig().write(tmp_path / "toeless.bvh")
    (tmp_path / "toeless-z.bvh").write_text(z_up_bvh((tmp_path / "toeless.bvh").read_text()), encoding="utf-8")
    z_clip, renamed = anonymous(read_bvh(tmp_path / "toeless-z.bvh"))
    found = auto_map(z_clip)
    assert found["left_hip"].theirs == (renamed["LeftUpperLeg"],) and found["right_wrist"].theirs == (
        renamed["RightHand"],
    )
    x, y, z = found["left_foot"].offset
    assert y < -2 * abs(x) and z < 0  # forward (−Y) and down (−Z)


def test_a_z_up_take_on_an_auto_mapped_rig_reads_as_its_y_up_twin(tmp_path):
    """A corpus take (`m2d2m data --dataset bvh`) on a rig no preset fits, written Z-up: the
    automatic map and the up axis read from its motion give the joints of the Y-up take."""
    rig = BY_NAME["daz (Genesis, Poser)"].rig()
    degrees = 15.0 * np.sin(np.linspace(0.0, 3.0, 12))[:, None] * (np.arange(len(rig.names)) > 0)  # the root upright
    y_up = rig.write(tmp_path / "y-up.bvh", scale=100.0, frames=axis_rotation("X", degrees))  # every joint bends
    (tmp_path / "z-up.bvh").write_text(z_up_bvh(y_up.read_text()), encoding="utf-8")
    upright, mapping = take_joints(tmp_path / "z-up.bvh")
    assert mapping.name == "auto" and mapping.standing(read_bvh(tmp_path / "z-up.bvh")).axis == "+Z"
    np.testing.assert_allclose(upright, take_joints(y_up)[0], atol=1e-5)


def test_helpers_twist_bones_and_props_are_never_mapped():
    for name in (
        "unreal (UE4 Mannequin)",
        "game studio (_L, _R, a prop in the hand)",
        "daz (Genesis 3, twist bones in the limbs)",
    ):
        mapped = {n for f in auto_map(BY_NAME[name].rig().clip()).values() for n in f.theirs}
        assert not {n for n in mapped if re.search("ik_|twist|Twist|Weapon|index|Index", n)}


def test_a_rig_without_arms_is_refused_in_one_line():
    armless = replace(
        MINIMAL, side={slot: name for slot, name in MINIMAL.side.items() if slot in ("thigh", "shin", "foot")}
    )
    clip = armless.rig().clip()
    assert auto_map(clip)["left_wrist"].how == MISSING
    with pytest.raises(
        BvhError, match=r"^cannot map the rig's joints onto ours: no two legs and a spine with two arms"
    ) as error:
        joint_map_for(clip)
    assert "\n" not in str(error.value)


def single_sources(mapping: JointMap, names) -> dict[int, int]:
    """The rig's joints that stand for one of ours (not a mean, not a point fixed to it) → ours."""
    return {
        names.index(theirs[0]): T2M.joint_names.index(ours)
        for ours, theirs in mapping.sources.items()
        if len(theirs) == 1 and ours not in mapping.offsets
    }


def angles_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cosine = np.sum(a * b, axis=-1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


@pytest.fixture(scope="module")
def ours() -> np.ndarray:
    return on_rigid_skeleton(np.load(HUMANML3D_SAMPLE / "new_joints" / "012314.npy")[::4], T2M)


@pytest.mark.parametrize(
    "convention",
    [BY_NAME["unreal (UE4 Mannequin)"], BY_NAME["daz (Genesis 3, twist bones in the limbs)"], TOELESS, MINIMAL],
    ids=lambda c: c.name,
)
def test_our_motion_goes_onto_an_auto_mapped_rig_bone_for_bone(convention, ours):
    """Every bone between two joints that stand for ours, from a joint with one such below it,
    points where ours points; feet and head turn from the rig's rest as ours from ours, each
    keeping one angle from ours."""
    rig = convention.rig()
    mapping = joint_map_for(rig.clip())
    moved = retarget(ours, Rig.from_bvh(rig.clip()), mapping)
    theirs = {mine: joint for joint, mine in single_sources(mapping, rig.names).items()}
    parents = T2M.parents
    pairs = [
        (theirs[int(parents[child])], theirs[child], int(parents[child]), child)
        for child in range(1, T2M.num_joints)
        if child in theirs and int(parents[child]) in theirs and np.count_nonzero(parents == parents[child]) == 1
    ]
    positions = moved.positions()
    assert len(pairs) >= 8  # legs, feet, arms, and the spine where the rig has one
    rig_bones = np.stack([positions[:, b] - positions[:, a] for a, b, _, _ in pairs], axis=1)
    our_bones = np.stack([ours[:, b] - ours[:, a] for _, _, a, b in pairs], axis=1)
    # each stands at rest as a person stands; without a neck the chest aims at the head, as ours
    assert moved.from_rest == (FEET_AND_HEAD if convention.neck else FEET_AND_HEAD - {T2M.head_joint})
    from_rest = np.array([child in moved.from_rest for _, _, _, child in pairs])
    angles = angles_between(rig_bones, our_bones)
    assert angles[:, ~from_rest].max() < 1e-4 and np.ptp(angles[:, from_rest], axis=0).max(initial=0.0) < 1e-4


def test_a_toeless_rig_takes_our_motion_and_reads_back_with_its_toes_direction(ours, tmp_path):
    """End to end: our clip as a BVH on Perception Neuron's toe-less rig (in centimetres), read
    back through the automatic map: its legs and arms point as ours did, and its foot turns from
    its rest as ours from ours, so the point the map fixes ahead of its ankle keeps one angle from
    our toe (its rest's: along its End Site, 23° below level, against our 18°)."""
    rig_file = TOELESS.rig().write(tmp_path / "neuron.bvh", scale=100.0)
    written = read_bvh(retarget_to_bvh(tmp_path / "on-neuron.bvh", ours, rig_file))
    mapping = joint_map_for(written)
    assert mapping.name == "auto" and set(mapping.offsets) == {"left_foot", "right_foot"}
    back = mapping.joints(written)
    bones = [(T2M.parents[j], j) for j in (4, 5, 7, 8, 10, 11, 18, 19, 20, 21)]  # knees to feet, elbows, wrists
    for parent, child in bones:
        angles = angles_between(back[:, child] - back[:, parent], ours[:, child] - ours[:, parent])
        if child in FEET_AND_HEAD:
            assert np.ptp(angles) < 1e-3 and angles.max() < 6.0
        else:
            assert angles.max() < 1e-3


def test_a_yaml_corrects_some_joints_and_a_joint_named_twice_is_refused(tmp_path):
    clip = TOELESS.rig().clip()
    (tmp_path / "spine.yaml").write_text("spine2: [Spine1, Spine2]\n", encoding="utf-8")
    corrected = joint_map_for(clip, tmp_path / "spine.yaml")
    auto = joint_map_for(clip)
    assert corrected.sources == auto.sources | {"spine2": ("Spine1", "Spine2")}
    assert corrected.offsets == auto.offsets and corrected.name.endswith("spine.yaml over auto")
    (tmp_path / "twice.yaml").write_text("left_foot: LeftFoot\n", encoding="utf-8")
    with pytest.raises(
        ValueError, match=r"names LeftFoot for both left_ankle and left_foot, so one would be dropped"
    ) as error:
        joint_map_for(clip, tmp_path / "twice.yaml")
    assert "\n" not in str(error.value)
    complete = {joint: joint for joint in T2M.joint_names} | {"left_ankle": "left_foot"}
    (tmp_path / "complete.yaml").write_text(yaml.safe_dump(complete), encoding="utf-8")
    with pytest.raises(ValueError, match="names left_foot for both left_ankle and left_foot"):
        JointMap.from_yaml(tmp_path / "complete.yaml")


def test_the_rig_command_prints_the_mapping_and_its_yaml_reads_back_as_the_same_map(tmp_path, capsys):
    rig_file = TOELESS.rig().write(tmp_path / "neuron.bvh", scale=100.0)
    assert main(["rig", str(rig_file), "--out", str(tmp_path / "map.yaml")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"{rig_file}: {len(TOELESS.rig().names)} joints; joint map auto"
    rows = dict(line.split(None, 1) for line in lines[1:23])
    assert list(rows) == list(T2M.joint_names)
    assert rows["left_hip"].split() == ["LeftUpLeg", "matched", "by", "name"]
    assert rows["spine2"].startswith("Spine2") and rows["left_foot"].startswith("LeftFoot + (")
    assert "derived: no toe: ahead of the ankle, along its End Site" in rows["left_foot"]
    assert lines[-2:] == [
        f"wrote {tmp_path / 'map.yaml'}: correct it and give it back with --joint-map {tmp_path / 'map.yaml'}",
        "can receive motion: yes (0.01 m a unit; aimed from its rest pose)",
    ]
    written = yaml.safe_load((tmp_path / "map.yaml").read_text())
    assert written["left_foot"]["joint"] == "LeftFoot" and len(written) == 22
    clip = read_bvh(rig_file)
    assert joint_map_for(clip, tmp_path / "map.yaml") == replace(joint_map_for(clip), name=str(tmp_path / "map.yaml"))
    assert main(["rig", str(rig_file), "--joint-map", str(tmp_path / "map.yaml")]) == 0
    again = capsys.readouterr().out.splitlines()
    assert [row.split()[:2] for row in again[1:23]] == [row.split()[:2] for row in lines[1:23]]
    assert all(row.rstrip().endswith(f"given: in {tmp_path / 'map.yaml'}") for row in again[1:23])


def test_the_rig_command_says_in_one_line_why_a_rig_cannot_take_motion(tmp_path, capsys):
    y_up = BY_NAME["unity (Mecanim)"].rig().write(tmp_path / "y-up.bvh")
    (tmp_path / "z-up.bvh").write_text(z_up_bvh(y_up.read_text()), encoding="utf-8")
    assert main(["rig", str(tmp_path / "z-up.bvh"), "--rest-frame", "1"]) == 2
    captured = capsys.readouterr()
    assert captured.out.splitlines()[-1] == "can receive motion: no"
    assert captured.err.splitlines() == [
        "m2d2m rig: error: rest frame 1: the rig's file has 1 frame(s), numbered 0 to 0"
    ]
    assert main(["rig", str(tmp_path / "z-up.bvh")]) == 0  # a Z-up rig is turned, not refused
    assert capsys.readouterr().out.splitlines()[-1] == (
        "can receive motion: yes (1 m a unit; aimed from its rest pose, turned to stand Y-up "
        "(written back in its own axes))"
    )
    armless = replace(
        MINIMAL, side={slot: name for slot, name in MINIMAL.side.items() if slot in ("thigh", "shin", "foot")}
    )
    armless.rig().write(tmp_path / "armless.bvh")
    assert main(["rig", str(tmp_path / "armless.bvh"), "--out", str(tmp_path / "fill-in.yaml")]) == 2
    captured = capsys.readouterr()
    assert re.search(r"^left_wrist +- +missing: no two legs and a spine", captured.out, re.MULTILINE)
    assert len(captured.err.splitlines()) == 1 and "cannot map the rig's joints onto ours" in captured.err
    assert "# left_wrist:  # missing" in (tmp_path / "fill-in.yaml").read_text()
