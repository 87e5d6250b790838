"""Synthetic characters' rigs in the naming conventions people export from, for the automatic
joint map's tests (tests/test_auto_map.py): a humanoid in a T-pose of plausible proportions (Y
up, facing +Z, its left +X, legs down, arms out, spine up; metres), its joints named as each
convention names them, with the fingers, twist bones, IK helpers and props some carry, and the
joint of the rig each of our 22 joints should map to."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from m2d2m.motion.files.bvh_reader import BvhClip
from m2d2m.motion.files.export import write_bvh

# The left side's joints where a T-pose puts them; the right side's are their mirror images in x.
LEFT = {
    "clavicle": (0.04, 1.45, -0.01),
    "upperarm": (0.17, 1.45, -0.02),
    "forearm": (0.45, 1.45, -0.03),
    "hand": (0.72, 1.45, -0.03),
    "thigh": (0.09, 0.90, 0.0),
    "shin": (0.09, 0.50, 0.02),
    "foot": (0.09, 0.08, -0.02),
    "toe": (0.09, 0.01, 0.12),
    "toe_end": (0.09, 0.01, 0.20),
}
LIMBS = (("clavicle", "upperarm", "forearm", "hand"), ("thigh", "shin", "foot", "toe", "toe_end"))
PELVIS_AT, CHEST_AT, NECK_AT, HEAD_AT = 0.95, 1.40, 1.50, 1.62
FINGERS = ("thumb", "index", "middle", "ring", "pinky")


@dataclass
class RigBuilder:
    """A rig being built: joints (name, parent, world rest position), parents listed first."""

    names: list[str] = field(default_factory=list)
    parents: list[int] = field(default_factory=list)
    at: list[np.ndarray] = field(default_factory=list)
    end_sites: dict[int, np.ndarray] = field(default_factory=dict)

    def add(self, name: str, parent: str | None, at) -> str:
        self.names.append(name)
        self.parents.append(-1 if parent is None else self.names.index(parent))
        self.at.append(np.asarray(at, dtype=np.float64))
        return name

    def position(self, name: str) -> np.ndarray:
        return self.at[self.names.index(name)]

    @property
    def offsets(self) -> np.ndarray:
        at = np.stack(self.at)
        parents = np.asarray(self.parents)
        return np.where(parents[:, None] >= 0, at - at[np.maximum(parents, 0)], at)

    def clip(self) -> BvhClip:
        """The rig as a one-frame BVH clip in its rest pose (as :func:`read_bvh` would read it)."""
        count = len(self.names)
        channels = (("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation"),) + (
            ("Zrotation", "Yrotation", "Xrotation"),
        ) * (count - 1)
        values = np.zeros((1, 3 * count + 3))
        values[0, :3] = self.at[0]
        return BvhClip(
            tuple(self.names), np.asarray(self.parents), self.offsets, dict(self.end_sites), channels, values, 1 / 30
        )

    def write_translated(self, path: Path, scale: float = 100.0, offsets: bool = True) -> Path:
        """The rig in its rest pose as a BVH with position channels on every joint, its bones also
        in its OFFSETs or (``offsets`` False) only in the channels, as some exporters write them."""
        lengths = self.offsets * scale
        kids = [[k for k, parent in enumerate(self.parents) if parent == joint] for joint in range(len(self.names))]
        lines, values = ["HIERARCHY"], []

        def emit(joint: int, indent: str) -> None:
            offset = lengths[joint] if offsets or self.parents[joint] < 0 else np.zeros(3)
            kind = "ROOT" if self.parents[joint] < 0 else "JOINT"
            lines.extend([f"{indent}{kind} {self.names[joint]}", indent + "{"])
            lines.append(f"{indent}  OFFSET {' '.join(f'{v:.6f}' for v in offset)}")
            lines.append(f"{indent}  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation")
            values.extend([*lengths[joint], 0.0, 0.0, 0.0])
            if not kids[joint]:
                lines.extend(
                    [
                        f"{indent}  End Site",
                        indent + "  {",
                        f"{indent}    OFFSET 0 {scale * 0.05:.6f} 0",
                        indent + "  }",
                    ]
                )
            for kid in kids[joint]:
                emit(kid, indent + "  ")
            lines.append(indent + "}")

        emit(0, "")
        frame = " ".join(f"{v:.6f}" for v in values)
        path.write_text("\n".join([*lines, "MOTION", "Frames: 2", "Frame Time: 0.033333", frame, frame]) + "\n")
        return path

    def write(self, path: Path, scale: float = 1.0, frames: np.ndarray | None = None) -> Path:
        """The rig as a BVH file, its lengths × ``scale`` (100: centimetres), in its rest pose or
        moved by ``frames`` (T, J, 3, 3) of local rotations."""
        local = np.broadcast_to(np.eye(3), (1, len(self.names), 3, 3)) if frames is None else frames
        root = np.repeat(self.at[0][None] * scale, len(local), axis=0)
        sites = {joint: site * scale for joint, site in self.end_sites.items()}
        return write_bvh(path, self.names, np.asarray(self.parents), self.offsets * scale, root, local, 30.0, sites)


@dataclass(frozen=True)
class Convention:
    """How one exporter names a humanoid: the trunk's joints, each side's (``{Side}`` Left/Right,
    ``{S}`` L/R, ``{s}`` l/r in a template; None for a joint the convention lacks), and what our
    trunk joints should map to where that is not one joint each (``expected``)."""

    name: str
    pelvis: str
    spine: tuple[str, ...]
    neck: tuple[str, ...]
    head: str
    side: dict[str, str | None]
    root: str | None = None
    head_end: str | None = None
    finger: str | None = None  # template with {Finger}/{finger} and {k}, the joint along the finger
    twist_leaves: tuple[str, ...] = ()  # slots with a twist bone hanging off them (Unreal's)
    twist_inside: dict[str, str] = field(default_factory=dict)  # slot → a twist bone between it and the next (Daz's)
    thighs_on: str | None = None  # the trunk joint the thighs hang from (default: the pelvis)
    arms_on: str | None = None  # ... the arms (default: the last spine joint)
    between_hips: str | None = None  # a joint between the pelvis and the thighs (Daz Genesis 3's "pelvis")
    ik: bool = False  # Unreal's IK helpers beside the pelvis
    prop: bool = False  # a weapon bone with children in the right hand
    foot_site: bool = False  # the foot's End Site points to the toes (a rig without toe joints)
    expected: dict[str, tuple[str, ...]] = field(default_factory=dict)

    def rig(self) -> RigBuilder:
        rig = RigBuilder()
        top = rig.add(self.root, None, (0, 0, 0)) if self.root else None
        pelvis = rig.add(self.pelvis, top, (0, PELVIS_AT, 0))
        trunk = [pelvis]
        for k, name in enumerate(self.spine, 1):
            trunk.append(rig.add(name, trunk[-1], (0, PELVIS_AT + (CHEST_AT - PELVIS_AT) * k / len(self.spine), 0)))
        for k, name in enumerate(self.neck):
            trunk.append(rig.add(name, trunk[-1], (0, NECK_AT + 0.04 * k, -0.01)))
        rig.add(self.head, trunk[-1], (0, HEAD_AT, 0))
        if self.head_end:
            rig.add(self.head_end, self.head, (0, 1.80, 0.02))
        for sign, words in ((1, ("Left", "L", "l")), (-1, ("Right", "R", "r"))):
            self._side(rig, sign, dict(zip(("Side", "S", "s"), words)))
        if self.ik:
            root = self.root or self.pelvis
            rig.add("ik_foot_root", root, (0, 0, 0))
            for side, sign in (("l", 1), ("r", -1)):
                rig.add(f"ik_foot_{side}", "ik_foot_root", np.multiply(LEFT["foot"], (sign, 1, 1)))
            rig.add("ik_hand_root", root, (0, 0, 0))
            rig.add("ik_hand_gun", "ik_hand_root", np.multiply(LEFT["hand"], (-1, 1, 1)))
            for side, sign in (("r", -1), ("l", 1)):
                rig.add(f"ik_hand_{side}", "ik_hand_gun", np.multiply(LEFT["hand"], (sign, 1, 1)))
        return rig

    def _side(self, rig: RigBuilder, sign: int, words: dict[str, str]) -> None:
        def at(slot: str) -> np.ndarray:
            return np.multiply(LEFT[slot], (sign, 1, 1))

        for limb, parent in zip(LIMBS, (self.arms_on or self.spine[-1], self.thighs_on or self.pelvis)):
            if limb[0] == "thigh" and self.between_hips:
                parent = (
                    self.between_hips
                    if self.between_hips in rig.names
                    else rig.add(self.between_hips, parent, (0, 0.93, 0))
                )
            for slot in limb:
                template = self.side.get(slot)
                if template is None:
                    continue
                name = rig.add(template.format(**words), parent, at(slot))
                if slot in self.twist_leaves:
                    nxt = limb[limb.index(slot) + 1]
                    rig.add(f"{slot}_twist_01_{words['s']}", name, (at(slot) + at(nxt)) / 2)
                if slot in self.twist_inside:
                    nxt = limb[limb.index(slot) + 1]
                    name = rig.add(self.twist_inside[slot].format(**words), name, (at(slot) + at(nxt)) / 2)
                parent = name
            if limb[0] == "thigh" and self.foot_site:
                rig.end_sites[rig.names.index(self.side["foot"].format(**words))] = np.array([0.0, -0.06, 0.14])
        if "hand" not in self.side:
            return
        hand = self.side["hand"].format(**words)
        if self.finger:
            for f, finger in enumerate(FINGERS):
                parent = hand
                for k in (1, 2, 3):
                    spread = (0.02 * k + 0.08, -0.01 * (f == 0), 0.04 - 0.02 * f)
                    name = self.finger.format(Finger=finger.title(), finger=finger, k=k, f=f, **words)
                    parent = rig.add(name, parent, rig.position(hand) + np.multiply(spread, (sign, 1, 1)))
        if self.prop and sign < 0:
            weapon = rig.add("Weapon_R", hand, rig.position(hand) + (0, -0.05, 0.1))
            rig.add("Weapon_Muzzle", weapon, rig.position(hand) + (0, -0.05, 0.9))

    def expected_map(self) -> dict[str, tuple[str, ...]]:
        """Each of our joints → the rig's joints it should map to (a mean: several)."""
        trunk = {"pelvis": (self.pelvis,), "head": (self.head,)}
        if len(self.spine) == 3:
            trunk |= {f"spine{k}": (name,) for k, name in enumerate(self.spine, 1)}
        if self.neck:
            trunk["neck"] = (self.neck[0],)
        ours = trunk | self.expected
        for side, words in (("left", ("Left", "L", "l")), ("right", ("Right", "R", "r"))):
            names = {slot: t.format(**dict(zip(("Side", "S", "s"), words))) for slot, t in self.side.items() if t}
            chest = self.arms_on or self.spine[-1]
            ours |= {
                f"{side}_hip": (names["thigh"],),
                f"{side}_knee": (names["shin"],),
                f"{side}_ankle": (names["foot"],),
                f"{side}_foot": (names["toe"],) if "toe" in names else (names["foot"],),
                f"{side}_collar": (names["clavicle"],) if "clavicle" in names else (chest, names["upperarm"]),
                f"{side}_shoulder": (names["upperarm"],),
                f"{side}_elbow": (names["forearm"],),
                f"{side}_wrist": (names["hand"],),
            }
        return ours


# Mixamo's limbs, which Rokoko's and Perception Neuron's exports name alike
MIXAMO_LIMBS = {
    "clavicle": "{Side}Shoulder",
    "upperarm": "{Side}Arm",
    "forearm": "{Side}ForeArm",
    "hand": "{Side}Hand",
    "thigh": "{Side}UpLeg",
    "shin": "{Side}Leg",
    "foot": "{Side}Foot",
    "toe": "{Side}ToeBase",
}
# Unreal's Mannequins' limbs, UE4's and UE5's alike
UNREAL_LIMBS = {
    "clavicle": "clavicle_{s}",
    "upperarm": "upperarm_{s}",
    "forearm": "lowerarm_{s}",
    "hand": "hand_{s}",
    "thigh": "thigh_{s}",
    "shin": "calf_{s}",
    "foot": "foot_{s}",
    "toe": "ball_{s}",
}


def without(limbs: dict[str, str], *slots: str) -> dict[str, str]:
    """``limbs`` less the joints a rig lacks."""
    return {slot: name for slot, name in limbs.items() if slot not in slots}


def _mixamo(prefix: str, name: str) -> Convention:
    return Convention(
        name,
        f"{prefix}Hips",
        tuple(f"{prefix}{s}" for s in ("Spine", "Spine1", "Spine2")),
        (f"{prefix}Neck",),
        f"{prefix}Head",
        {slot: prefix + pattern for slot, pattern in (MIXAMO_LIMBS | {"toe_end": "{Side}Toe_End"}).items()},
        head_end=f"{prefix}HeadTop_End",
        finger=prefix + "{Side}Hand{Finger}{k}",
    )


CONVENTIONS = [
    _mixamo("mixamorig:", "mixamo"),
    _mixamo("mixamorig1:", "mixamo (mixamorig1:)"),
    _mixamo("", "rokoko (Mixamo names)"),
    Convention(
        "rokoko (Newton)",
        "Hips",
        ("Spine1", "Spine2", "Spine3", "Spine4"),
        ("Neck",),
        "Head",
        {
            "clavicle": "{Side}Shoulder",
            "upperarm": "{Side}Arm",
            "forearm": "{Side}ForeArm",
            "hand": "{Side}Hand",
            "thigh": "{Side}Thigh",
            "shin": "{Side}Shin",
            "foot": "{Side}Foot",
            "toe": "{Side}Toe",
            "toe_end": "{Side}ToeEnd",
        },
        head_end="HeadTop",
        finger="{Side}Finger{f}Proximal{k}",
        expected={"spine1": ("Spine2",), "spine2": ("Spine3",), "spine3": ("Spine4",)},
    ),
    Convention(
        "unity (Mecanim)",
        "Hips",
        ("Spine", "Chest", "UpperChest"),
        ("Neck",),
        "Head",
        {
            "clavicle": "{Side}Shoulder",
            "upperarm": "{Side}UpperArm",
            "forearm": "{Side}LowerArm",
            "hand": "{Side}Hand",
            "thigh": "{Side}UpperLeg",
            "shin": "{Side}LowerLeg",
            "foot": "{Side}Foot",
            "toe": "{Side}Toes",
        },
        finger="{Side}{Finger}Proximal{k}",
    ),
    Convention(
        "perception neuron (no toes)",
        "Hips",
        ("Spine", "Spine1", "Spine2", "Spine3"),
        ("Neck",),
        "Head",
        without(MIXAMO_LIMBS, "toe"),
        finger="{Side}Hand{Finger}{k}",
        foot_site=True,
        expected={"spine1": ("Spine1",), "spine2": ("Spine2",), "spine3": ("Spine3",)},
    ),
    Convention(
        "unreal (UE4 Mannequin)",
        "pelvis",
        ("spine_01", "spine_02", "spine_03"),
        ("neck_01",),
        "head",
        UNREAL_LIMBS,
        root="root",
        finger="{finger}_0{k}_{s}",
        twist_leaves=("upperarm", "forearm", "thigh", "shin"),
        ik=True,
    ),
    Convention(
        "unreal (UE5 Manny)",
        "pelvis",
        ("spine_01", "spine_02", "spine_03", "spine_04", "spine_05"),
        ("neck_01", "neck_02"),
        "head",
        UNREAL_LIMBS,
        root="root",
        finger="{finger}_0{k}_{s}",
        twist_leaves=("upperarm", "thigh"),
        ik=True,
        expected={"spine1": ("spine_02",), "spine2": ("spine_04",), "spine3": ("spine_05",)},
    ),
    Convention(
        "daz (Genesis, Poser)",
        "hip",
        ("abdomen", "chest"),
        ("neck",),
        "head",
        {
            "clavicle": "{s}Collar",
            "upperarm": "{s}Shldr",
            "forearm": "{s}ForeArm",
            "hand": "{s}Hand",
            "thigh": "{s}Thigh",
            "shin": "{s}Shin",
            "foot": "{s}Foot",
            "toe": "{s}Toe",
        },
        finger="{s}{Finger}{k}",
        expected={"spine1": ("abdomen",), "spine2": ("abdomen", "chest"), "spine3": ("chest",)},
    ),
    Convention(
        "daz (Genesis 3, twist bones in the limbs)",
        "hip",
        ("abdomenLower", "abdomenUpper", "chestLower", "chestUpper"),
        ("neckLower", "neckUpper"),
        "head",
        {
            "clavicle": "{s}Collar",
            "upperarm": "{s}ShldrBend",
            "forearm": "{s}ForearmBend",
            "hand": "{s}Hand",
            "thigh": "{s}ThighBend",
            "shin": "{s}Shin",
            "foot": "{s}Foot",
            "toe": "{s}Toe",
        },
        finger="{s}{Finger}{k}",
        twist_inside={"upperarm": "{s}ShldrTwist", "forearm": "{s}ForearmTwist", "thigh": "{s}ThighTwist"},
        between_hips="pelvis",
        expected={"spine1": ("abdomenUpper",), "spine2": ("chestLower",), "spine3": ("chestUpper",)},
    ),
    Convention(
        "3ds max biped",
        "Bip01_Pelvis",
        ("Bip01_Spine", "Bip01_Spine1", "Bip01_Spine2"),
        ("Bip01_Neck",),
        "Bip01_Head",
        {
            "clavicle": "Bip01_{S}_Clavicle",
            "upperarm": "Bip01_{S}_UpperArm",
            "forearm": "Bip01_{S}_Forearm",
            "hand": "Bip01_{S}_Hand",
            "thigh": "Bip01_{S}_Thigh",
            "shin": "Bip01_{S}_Calf",
            "foot": "Bip01_{S}_Foot",
            "toe": "Bip01_{S}_Toe0",
            "toe_end": "Bip01_{S}_Toe0Nub",
        },
        root="Bip01",
        head_end="Bip01_HeadNub",
        finger="Bip01_{S}_Finger{f}{k}",
        thighs_on="Bip01_Spine",
        arms_on="Bip01_Neck",
    ),
    Convention(
        "blender (Rigify metarig: no head name)",
        "spine",
        ("spine.001", "spine.002", "spine.003"),
        ("spine.004", "spine.005"),
        "spine.006",
        {
            "clavicle": "shoulder.{S}",
            "upperarm": "upper_arm.{S}",
            "forearm": "forearm.{S}",
            "hand": "hand.{S}",
            "thigh": "thigh.{S}",
            "shin": "shin.{S}",
            "foot": "foot.{S}",
            "toe": "toe.{S}",
        },
        finger="f_{finger}.0{k}.{S}",
    ),
    Convention(
        "game studio (_L, _R, a prop in the hand)",
        "Pelvis",
        ("Spine_01", "Spine_02", "Chest"),
        ("Neck",),
        "Head",
        {
            "clavicle": "Clavicle_{S}",
            "upperarm": "UpperArm_{S}",
            "forearm": "Forearm_{S}",
            "hand": "Hand_{S}",
            "thigh": "Thigh_{S}",
            "shin": "Calf_{S}",
            "foot": "Foot_{S}",
            "toe": "Toe_{S}",
        },
        root="Root",
        prop=True,
    ),
    Convention(
        "studio (L_, R_ prefixes, Shoulder for the upper arm)",
        "Hips",
        ("Spine1", "Spine2", "Spine3"),
        ("Neck",),
        "Head",
        {
            "clavicle": "{S}_Clavicle",
            "upperarm": "{S}_Shoulder",
            "forearm": "{S}_Elbow",
            "hand": "{S}_Wrist",
            "thigh": "{S}_Hip",
            "shin": "{S}_Knee",
            "foot": "{S}_Ankle",
            "toe": "{S}_Ball",
        },
        finger="{S}_{Finger}{k}",
    ),
]
