"""A rig's joints as a skeleton's: which joint of a BVH file (or the midpoint of several) stands
for each joint of the 22-joint T2M layout, so that motion capture becomes HumanML3D's joints.

Presets name CMU's two cgspeed releases of its database (CMU's ASF bones as BVH joints, each joint
at the start of its bone): the "3dsMax-friendly" names (``LeftHip``, ``Chest``, ``LeftCollar``…)
and the "MotionBuilder-friendly" ones (``LeftUpLeg``, ``Spine``, ``LeftShoulder``…). CMU's spine
and neck have other joints than SMPL's, so the map is approximate there: SMPL's ``spine2`` is the
midpoint of CMU's upper back and thorax, and its collars the midpoints of the clavicles (the
features made from them are not HumanML3D's, and their scores must not be set beside published
ones). Two more presets serve retargeting onto a character (:mod:`m2d2m.motion.retarget`):
Mixamo's rigs (``mixamorig:Hips``, ``mixamorig:LeftUpLeg``…, each of ours one of theirs) and
SMPL's 24 joints, whose first 22 are T2M's under the same names. ``bandai-namco`` reads the
Bandai Namco Research Motion Dataset's 22-joint rig (:func:`_bandai_namco`). A user's own rig is a YAML map:
``our joint: their joint`` or ``our joint: [theirs, …]`` for a midpoint, every joint of the
layout named once.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from m2d2m.motion.bvh_reader import BvhClip, BvhError, BvhHeader
from m2d2m.motion.skeleton import T2M, Skeleton
from m2d2m.motion.up_axis import Stance, stance

# Metres per unit of the units BVH files come in; "cmu" is CMU's cgspeed conversions' 1/0.45 inch.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "inch": 0.0254, "cmu": 0.0254 / 0.45}
STANDING_METRES = (1.0, 2.4)  # how tall a rig's rest pose may stand to be taken for a person's


@dataclass(frozen=True)
class JointMap:
    """For each joint of a skeleton, the joints of a rig whose mean position it takes."""

    name: str
    sources: dict[str, tuple[str, ...]]  # our joint → their joints (one, or several for a midpoint)
    rest_frames: int = 0  # frames a file of this rig opens with that hold its rest pose, not motion

    def check(self, skeleton: Skeleton = T2M) -> JointMap:
        """This map, or ValueError when it leaves out a joint of ``skeleton`` or names one it lacks."""
        missing = [joint for joint in skeleton.joint_names if joint not in self.sources]
        unknown = [joint for joint in self.sources if joint not in skeleton.joint_names]
        empty = [joint for joint, theirs in self.sources.items() if not theirs]
        if missing or unknown or empty:
            problems = [
                f"it leaves out {', '.join(missing)}" if missing else "",
                f"{skeleton.name} has no joint {', '.join(unknown)}" if unknown else "",
                f"no joint of the rig given for {', '.join(empty)}" if empty else "",
            ]
            raise ValueError(f"joint map {self.name}: {'; '.join(p for p in problems if p)}")
        return self

    def fits(self, clip: BvhClip | BvhHeader) -> bool:
        """Whether every joint this map reads is in ``clip``."""
        return all(name in clip.names for theirs in self.sources.values() for name in theirs)

    def joints(self, clip: BvhClip, skeleton: Skeleton = T2M, at: np.ndarray | None = None) -> np.ndarray:
        """``clip``'s motion as ``skeleton``'s joints (T, J, 3), in the clip's lengths and axes, its
        rest frames left out, in every frame or at the fractional frames ``at`` of the motion
        (:meth:`~m2d2m.motion.bvh_reader.BvhClip.positions`); BvhError names the joints the map
        reads that the file lacks, or says that no frame of motion is left.
        :func:`~m2d2m.motion.up_axis.stance` says which way is up."""
        if len(clip.values) <= self.rest_frames:
            raise BvhError(f"joint map {self.name}: the file holds its rest pose and no motion after it")
        if at is not None:
            return self._mapped(clip.positions(np.asarray(at) + self.rest_frames), clip, skeleton)
        return self._mapped(clip.positions()[self.rest_frames :], clip, skeleton)

    def standing(self, clip: BvhClip, skeleton: Skeleton = T2M) -> Stance:
        """How ``clip``'s motion stands (:func:`~m2d2m.motion.up_axis.stance`; its rest frames left
        out, unless it holds nothing else: a rig file's one frame), in the clip's lengths."""
        positions = clip.positions()
        if len(positions) > self.rest_frames:
            positions = positions[self.rest_frames :]
        return stance(self._mapped(positions, clip, skeleton), skeleton)

    def _mapped(self, positions: np.ndarray, clip: BvhClip, skeleton: Skeleton) -> np.ndarray:
        lacking = sorted({name for theirs in self.sources.values() for name in theirs} - set(clip.names))
        if lacking:
            raise BvhError(f"joint map {self.name} reads {', '.join(lacking)}, which the BVH lacks")
        return np.stack(
            [
                positions[:, [clip.joint(name) for name in self.sources[joint]]].mean(axis=1)
                for joint in skeleton.joint_names
            ],
            axis=1,
        )

    def stature(self, clip: BvhClip, skeleton: Skeleton = T2M) -> np.ndarray:
        """The vector from the feet to the head of the rig's rest pose (every rotation zero), in
        the clip's lengths: how tall it stands, and along which axis."""
        rest = self._mapped(clip.rest_positions()[None], clip, skeleton)[0]
        feet = rest[list(skeleton.feet_left + skeleton.feet_right)].mean(axis=0)
        return rest[skeleton.head_joint] - feet

    def metres_per_unit(
        self, clip: BvhClip, units: str | None = None, skeleton: Skeleton = T2M, standing: Stance | None = None
    ) -> float:
        """Metres per unit of ``clip``'s lengths: ``units`` named (a key of :data:`UNITS` or a
        number), or else the one unit in which the rig stands a person's height
        (:data:`STANDING_METRES`): its rest pose's height where that pose stands along the
        motion's up axis (CMU's T-pose), else its motion's (Bandai Namco's rest pose lies along
        its bones' X axes); ValueError in one line when it cannot be told. ``standing``: the
        clip's :meth:`standing`, when the caller has it already."""
        if units is not None:
            if units in UNITS:
                return UNITS[units]
            try:
                value = float(units)
            except ValueError:
                raise ValueError(f"unknown unit {units!r}; give one of {', '.join(UNITS)} or metres per unit") from None
            if not value > 0:
                raise ValueError(f"metres per unit must be positive, got {units}")
            return value
        standing = standing or self.standing(clip, skeleton)
        rest = standing.upright(self.stature(clip, skeleton))
        if np.argmax(np.abs(rest)) == 1 and rest[1] > 0:
            tall, what = float(np.linalg.norm(rest)), "the rig stands"
        else:
            tall, what = standing.height, "the rig's motion stands (head over feet)"
        fitting = [name for name, scale in UNITS.items() if STANDING_METRES[0] <= tall * scale <= STANDING_METRES[1]]
        if len(fitting) != 1:
            raise ValueError(f"cannot tell the unit: {what} {tall:.4g} units tall; give --units ({', '.join(UNITS)})")
        return UNITS[fitting[0]]

    @classmethod
    def from_yaml(cls, path: str | Path, skeleton: Skeleton = T2M) -> JointMap:
        """A user's map: a YAML mapping of our joint → their joint, or a list of theirs for a midpoint."""
        path = Path(path)
        try:
            data = yaml.safe_load(path.read_text(encoding="utf-8"))
        except (OSError, yaml.YAMLError) as error:
            raise ValueError(f"{path}: not a readable YAML joint map ({error})") from error
        if not isinstance(data, dict) or not all(isinstance(v, (str, list)) for v in data.values()):
            raise ValueError(f"{path}: a joint map is a mapping of our joint → their joint or a list of theirs")
        sources = {
            str(ours): (theirs,) if isinstance(theirs, str) else tuple(map(str, theirs))
            for ours, theirs in data.items()
        }
        return cls(str(path), sources).check(skeleton)


def _cmu(
    hip: str,
    knee: str,
    ankle: str,
    toe: str,
    upperback: str,
    thorax: str,
    upperneck: str,
    clavicle: str,
    humerus: str,
    radius: str,
    wrist: str,
    name: str,
    rest_frames: int,
) -> JointMap:
    """CMU's map in one release's names; each side's names begin with Left/Right (L/R for the rest)."""
    sides = {"left": "Left", "right": "Right"}
    sources: dict[str, tuple[str, ...]] = {
        "pelvis": ("Hips",),
        "spine1": (upperback,),
        "spine2": (upperback, thorax),
        "spine3": (thorax,),
        "neck": (upperneck,),
        "head": ("Head",),
    }
    for side, prefix in sides.items():
        sources |= {
            f"{side}_hip": (prefix + hip,),
            f"{side}_knee": (prefix + knee,),
            f"{side}_ankle": (prefix + ankle,),
            f"{side}_foot": (prefix + toe,),
            f"{side}_collar": (prefix + clavicle, prefix + humerus),
            f"{side}_shoulder": (prefix + humerus,),
            f"{side}_elbow": (prefix + radius,),
            f"{side}_wrist": (prefix + wrist,),
        }
    return JointMap(name, sources, rest_frames).check()


def _mixamo() -> JointMap:
    """Mixamo's humanoid rig (``mixamorig:`` names): each of our joints one of its joints, our
    collars its ``Shoulder`` and our shoulders its ``Arm``."""
    sources = {
        "pelvis": "Hips",
        "spine1": "Spine",
        "spine2": "Spine1",
        "spine3": "Spine2",
        "neck": "Neck",
        "head": "Head",
    }
    for side, prefix in (("left", "Left"), ("right", "Right")):
        sources |= {
            f"{side}_hip": f"{prefix}UpLeg",
            f"{side}_knee": f"{prefix}Leg",
            f"{side}_ankle": f"{prefix}Foot",
            f"{side}_foot": f"{prefix}ToeBase",
            f"{side}_collar": f"{prefix}Shoulder",
            f"{side}_shoulder": f"{prefix}Arm",
            f"{side}_elbow": f"{prefix}ForeArm",
            f"{side}_wrist": f"{prefix}Hand",
        }
    return JointMap("mixamo", {ours: (f"mixamorig:{theirs}",) for ours, theirs in sources.items()}).check()


def _bandai_namco() -> JointMap:
    """The Bandai Namco Research Motion Dataset's rig (github.com/BandaiNamcoResearchInc/
    Bandai-Namco-Research-Motiondataset; ``joint_Root`` on the floor, ``Hips``, ``Spine``,
    ``Chest``, ``Neck``, ``Head``, ``Shoulder_L``, ``UpperArm_L``, ``LowerArm_L``, ``Hand_L``,
    ``UpperLeg_L``, ``LowerLeg_L``, ``Foot_L``, ``Toes_L`` and the same ``_R``). Its trunk has
    two joints where SMPL's has three, so, measured as fractions of the height from the hip
    joints to the neck (Bandai's rest offsets; SMPL's from HumanML3D's sample clip 012314):
    ``spine1`` is ``Spine`` (0.41; SMPL 0.36), ``spine2`` the midpoint of ``Spine`` and ``Chest``
    (0.52; 0.58) and ``spine3`` ``Chest`` (0.62; 0.65), where the arms branch off as from SMPL's
    spine3. Each collar is the midpoint of ``Shoulder`` (the clavicle's inner end, 5 cm off the
    midline) and ``UpperArm`` (the shoulder joint, 10 cm), as CMU's map makes it: 7.6 cm off the
    midline, where SMPL's collars lie 7.2 cm off it in 012314."""
    sources: dict[str, tuple[str, ...]] = {
        "pelvis": ("Hips",),
        "spine1": ("Spine",),
        "spine2": ("Spine", "Chest"),
        "spine3": ("Chest",),
        "neck": ("Neck",),
        "head": ("Head",),
    }
    for side, suffix in (("left", "_L"), ("right", "_R")):
        sources |= {
            f"{side}_hip": (f"UpperLeg{suffix}",),
            f"{side}_knee": (f"LowerLeg{suffix}",),
            f"{side}_ankle": (f"Foot{suffix}",),
            f"{side}_foot": (f"Toes{suffix}",),
            f"{side}_collar": (f"Shoulder{suffix}", f"UpperArm{suffix}"),
            f"{side}_shoulder": (f"UpperArm{suffix}",),
            f"{side}_elbow": (f"LowerArm{suffix}",),
            f"{side}_wrist": (f"Hand{suffix}",),
        }
    return JointMap("bandai-namco", sources).check()


PRESETS: dict[str, JointMap] = {
    "cmu": _cmu(
        "Hip", "Knee", "Ankle", "Toe", "Chest", "Chest2", "Neck", "Collar", "Shoulder", "Elbow", "Wrist", "cmu", 0
    ),
    "cmu-motionbuilder": _cmu(
        "UpLeg",
        "Leg",
        "Foot",
        "ToeBase",
        "Spine",
        "Spine1",
        "Neck1",
        "Shoulder",
        "Arm",
        "ForeArm",
        "Hand",
        "cmu-motionbuilder",
        1,  # this release opens every take with a T-pose
    ),
    "mixamo": _mixamo(),
    "smpl": JointMap("smpl", {name: (name,) for name in T2M.joint_names}).check(),
    "bandai-namco": _bandai_namco(),
}


def joint_map_for(clip: BvhClip | BvhHeader, given: str | Path | None = None) -> JointMap:
    """The map ``given`` (a preset's name or a YAML file), or the preset whose joints ``clip`` has;
    BvhError when none fits."""
    if given is not None:
        return PRESETS[str(given)] if str(given) in PRESETS else JointMap.from_yaml(given)
    for preset in PRESETS.values():
        if preset.fits(clip):
            return preset
    raise BvhError(
        f"no joint map preset ({', '.join(PRESETS)}) fits a BVH with joints {', '.join(clip.names[:8])}, …; "
        "give a YAML map of our joint → yours"
    )
