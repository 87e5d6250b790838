"""A motion on someone else's rig: the rotations that make their skeleton, with its own bone
lengths and rest pose, move as ours does (issue 40 §2; docs/generation.md, "On your own rig").

The rig comes from a BVH file (its hierarchy and OFFSETs; its first frame is not used) or a
skinned glTF/GLB character (:mod:`m2d2m.motion.files.gltf_rig`: its skin's joints as they stand), and a
:class:`~m2d2m.motion.rigs.joint_map.JointMap` naming which of its joints stand for ours (the presets
of CMU's two cgspeed releases, Mixamo's ``mixamorig:`` names, SMPL's, Bandai Namco's, the map found
from the rig's names and hierarchy, or a user's YAML: :mod:`m2d2m.motion.rigs.joint_map`). Each
of its joints is turned, root first, so that the mapped joints below it point where ours point:

* a joint with one mapped joint below it (through any unmapped ones) gets the swing that turns
  its rest vector to that joint onto our bone's direction, measured in its parent's frame (no
  twist, as :mod:`m2d2m.motion.representation.pose` does for our own rig);
* a joint with several (a pelvis: both hips and the spine) gets the best-fit (Kabsch) rotation of
  its rest vectors onto our directions, unless only one of them continues our chain from the
  joint it stands for (3ds Max Biped's first spine joint: our spine2, beside the thighs, which
  ours hangs from the pelvis): that one is pointed exactly and the others set the twist about it
  (:func:`_twisted`);
* a joint with none (fingers, an end bone) keeps its rest rotation relative to its parent, so a
  hand continues its forearm rather than spinning (momask-codes#42's complaint);
* a point the map fixes to a joint (our foot ahead of the ankle of a rig without toes:
  :mod:`m2d2m.motion.rigs.auto_map`) is aimed as a mapped joint below it would be;
* on a character whose rest pose stands on its floor as a person stands (its toes on the floor,
  its head up: :func:`stands_at_rest`), the foot (ankle → toe) and the head (neck → head) turn
  from its rest as ours turn from where ours stand (:data:`OUR_REST_AIMS`), not onto our
  direction: where a rig puts these joints is its design (Mixamo's X Bot's toe lies 39° below its
  ankle, ours 18° in stance; its head joint 10° ahead of upright from its neck, HumanML3D's 62°),
  so a foot flat in our stance is flat on its floor and a head looking ahead looks ahead. Each
  keeps the angle from our bone that its rest makes with ours. A rest pose hanging from its root
  (a BVH's) or with feet held level above the floor (our own skeleton's) says nothing of how the
  character stands, and its feet and head point where ours point, as limbs and spine always do:
  their rest directions are a pose (T or A: arms out or down), which our motion replaces.

The direction of an unmapped joint's aim is taken from its nearest mapped ancestor in our clip,
which is exact where the rig puts that joint on its ancestor (CMU's ``LHipJoint``, ``lowerback``,
``LeftCollar`` have zero OFFSETs). An unmapped joint between a joint that aims exactly at one
target and that target (a twist bone inside a limb, Daz's ``lShldrTwist``; a second neck joint)
keeps its rest rotation: its parent's turn already points the target where ours points. Bone lengths are the rig's, so the root's path is scaled by the
ratio of the rig's leg length to ours: feet cover the ground a leg of that length covers, instead
of sliding. The root goes where it puts the rig's hips where ours are, lifted once for the clip so
that its ankles stand on its own floor (:func:`ankle_lift`; docs/generation.md, "How well it lands").
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from m2d2m.motion.files.bvh_reader import BvhClip, read_bvh, rest_positions
from m2d2m.motion.files.export import write_bvh
from m2d2m.motion.files.gltf_rig import GLTF_SUFFIXES, read_gltf_rig
from m2d2m.motion.representation.rigid import best_fit_rotation, children
from m2d2m.motion.representation.rotations import qbetween, quat_from_axis_angle, quat_to_matrix
from m2d2m.motion.representation.skeleton import T2M, Skeleton
from m2d2m.motion.rigs.joint_map import JointMap, joint_map_for
from m2d2m.motion.rigs.up_axis import Stance

# Where our feet stand: HumanML3D puts each clip's floor at its lowest joint, and in clip 012314's
# stance frames (m2d2m.motion.transforms.feet.foot_contacts) its ankles stand 5.5 cm above it (median).
OUR_ANKLE_ON_FLOOR_M = 0.055
FLOOR_REACH = 0.2  # a rig's ankle this share of its leg above y = 0 or less stands on that floor
FLOOR_TOLERANCE_M = 0.01
# Where our foot and head point when standing, facing +Z: the ball of the foot 18° below the
# ankle's horizontal (clip 012314's stance frames, median), the head joint 62° ahead of upright
# from the neck (HumanML3D's Mean.npy pose, where the neck stands within 2° of upright; 012314's
# median too). Each (our parent, our child) → that bone's unit direction.
_FOOT, _HEAD = np.radians(18.0), np.radians(62.0)
HEAD_UP_DEGREES = 45.0  # a rest bone to the head this near upright holds the head up
OUR_REST_AIMS = {
    ("left_ankle", "left_foot"): (0.0, -np.sin(_FOOT), np.cos(_FOOT)),
    ("right_ankle", "right_foot"): (0.0, -np.sin(_FOOT), np.cos(_FOOT)),
    ("neck", "head"): (0.0, np.cos(_HEAD), np.sin(_HEAD)),
}


@dataclass(frozen=True)
class Rig:
    """A character's skeleton: joint ``names``, ``parents`` (-1 for the root, parents first),
    rest ``offsets`` (J, 3) from each parent in metres, and the End Sites of its leaves."""

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    end_sites: dict[int, np.ndarray]

    @classmethod
    def from_bvh(cls, clip: BvhClip) -> Rig:
        return cls(clip.names, clip.parents, clip.offsets, clip.end_sites)

    def rest_positions(self) -> np.ndarray:
        """(J, 3) every joint where the rest pose puts it (each rotation zero)."""
        return rest_positions(self.parents, self.offsets)

    def bound(self, bind: Bind) -> Rig:
        """This rig with ``bind``'s pose as its rest pose, turned to stand along +Y: the rig
        retargeting aims (:func:`retarget`); :meth:`RigMotion.unbound` takes its motion back."""
        turn, (world, above) = bind.turn, bind.world(self.parents)
        offsets = np.einsum("ij,njk,nk->ni", turn, above, self.offsets)
        root = np.flatnonzero(self.parents < 0)
        if bind.root is not None:
            offsets[root] = turn @ bind.root
        sites = {joint: turn @ world[joint] @ site for joint, site in self.end_sites.items()}
        return replace(self, offsets=offsets, end_sites=sites)


@dataclass(frozen=True)
class Bind:
    """How a rig's file stands against the pose retargeting aims from (:meth:`Rig.bound`):
    ``turn`` (3, 3), the proper rotation taking its up axis onto +Y (a Z-up capture's:
    :func:`~m2d2m.motion.rigs.up_axis.stance`); ``rotations`` (J, 3, 3), each joint's world rotation in
    its bind pose, a frame of its file (None: every rotation zero, the file's rest pose); ``root``
    (3,), where that frame puts the root, in the file's units."""

    turn: np.ndarray = field(default_factory=lambda: np.eye(3))
    rotations: np.ndarray | None = None
    root: np.ndarray | None = None
    frame: int | None = None  # the file's frame the bind pose is, for messages

    @property
    def turned(self) -> bool:
        """Whether the file stands along another axis than +Y."""
        return not np.allclose(self.turn, np.eye(3))

    def world(self, parents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Each joint's world rotation (J, 3, 3) in the bind pose of a rig of ``parents``, and its
        parent's (the root's: none)."""
        world = np.tile(np.eye(3), (len(parents), 1, 1)) if self.rotations is None else self.rotations
        above = world[np.maximum(parents, 0)]
        above[parents < 0] = np.eye(3)
        return world, above

    def scaled(self, metres_per_unit: float) -> Bind:
        return self if self.root is None else replace(self, root=self.root * metres_per_unit)


@dataclass(frozen=True)
class RigMotion:
    """A rig's animation: its root's positions (T, 3) and every joint's rotation relative to its
    parent (T, J, 3, 3); ``from_rest``: our joints at the end of the bones that turned from the
    rig's rest rather than onto ours (a foot, a head: :func:`stands_at_rest`)."""

    rig: Rig
    root: np.ndarray
    local: np.ndarray
    from_rest: frozenset[int] = frozenset()

    def positions(self) -> np.ndarray:
        """(T, J, 3) every joint's world position, by forward kinematics."""
        return self.pose()[1]

    def unbound(self, rig: Rig, bind: Bind) -> RigMotion:
        """This motion of ``rig.bound(bind)`` as ``rig``'s own (its file's axes and rest pose):
        each local rotation L' becomes B_parent⁻¹ R⁻¹ L' R B_joint (R the bind's turn, B its
        world rotations), the root's path R⁻¹ p, so that every joint stands where it stood."""
        turn, (world, above) = bind.turn, bind.world(rig.parents)
        local = np.swapaxes(above, -1, -2) @ turn.T @ self.local @ turn @ world
        return RigMotion(rig, self.root @ turn, local, self.from_rest)

    def pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Every joint's world rotation (T, J, 3, 3), from the rest pose's frame, and world
        position (T, J, 3), by forward kinematics."""
        frames, count = self.local.shape[:2]
        world = np.empty_like(self.local)
        positions = np.empty((frames, count, 3))
        for joint, parent in enumerate(self.rig.parents):
            if parent < 0:
                world[:, joint], positions[:, joint] = self.local[:, joint], self.root
            else:
                world[:, joint] = world[:, parent] @ self.local[:, joint]
                positions[:, joint] = positions[:, parent] + world[:, parent] @ self.rig.offsets[joint]
        return world, positions


def _ours_of(rig: Rig, joint_map: JointMap, skeleton: Skeleton) -> dict[int, int]:
    """The rig's joints that stand for one of ours (a map's means and points fixed to a joint
    stand for none), → ours."""
    mapped = {}
    for ours, theirs in joint_map.sources.items():
        if len(theirs) == 1 and theirs[0] in rig.names and ours not in joint_map.offsets:
            mapped[rig.names.index(theirs[0])] = skeleton.joint_names.index(ours)
    return mapped


def _aims(
    rig: Rig, joint_map: JointMap, mapped: dict[int, int], skeleton: Skeleton
) -> list[list[tuple[np.ndarray, int]]]:
    """For each joint, what it aims at, as (its rest vector to the target, our joint the target
    stands for): the first mapped joint below each of its children (depth first), and the points
    the map fixes to it (a toe ahead of an ankle: the ankle turns so that it points where our
    toe does)."""
    kids_of = children(rig.parents)
    rest = rig.rest_positions()

    def first_mapped(joint: int) -> int | None:
        if joint in mapped:
            return joint
        return next((found for kid in kids_of[joint] if (found := first_mapped(kid)) is not None), None)

    aims = [
        [
            (rest[found] - rest[joint], mapped[found])
            for kid in kids_of[joint]
            if (found := first_mapped(kid)) is not None
        ]
        for joint in range(len(kids_of))
    ]
    for ours, offset in joint_map.offsets.items():
        if joint_map.sources[ours][0] in rig.names:
            aims[rig.names.index(joint_map.sources[ours][0])].append(
                (np.asarray(offset), skeleton.joint_names.index(ours))
            )
    return aims


def retarget(joints: np.ndarray, rig: Rig, joint_map: JointMap, skeleton: Skeleton = T2M) -> RigMotion:
    """Our joint positions (T, J, 3) as ``rig``'s animation; ValueError when the map names no
    joint of the rig for our root or for the legs the root path is scaled by."""
    joints = np.asarray(skeleton.check_joints(joints), dtype=np.float64)
    mapped = _ours_of(rig, joint_map, skeleton)
    theirs = {ours: joint for joint, ours in mapped.items()}
    legs = [skeleton.joint_names.index(name) for name in ("left_hip", "left_knee", "left_ankle")]
    hips = [legs[0], skeleton.joint_names.index("right_hip")]
    missing = [skeleton.joint_names[j] for j in [0, *legs, hips[1]] if j not in theirs]
    if missing:
        raise ValueError(f"joint map {joint_map.name} names no joint of the rig for our {', '.join(missing)}")
    rest = rig.rest_positions()
    rig_leg = sum(np.linalg.norm(rest[theirs[b]] - rest[theirs[a]]) for a, b in zip(legs, legs[1:]))
    our_leg = sum(np.linalg.norm(joints[:, b] - joints[:, a], axis=-1).mean() for a, b in zip(legs, legs[1:]))
    scale = rig_leg / our_leg

    anchor = np.empty(len(rig.names), dtype=np.int64)  # each joint's nearest mapped ancestor-or-self, as ours
    aimed = np.full(len(rig.names), -1)  # the one joint of ours each joint's turn points exactly, if one
    on_floor = stands_on_floor(rest, theirs[legs[2]], rig_leg)
    rest_aims = {
        (skeleton.joint_names.index(a), skeleton.joint_names.index(b)): np.array(direction)
        for (a, b), direction in OUR_REST_AIMS.items()
        if on_floor and {a, b} <= set(skeleton.joint_names)
    }
    from_rest = set()
    frames = len(joints)
    world = np.empty((frames, len(rig.names), 3, 3))
    local = np.empty_like(world)
    identity = np.broadcast_to(np.eye(3), (frames, 3, 3))
    for joint, aims in enumerate(_aims(rig, joint_map, mapped, skeleton)):
        parent = rig.parents[joint]
        parent_world = identity if parent < 0 else world[:, parent]
        anchor[joint] = mapped.get(joint, anchor[parent] if parent >= 0 else 0)
        targets = [target for _, target in aims]
        if not aims or (joint not in mapped and parent >= 0 and [aimed[parent]] == targets):
            local[:, joint] = np.eye(3)  # nothing to aim, or its parent's turn already points its one target
            aimed[joint] = aimed[parent] if aims else -1
        elif joint not in mapped and targets == [anchor[joint]]:
            local[:, joint] = np.eye(3)  # a root above the pelvis (Unreal's on the floor): ours has no bone to it
            aimed[joint] = -1
        elif len(aims) == 1 or len(primary := _continuing(aims, int(anchor[joint]), skeleton)) == 1:
            k = 0 if len(aims) == 1 else primary[0]
            vector, aimed[joint] = aims[k]
            in_parent = np.einsum("tji,tj->ti", parent_world, joints[:, aimed[joint]] - joints[:, anchor[joint]])
            start = rest_aims.get((anchor[joint], aimed[joint]))
            if start is None or not stands_at_rest(rest[joint], vector, start):
                start = vector  # onto our direction
            else:
                from_rest.add(int(aimed[joint]))  # a foot, a head: our turn from where ours stand
            local[:, joint] = quat_to_matrix(qbetween(start, in_parent))
            others = [aim for i, aim in enumerate(aims) if i != k]
            if others:  # joints ours hangs elsewhere (Biped's thighs on its spine): they set the twist
                turned = _twisted(parent_world @ local[:, joint], others, joints, anchor[joint], aimed[joint])
                local[:, joint] = np.swapaxes(parent_world, -1, -2) @ turned
        else:
            wanted = np.stack([joints[:, target] - joints[:, anchor[joint]] for _, target in aims], axis=1)
            directions = wanted / np.linalg.norm(wanted, axis=-1, keepdims=True)
            vectors = np.stack([vector / np.linalg.norm(vector) for vector, _ in aims])
            local[:, joint] = np.swapaxes(parent_world, -1, -2) @ best_fit_rotation(vectors, directions)
        world[:, joint] = parent_world @ local[:, joint]
    # The root goes where it puts the rig's hips (not its root, which sits above them on one rig
    # and below on another) where ours are, scaled, and lifted by what keeps its feet on its floor.
    their_hips = RigMotion(rig, np.zeros((frames, 3)), local).positions()[:, [theirs[j] for j in hips]].mean(axis=1)
    lift = np.array([0.0, ankle_lift(rest, theirs[legs[2]], rig_leg, scale, skeleton), 0.0])
    return RigMotion(rig, joints[:, hips].mean(axis=1) * scale + lift - their_hips, local, frozenset(from_rest))


def _continuing(aims: list[tuple[np.ndarray, int]], anchor: int, skeleton: Skeleton) -> list[int]:
    """Which of a joint's ``aims`` are at our ``anchor``'s own children: the bones ours continues
    from it (a spine joint's next spine joint, where Biped also hangs the thighs from it)."""
    return [k for k, (_, target) in enumerate(aims) if skeleton.parents[target] == anchor]


def _twisted(
    world: np.ndarray, others: list[tuple[np.ndarray, int]], joints: np.ndarray, anchor: int, aimed: int
) -> np.ndarray:
    """``world`` (T, 3, 3), which points a joint's bone to our joint ``aimed`` exactly, turned
    about that bone so that its ``others`` (rest vector, our target) point as near as they can to
    where ours point from ``anchor``: the twist of least squares, angle atan2(Σ a·(u×w), Σ u·w)
    over each other's rest vector u and our direction w, both projected across the bone's axis a
    (an aim constraint with its up vectors, as a DCC tool's)."""
    axis = joints[:, aimed] - joints[:, anchor]
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    sine = cosine = np.zeros(len(world))
    for vector, target in others:
        turned = world @ (vector / np.linalg.norm(vector))
        wanted = joints[:, target] - joints[:, anchor]
        wanted /= np.linalg.norm(wanted, axis=-1, keepdims=True)
        across = [v - np.sum(v * axis, axis=-1, keepdims=True) * axis for v in (turned, wanted)]
        sine = sine + np.sum(axis * np.cross(*across), axis=-1)
        cosine = cosine + np.sum(across[0] * across[1], axis=-1)
    return quat_to_matrix(quat_from_axis_angle(axis, np.arctan2(sine, cosine))) @ world


def stands_on_floor(rest: np.ndarray, ankle: int, rig_leg: float) -> bool:
    """Whether a rig's rest pose (J, 3) stands on y = 0: its ``ankle`` at most :data:`FLOOR_REACH`
    of its leg above it and not below, as a DCC tool exports a character (a BVH's rest pose hangs
    from its root at the origin, and says nothing of a floor)."""
    return -FLOOR_TOLERANCE_M <= float(rest[ankle, 1]) <= FLOOR_REACH * rig_leg


def stands_at_rest(at: np.ndarray, vector: np.ndarray, ours: np.ndarray) -> bool:
    """Whether a rest bone ``vector`` from a joint ``at`` (rest position, of a rig standing on its
    floor) rests as the bone whose standing direction ours is (:data:`OUR_REST_AIMS`): a foot
    (ours points down) with its toe on the floor, lower than half the ankle's height (our own
    skeleton's level feet are not); a head (ours points up) within :data:`HEAD_UP_DEGREES` of
    upright (ours, straight ahead, is not)."""
    if ours[1] < 0:
        return float(at[1] + vector[1]) <= float(at[1]) / 2
    return float(vector[1]) >= np.cos(np.radians(HEAD_UP_DEGREES)) * float(np.linalg.norm(vector))


def ankle_lift(rest: np.ndarray, ankle: int, rig_leg: float, scale: float, skeleton: Skeleton = T2M) -> float:
    """How much higher than our scaled ankles the rig's ankles stand on its floor, in metres: its
    rest pose's ankle height where that pose stands on y = 0 (:func:`stands_on_floor`), else none."""
    if not stands_on_floor(rest, ankle, rig_leg):
        return 0.0
    return float(rest[ankle, 1]) - scale * OUR_ANKLE_ON_FLOOR_M / skeleton.metres_per_unit


def rig_bind(
    clip: BvhClip, joint_map: JointMap, standing: Stance, rest_frame: int | None = None, skeleton: Skeleton = T2M
) -> Bind:
    """The pose ``clip``'s rig is retargeted from (:class:`Bind`), turned by ``standing`` (how its
    motion stands: :meth:`~m2d2m.motion.rigs.joint_map.JointMap.standing`) to stand along +Y: its rest
    pose where that stands as its motion does (CMU's T-pose), else frame ``rest_frame`` of its
    file (by default the first: Bandai Namco's rest pose lies along its bones' X axes, and a
    bone's turn from a line is no pose to keep the twist of); ValueError in one line for a frame
    the file lacks."""
    if rest_frame is None and joint_map.rest_stands(clip, standing, skeleton):
        return Bind(standing.rotation)
    frame = 0 if rest_frame is None else rest_frame
    if not 0 <= frame < len(clip.values):
        raise ValueError(
            f"rest frame {frame}: the rig's file has {len(clip.values)} frame(s), numbered 0 to {len(clip.values) - 1}"
        )
    rotations, positions = clip.pose(np.array([float(frame)]))
    root = int(np.flatnonzero(clip.parents < 0)[0])
    return Bind(standing.rotation, rotations[0], positions[0, root], frame)


def target_of(
    clip: BvhClip,
    joint_map: JointMap,
    units: str | None = None,
    skeleton: Skeleton = T2M,
    rest_frame: int | None = None,
    character: Path | None = None,
) -> Target:
    """``clip``'s rig through ``joint_map`` as a :class:`Target`, in ``units`` (by default the one
    it stands a person's height in: :meth:`~m2d2m.motion.rigs.joint_map.JointMap.metres_per_unit`),
    from its :func:`rig_bind`; ValueError in one line where our motion cannot go onto it (checked
    with our rest pose: :meth:`Target.checked`)."""
    standing = joint_map.standing(clip, skeleton)
    scale = joint_map.metres_per_unit(clip, units, skeleton, standing)
    bind = rig_bind(clip, joint_map, standing, rest_frame, skeleton)
    return Target(Rig.from_bvh(clip), joint_map, scale, character, bind).checked(skeleton)


def read_rig(path: str | Path) -> BvhClip:
    """The rig in the file at ``path``: a glTF character (``.glb``, ``.gltf``) or else a BVH."""
    return read_gltf_rig(path) if Path(path).suffix.lower() in GLTF_SUFFIXES else read_bvh(path)


@dataclass(frozen=True)
class Target:
    """A rig read and checked once, ready to take any number of motions: its skeleton in its own
    units, the joint map its joints take and its metres per unit (a server keeps one per uploaded
    character, so a character's file is not read again for every clip put on it); ``character``:
    the glTF file the rig came from, whose meshes a GLB on the rig keeps (:mod:`m2d2m.motion.rigs.gltf_export`);
    ``bind``: the pose its motions are aimed from, turned to stand along +Y (:func:`rig_bind`)."""

    rig: Rig
    joint_map: JointMap
    metres_per_unit: float
    character: Path | None = None
    bind: Bind = field(default_factory=Bind)

    def checked(self, skeleton: Skeleton = T2M) -> Target:
        """This target, having put our rest pose on it once: ValueError in one line where our
        motion cannot go onto it (a map whose joints do not chain as ours do)."""
        identity = np.tile([1.0, 0.0, 0.0, 0.0], (1, skeleton.num_joints, 1))
        self.retargeted(skeleton.forward_kinematics(identity, np.array([[0.0, 0.9 / skeleton.metres_per_unit, 0.0]])))
        return self

    def retargeted(self, joints: np.ndarray, skeleton: Skeleton = T2M) -> RigMotion:
        """Our joints (T, J, 3) as this rig's animation in its file's axes and rest pose, in metres
        (:func:`retarget` onto the rig as its :attr:`bind` stands it)."""
        in_metres = replace(self.rig, offsets=self.rig.offsets * self.metres_per_unit)
        bind = self.bind.scaled(self.metres_per_unit)
        return retarget(joints, in_metres.bound(bind), self.joint_map, skeleton).unbound(in_metres, bind)

    def write_bvh(
        self, path: str | Path, joints: np.ndarray, fps: float | None = None, skeleton: Skeleton = T2M
    ) -> Path:
        """Our joints as a BVH on this rig, in the rig's own units, so it drops onto the character."""
        motion = self.retargeted(joints, skeleton)
        rig = self.rig
        fps = float(skeleton.fps if fps is None else fps)
        root = motion.root / self.metres_per_unit
        return write_bvh(path, rig.names, rig.parents, rig.offsets, root, motion.local, fps, rig.end_sites)


def read_target(
    rig_file: str | Path,
    joint_map: str | Path | JointMap | None = None,
    units: str | None = None,
    skeleton: Skeleton = T2M,
    rest_frame: int | None = None,
) -> Target:
    """The rig of ``rig_file`` (:func:`read_rig`: a BVH or a glTF character) through ``joint_map``
    (:func:`~m2d2m.motion.rigs.joint_map.joint_map_for`: a map, complete or correcting the automatic
    one, a preset's name, ``auto``, a YAML file, or by default the preset its joints fit, else
    the automatic map), in ``units``, from its rest pose or frame ``rest_frame`` (:func:`target_of`);
    BvhError or ValueError in one line for a rig our motions cannot go onto."""
    clip = read_rig(rig_file)
    mapping = joint_map_for(clip, joint_map)
    character = Path(rig_file) if Path(rig_file).suffix.lower() in GLTF_SUFFIXES else None
    return target_of(clip, mapping, units, skeleton, rest_frame, character)


def retarget_to_bvh(
    path: str | Path,
    joints: np.ndarray,
    rig_file: str | Path,
    joint_map: str | Path | None = None,
    fps: float | None = None,
    skeleton: Skeleton = T2M,
    units: str | None = None,
) -> Path:
    """Our joints as a BVH on the rig of ``rig_file`` through ``joint_map``, in ``units``
    (:func:`read_target`), written in the rig's own units so it drops onto the character."""
    return read_target(rig_file, joint_map, units, skeleton).write_bvh(path, joints, fps, skeleton)
