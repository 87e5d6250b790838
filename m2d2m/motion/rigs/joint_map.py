"""A rig's joints as a skeleton's: which joint of a BVH file (or the mean of several, or a point
fixed to one) stands for each joint of the 22-joint T2M layout, so that motion capture becomes
HumanML3D's joints and our motion goes onto a character (:mod:`m2d2m.motion.rigs.retarget`).

Presets name CMU's two cgspeed releases of its database (CMU's ASF bones as BVH joints, each joint
at the start of its bone): the "3dsMax-friendly" names (``LeftHip``, ``Chest``, ``LeftCollar``…)
and the "MotionBuilder-friendly" ones (``LeftUpLeg``, ``Spine``, ``LeftShoulder``…). CMU's spine
and neck have other joints than SMPL's, so the map is approximate there: SMPL's ``spine2`` is the
midpoint of CMU's upper back and thorax, and its collars the midpoints of the clavicles (the
features made from them are not HumanML3D's, and their scores must not be set beside published
ones). Two more presets serve retargeting onto a character: Mixamo's rigs (``mixamorig:Hips``,
``mixamorig:LeftUpLeg``…, each of ours one of theirs) and SMPL's 24 joints, whose first 22 are
T2M's under the same names. ``bandai-namco`` reads the Bandai Namco Research Motion Dataset's
22-joint rig (:func:`_bandai_namco`).

Any other rig is mapped from its names and hierarchy (:mod:`m2d2m.motion.rigs.auto_map`, the map
named ``auto``), and a user's YAML map corrects it: ``our joint: their joint``, ``our joint:
[theirs, …]`` for the mean of several (one repeated weighs twice), or ``our joint: {joint:
theirs, offset: [x, y, z]}`` for a point fixed to one (our foot on a rig without toes), naming
all of our joints or only those it corrects. ``m2d2m rig FILE`` prints what is found and writes
it as such a YAML (:meth:`RigMapping.yaml`). A map that names one joint of theirs for two of ours
is refused: the rig's joint can stand for one of ours only, and the other would be dropped.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from m2d2m.motion.files.bvh_reader import BvhClip, BvhError, BvhHeader
from m2d2m.motion.representation.skeleton import T2M, Skeleton
from m2d2m.motion.rigs.auto_map import DERIVED, MISSING, NAME, Found, auto_map
from m2d2m.motion.rigs.up_axis import Stance, stance

# Metres per unit of the units BVH files come in; "cmu" is CMU's cgspeed conversions' 1/0.45 inch.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "inch": 0.0254, "cmu": 0.0254 / 0.45}
STANDING_METRES = (1.0, 2.4)  # how tall a rig's rest pose may stand to be taken for a person's


@dataclass(frozen=True)
class JointMap:
    """For each joint of a skeleton, the joints of a rig whose mean position it takes; or, for
    one with an ``offsets`` entry, the point that offset (in the rig's rest pose and units) from
    its one joint, turning as that joint turns."""

    name: str
    sources: dict[str, tuple[str, ...]]  # our joint → their joints (one, or several for a mean)
    rest_frames: int = 0  # frames a file of this rig opens with that hold its rest pose, not motion
    offsets: dict[str, tuple[float, float, float]] = field(default_factory=dict)

    def check(self, skeleton: Skeleton = T2M, complete: bool = True) -> JointMap:
        """This map, or ValueError in one line when it leaves out a joint of ``skeleton`` (unless
        not ``complete``: a map that corrects some), names one it lacks, gives an offset to a
        mean, or names one joint of theirs alone for two of ours (one of them would be dropped)."""
        missing = [joint for joint in skeleton.joint_names if joint not in self.sources] if complete else []
        unknown = [joint for joint in self.sources if joint not in skeleton.joint_names]
        empty = [joint for joint, theirs in self.sources.items() if not theirs]
        means = [joint for joint in self.offsets if len(self.sources.get(joint, ())) != 1]
        if missing or unknown or empty or means:
            problems = [
                f"it leaves out {', '.join(missing)}" if missing else "",
                f"{skeleton.name} has no joint {', '.join(unknown)}" if unknown else "",
                f"no joint of the rig given for {', '.join(empty)}" if empty else "",
                f"an offset is from one joint, not a mean ({', '.join(means)})" if means else "",
            ]
            raise ValueError(f"joint map {self.name}: {'; '.join(p for p in problems if p)}")
        alone: dict[tuple[str, ...], list[str]] = {}
        for joint, theirs in self.sources.items():
            if len(theirs) == 1:
                alone.setdefault((theirs[0], *self.offsets.get(joint, ())), []).append(joint)
        twice = next((joints for joints in alone.values() if len(joints) > 1), None)
        if twice:
            raise ValueError(
                f"joint map {self.name} names {self.sources[twice[0]][0]} for both {twice[0]} and {twice[1]}, "
                f"so one would be dropped: give each of ours its own joint, or a list of joints for a mean"
            )
        return self

    def fits(self, clip: BvhClip | BvhHeader) -> bool:
        """Whether every joint this map reads is in ``clip``."""
        return all(name in clip.names for theirs in self.sources.values() for name in theirs)

    def joints(self, clip: BvhClip, skeleton: Skeleton = T2M, at: np.ndarray | None = None) -> np.ndarray:
        """``clip``'s motion as ``skeleton``'s joints (T, J, 3), in the clip's lengths and axes, its
        rest frames left out, in every frame or at the fractional frames ``at`` of the motion
        (:meth:`~m2d2m.motion.files.bvh_reader.BvhClip.pose`); BvhError names the joints the map
        reads that the file lacks, or says that no frame of motion is left.
        :func:`~m2d2m.motion.rigs.up_axis.stance` says which way is up."""
        if len(clip.values) <= self.rest_frames:
            raise BvhError(f"joint map {self.name}: the file holds its rest pose and no motion after it")
        if at is not None:
            return self._mapped(*clip.pose(np.asarray(at) + self.rest_frames), clip, skeleton)
        rotations, positions = clip.pose()
        return self._mapped(rotations[self.rest_frames :], positions[self.rest_frames :], clip, skeleton)

    def standing(self, clip: BvhClip, skeleton: Skeleton = T2M) -> Stance:
        """How ``clip``'s motion stands (:func:`~m2d2m.motion.rigs.up_axis.stance`; its rest frames left
        out, unless it holds nothing else: a rig file's one frame), in the clip's lengths."""
        rotations, positions = clip.pose()
        first = self.rest_frames if len(positions) > self.rest_frames else 0
        return stance(self._mapped(rotations[first:], positions[first:], clip, skeleton), skeleton)

    def _mapped(self, rotations: np.ndarray, positions: np.ndarray, clip: BvhClip, skeleton: Skeleton) -> np.ndarray:
        """Our joints from the rig's world rotations (T, J, 3, 3) and positions (T, J, 3)."""
        lacking = sorted({name for theirs in self.sources.values() for name in theirs} - set(clip.names))
        if lacking:
            raise BvhError(f"joint map {self.name} reads {', '.join(lacking)}, which the BVH lacks")
        ours = []
        for joint in skeleton.joint_names:
            theirs = [clip.joint(name) for name in self.sources[joint]]
            point = positions[:, theirs].mean(axis=1)
            if joint in self.offsets:
                point = point + rotations[:, theirs[0]] @ np.asarray(self.offsets[joint])
            ours.append(point)
        return np.stack(ours, axis=1)

    def stature(self, clip: BvhClip, skeleton: Skeleton = T2M) -> np.ndarray:
        """The vector from the feet to the head of the rig's rest pose (every rotation zero), in
        the clip's lengths: how tall it stands, and along which axis."""
        rest = clip.rest_positions()
        rest = self._mapped(np.broadcast_to(np.eye(3), (1, len(rest), 3, 3)), rest[None], clip, skeleton)[0]
        feet = rest[list(skeleton.feet_left + skeleton.feet_right)].mean(axis=0)
        return rest[skeleton.head_joint] - feet

    def rest_stands(self, clip: BvhClip, standing: Stance, skeleton: Skeleton = T2M) -> bool:
        """Whether ``clip``'s rest pose stands along the up axis its motion stands along
        (``standing``): head over feet (CMU's T-pose does; Bandai Namco's, along its bones' X
        axes, does not)."""
        rest = standing.upright(self.stature(clip, skeleton))
        return bool(np.argmax(np.abs(rest)) == 1 and rest[1] > 0)

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
        if self.rest_stands(clip, standing, skeleton):
            tall, what = float(np.linalg.norm(self.stature(clip, skeleton))), "the rig stands"
        else:
            tall, what = standing.height, "the rig's motion stands (head over feet)"
        fitting = [name for name, scale in UNITS.items() if STANDING_METRES[0] <= tall * scale <= STANDING_METRES[1]]
        if len(fitting) != 1:
            raise ValueError(f"cannot tell the unit: {what} {tall:.4g} units tall; give --units ({', '.join(UNITS)})")
        return UNITS[fitting[0]]

    @classmethod
    def from_yaml(cls, path: str | Path, skeleton: Skeleton = T2M) -> JointMap:
        """A user's map, which may name only some of our joints: a YAML mapping of our joint →
        their joint, a list of theirs for a mean, or ``{joint: theirs, offset: [x, y, z]}``."""
        path = Path(path)
        try:
            data = yaml.safe_load(path.read_text(encoding="utf-8"))
        except (OSError, yaml.YAMLError) as error:
            raise ValueError(f"{path}: not a readable YAML joint map ({error})") from error
        if not isinstance(data, dict) or not all(isinstance(v, (str, list, dict)) for v in data.values()):
            raise ValueError(f"{path}: a joint map is a mapping of our joint → their joint or a list of theirs")
        sources, offsets = {}, {}
        for ours, theirs in data.items():
            if isinstance(theirs, dict):
                joint, offset = theirs.get("joint"), theirs.get("offset")
                if set(theirs) != {"joint", "offset"} or not isinstance(joint, str) or not _is_vector(offset):
                    raise ValueError(
                        f"{path}: {ours}: a point fixed to a joint is {{joint: theirs, offset: [x, y, z]}}"
                    )
                theirs, offsets[str(ours)] = joint, tuple(float(v) for v in offset)
            if isinstance(theirs, list) and not all(isinstance(name, str) for name in theirs):
                # names only: a nested list is no joint, and YAML aliases nested in lists would
                # make one a few lines long expand to gigabytes when written out as names
                raise ValueError(f"{path}: {ours}: a list of their joints holds names only")
            sources[str(ours)] = (theirs,) if isinstance(theirs, str) else tuple(theirs)
        return cls(str(path), sources, offsets=offsets).check(skeleton, complete=False)


def _is_vector(value: object) -> bool:
    return isinstance(value, list) and len(value) == 3 and all(isinstance(v, (int, float)) for v in value)


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


AUTO = "auto"  # the name of a map found from the rig itself (:mod:`m2d2m.motion.rigs.auto_map`)
GIVEN = "given"  # how a joint the user's YAML names was found


@dataclass(frozen=True)
class RigMapping:
    """Which joints of a rig stand for ours and how each was found (:class:`~m2d2m.motion.rigs.auto_map.Found`:
    matched by name, guessed, derived, missing, or :data:`GIVEN` by the user's YAML); ``name``
    says whose map it is (a preset's, ``auto``, or the YAML's path)."""

    name: str
    found: dict[str, Found]
    rest_frames: int = 0

    @property
    def missing(self) -> list[str]:
        return [joint for joint, found in self.found.items() if found.how == MISSING]

    def joint_map(self) -> JointMap:
        """The map, or a BvhError in one line saying what the rig lacks."""
        if self.missing:
            why = self.found[self.missing[0]].why
            which = "none of ours" if len(self.missing) == len(self.found) else ", ".join(self.missing) + " not"
            raise BvhError(
                f"cannot map the rig's joints onto ours: {why} ({which} found); give a YAML map of our joint → "
                "yours (`m2d2m rig FILE --out map.yaml` writes one to correct)"
            )
        sources = {joint: found.theirs for joint, found in self.found.items()}
        offsets = {joint: found.offset for joint, found in self.found.items() if found.offset is not None}
        return JointMap(self.name, sources, self.rest_frames, offsets).check()

    def lines(self) -> list[str]:
        """One line per joint of ours: its joints of the rig, how they were found and why."""
        theirs = {
            joint: (" + ".join(found.theirs) or "-")
            + ("" if found.offset is None else f" + ({', '.join(f'{v:g}' for v in found.offset)}) turning with it")
            for joint, found in self.found.items()
        }
        ours_width, theirs_width = max(map(len, theirs)), max(map(len, theirs.values()))
        return [
            f"{joint:<{ours_width}}  {theirs[joint]:<{theirs_width}}  {found.how}{': ' + found.why if found.why else ''}"
            for joint, found in self.found.items()
        ]

    def yaml(self, rig: str) -> str:
        """The mapping as a YAML map to correct and give back (``--joint-map``), each line
        commented with how it was found, the joints not found commented out."""
        header = [
            f"# Joint map for {rig}: our joint: the rig's joint, [its joints] for their mean (one repeated",
            "# weighs twice), or {joint: its joint, offset: [x, y, z]} for a point fixed to it (rest pose,",
            "# the rig's units). Correct any line; a map may name only the joints it corrects.",
        ]
        lines = []
        for joint, found in self.found.items():
            note = f"  # {found.how}{': ' + found.why if found.why else ''}"
            if found.how == MISSING:
                lines.append(f"# {joint}:{note}")
                continue
            entry: str | list | dict = list(found.theirs)  # each written as JointMap.from_yaml reads it back
            if found.offset is not None:
                entry = {"joint": found.theirs[0], "offset": list(found.offset)}
            elif len(found.theirs) == 1:
                entry = found.theirs[0]
            value = yaml.safe_dump({joint: entry}, default_flow_style=True, width=10**6).strip()
            lines.append(value[1:-1] + note)  # the one-key flow mapping's braces taken off: one line per joint
        return "\n".join(header + lines) + "\n"


def _as_found(joint_map: JointMap, how: str, why: str) -> dict[str, Found]:
    """Each joint a map names, in our order, as found ``how`` (by name: derived where it is a mean
    or a point fixed to a joint)."""
    found = {}
    for joint in (joint for joint in T2M.joint_names if joint in joint_map.sources):
        theirs = joint_map.sources[joint]
        derived = how == NAME and (len(theirs) > 1 or joint in joint_map.offsets)
        found[joint] = Found(theirs, DERIVED if derived else how, why, joint_map.offsets.get(joint))
    return found


def rig_mapping(clip: BvhClip | BvhHeader, given: str | Path | JointMap | None = None) -> RigMapping:
    """How ``clip``'s joints map onto ours: through ``given`` (a preset's name, ``auto``, or a
    user's map, a YAML file or one read already, which may correct only some joints of the
    automatic map), or else the preset whose
    joints the clip has, or else the automatic map (:func:`~m2d2m.motion.rigs.auto_map.auto_map`)."""
    preset = _preset(clip, given)
    if preset is not None:
        return RigMapping(preset.name, _as_found(preset, NAME, f"preset {preset.name}"), preset.rest_frames)
    user = given if isinstance(given, JointMap) else None if given in (None, AUTO) else JointMap.from_yaml(given)
    complete = user is not None and all(joint in user.sources for joint in T2M.joint_names)
    found = {} if complete else auto_map(clip)
    if user is not None:
        lacking = {name for theirs in user.sources.values() for name in theirs} - set(clip.names)
        for joint, theirs in _as_found(user, GIVEN, f"in {user.name}").items():
            absent = [name for name in theirs.theirs if name in lacking]
            found[joint] = Found((), MISSING, f"the rig has no joint {absent[0]}") if absent else theirs
    name = AUTO if user is None else user.name if complete else f"{user.name} over auto"
    return RigMapping(name, {joint: found[joint] for joint in T2M.joint_names})


def joint_map_for(clip: BvhClip | BvhHeader, given: str | Path | JointMap | None = None) -> JointMap:
    """The map ``given`` (a preset's name, ``auto``, or a user's map, complete or correcting the
    automatic map), or the preset whose joints ``clip`` has, or the one found from its names and
    hierarchy (:func:`rig_mapping`); BvhError in one line when its legs, spine, head or arms
    cannot be found."""
    if isinstance(given, JointMap) and all(joint in given.sources for joint in T2M.joint_names):
        return given  # complete already: nothing of the automatic map to add
    preset = _preset(clip, given)
    return preset if preset is not None else rig_mapping(clip, given).joint_map()


def _preset(clip: BvhClip | BvhHeader, given: str | Path | JointMap | None) -> JointMap | None:
    """The preset ``given`` names, or where none is given the first whose joints ``clip`` has."""
    if isinstance(given, JointMap):
        return None
    if given is not None:
        return PRESETS.get(str(given))
    return next((preset for preset in PRESETS.values() if preset.fits(clip)), None)
