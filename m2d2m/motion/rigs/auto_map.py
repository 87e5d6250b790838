"""Which joints of someone else's rig stand for the 22 of T2M, found from the rig itself: its
joints' names and its hierarchy, for a rig no preset of :mod:`m2d2m.motion.rigs.joint_map` fits
(docs/generation.md, "On your own rig").

The approach follows two public designs. Unreal Engine's IK Rig auto-characterization compares a
skeleton's names and hierarchy with templates of known rigs and adapts the chains it finds
(dev.epicgames.com, the IKRigEditor API's ``FAutoCharacterizer``); Unity's Humanoid avatar sorts
bones into required ones (hips, upper and lower legs, feet, spine, head, upper and lower arms,
hands) and optional ones (toes, neck, shoulders, chest, upper chest; docs.unity3d.com,
``HumanBodyBones`` and the Manual's "Humanoid Avatars"). Here:

1. **The ends.** Each joint's name is read (:mod:`m2d2m.motion.rigs.bone_names`); the feet, the hands
   and the head are the shallowest joints named so, each side's by its name; a head no name
   gives is the end of the longest branch above the chest that leads to no hand (Rigify's
   ``spine.006``). Where names do not give the feet and hands, the hierarchy does: the pelvis is
   the first joint with three long branches (two legs and a spine), the chest the first joint up
   that spine with three (two arms and a neck); a leg's ankle is its third joint, an arm's wrist
   the joint where it branches into fingers. Where names do not tell left from right, the rest
   pose does: the character's left is up × forward, forward being where its toes point, else
   glTF's +Z for a Y-up rig and Blender's −Y for a Z-up one (:func:`~m2d2m.motion.rigs.up_axis.facing`).
2. **The chains.** The pelvis is the joint where the legs and the head's path part (a joint named
   pelvis or hips above it, as 3ds Max Biped's ``Bip01 Pelvis`` above ``Bip01 Spine``, where the
   thighs hang); the chest is where the two arms part. Along each chain, joints named as a
   helper (IK targets, props: their whole branch), a twist or roll bone, a finger or a chain's
   tip are passed over, and so is a joint that sits on its parent (CMU's ``LHipJoint``). Within
   a chain, a joint named for the part is taken first; otherwise the joint's place tells, counted
   back from the chain's end: the knee is the joint before the ankle, the hip the one before
   that; the elbow, the shoulder and the clavicle likewise before the wrist. The spine runs from
   the pelvis to the first joint named neck, or else to the chest.
3. **Optional joints**, made from the others where the rig lacks them (a JointMap's mean of
   several of its joints, a joint repeated to weigh it, or a point fixed to one:
   :class:`~m2d2m.motion.rigs.joint_map.JointMap`). Three spine joints are spine1..3; more, the top
   two and the one :data:`SPINE1_AT` of the way up; two, as CMU's and Bandai Namco's presets
   take them, spine2 their midpoint; one is spine3, spine1 and spine2 1/2 and 2/3 of the way to
   it from the pelvis; none, all three between the pelvis and the neck. No neck: the midpoint of
   the chest and the head. A clavicle that stands off the chest is our collar; one on the chest
   (CMU's) or none, the collar is halfway from it (or the chest) to the shoulder. No toe: a point
   fixed to the ankle, along the foot's End Site where a BVH gives one pointing forward, at
   HumanML3D's proportions (its sample clip 012314: the ball of the foot 0.143 m from the ankle,
   17 % of the thigh and shin, 20° below the horizontal).

Each of our joints comes back :class:`Found`, matched by name, guessed (by the hierarchy or the
rest pose), derived (from other joints) or missing, with why.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from m2d2m.motion.files.bvh_reader import BvhClip, BvhHeader
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.motion.rigs.bone_names import BoneName, read_name
from m2d2m.motion.rigs.up_axis import axis_of, facing

NAME, GUESSED, DERIVED, MISSING = "matched by name", "guessed", "derived", "missing"
SIDES = ("left", "right")
REQUIRED = ("pelvis", "head") + tuple(
    f"{side}_{joint}" for side in SIDES for joint in ("hip", "knee", "ankle", "shoulder", "elbow", "wrist")
)
FOOT_LENGTH = 0.173  # ankle to the ball of the foot, over thigh + shin (HumanML3D's 012314: 0.143 / 0.826 m)
FOOT_DROP = np.radians(20.0)  # how far below the horizontal the ball of the foot lies from the ankle (012314)
SITS_ON_PARENT = 1e-3  # a bone shorter than this share of the rig's size puts its joint on its parent
LIMB = 0.2  # a branch at least this share of the longest path from the root is a leg or the spine
NECK_OR_ARM = 0.08  # ... at least this share, an arm or the neck where they part at the chest
SPINE1_AT = 0.4  # SMPL's spine1 lies 0.4 of the way up the spine to spine3, along its bones


@dataclass(frozen=True)
class Found:
    """How one joint of ours was found on a rig: ``theirs``, the rig's joints whose mean it is (a
    joint repeated weighs twice; none when ``how`` is :data:`MISSING`), ``offset`` from the one
    joint, in the rig's rest pose and units, where ours is a point fixed to it (a toe the rig
    lacks), ``how`` (:data:`NAME`, :data:`GUESSED`, :data:`DERIVED` or :data:`MISSING`) and why."""

    theirs: tuple[str, ...]
    how: str
    why: str = ""
    offset: tuple[float, float, float] | None = None


Hierarchy = BvhClip | BvhHeader  # anything with names, parents, offsets, End Sites and a rest pose


class _Tree:
    """A rig's hierarchy with what its names say, and the lengths its rest pose gives."""

    def __init__(self, rig: Hierarchy) -> None:
        self.names = rig.names
        self.parents = np.asarray(rig.parents)
        self.said: list[BoneName] = [read_name(name) for name in rig.names]
        self.rest = rig.rest_positions()
        self.end_sites = rig.end_sites
        self.length = np.linalg.norm(np.asarray(rig.offsets, dtype=np.float64), axis=-1)
        self.length[self.parents < 0] = 0.0
        self.kids: list[list[int]] = [[] for _ in self.names]
        self.depth = np.zeros(len(self.names), dtype=np.int64)
        for joint, parent in enumerate(self.parents):
            if parent >= 0:
                self.kids[parent].append(joint)
                self.depth[joint] = self.depth[parent] + 1
        helper = np.zeros(len(self.names), dtype=bool)
        for joint, parent in enumerate(self.parents):  # parents come first
            helper[joint] = self.said[joint].helper or (parent >= 0 and helper[parent])
        self.body = [joint for joint in range(len(self.names)) if not helper[joint]]
        size = float(np.ptp(self.rest, axis=0).max()) if len(self.names) > 1 else 0.0
        self.tolerance = SITS_ON_PARENT * (size or 1.0)

    @cached_property
    def reach(self) -> np.ndarray:
        """Each joint's bone plus the longest path below it, through joints of the body."""
        reach = self.length.copy()
        for joint in reversed(range(len(self.names))):
            below = [reach[kid] for kid in self.kids[joint] if not self.said[kid].helper]
            reach[joint] += max(below, default=0.0)
        return reach

    def ancestors(self, joint: int) -> list[int]:
        """``joint`` and every joint above it, up to the root."""
        line = [joint]
        while self.parents[line[-1]] >= 0:
            line.append(int(self.parents[line[-1]]))
        return line

    def meet(self, joints: Iterable[int]) -> int:
        """The deepest joint above (or at) all of ``joints``."""
        common = None
        for joint in joints:
            line = self.ancestors(joint)
            common = line if common is None else [j for j in line if j in common]
        return common[0]

    def path(self, top: int, bottom: int) -> list[int]:
        """The joints from below ``top`` down to ``bottom``, in order (empty when ``top`` is not above it)."""
        line = self.ancestors(bottom)
        return list(reversed(line[: line.index(top)])) if top in line else []

    def on_parent(self, joint: int) -> bool:
        return bool(self.length[joint] < self.tolerance)

    def main_line(self, joint: int) -> list[int]:
        """``joint`` and the joints below it, each the child of the longest reach, to a leaf."""
        line = [joint]
        while kids := [kid for kid in self.kids[line[-1]] if not self.said[kid].helper]:
            line.append(max(kids, key=lambda kid: self.reach[kid]))
        return line

    def major_kids(self, joint: int, share: float) -> list[int]:
        """The children of ``joint`` whose branch is at least ``share`` of the root's reach, longest first."""
        least = share * self.reach[int(np.flatnonzero(self.parents < 0)[0])]
        kids = [kid for kid in self.kids[joint] if not self.said[kid].helper and self.reach[kid] >= least]
        return sorted(kids, key=lambda kid: -self.reach[kid])


@dataclass(frozen=True)
class _Ends:
    """The ankles and the wrists of a rig, by side, its head, and what told the sides apart
    where names did not ("" where they did)."""

    ankles: dict[str, int]
    wrists: dict[str, int]
    head: int
    sides_by: str = ""


def auto_map(rig: Hierarchy) -> dict[str, Found]:
    """Each of T2M's joints (in its order) as found on ``rig``: a BVH clip or header, or a glTF
    rig read as a clip (:func:`~m2d2m.motion.files.gltf_rig.read_gltf_rig`)."""
    tree = _Tree(rig)
    ends = _ends(tree)
    if isinstance(ends, str):
        return {joint: Found((), MISSING, ends) for joint in T2M.joint_names}
    pelvis = _pelvis(tree, ends)
    chest = tree.meet(ends.wrists.values())
    trunk = tree.path(pelvis, ends.head)
    if chest not in trunk[:-1]:
        why = "the arms do not part on the path from the pelvis to the head"
        return {joint: Found((), MISSING, why) for joint in T2M.joint_names}
    found = {"pelvis": _found(tree, pelvis, {"pelvis"}, None, "where the legs and the spine part")}
    found |= _trunk(tree, pelvis, chest, trunk)
    for side in SIDES:
        found |= _leg(tree, side, pelvis, ends)
        found |= _arm(tree, side, chest, ends)
    if _missing_required(found):
        found |= {f"{side}_foot": Found((), MISSING, "no leg to put it on") for side in SIDES}
    else:
        found |= {f"{side}_foot": _toe(tree, found, side, ends.ankles[side]) for side in SIDES}
    return {joint: found[joint] for joint in T2M.joint_names}


def _missing_required(found: dict[str, Found]) -> list[str]:
    """The joints of ours a rig must have to take our motion (Unity's required bones, less the
    spine) that ``found`` lacks."""
    return [joint for joint in REQUIRED if joint not in found or found[joint].how == MISSING]


def _found(tree: _Tree, joint: int, parts: set[str], side: str | None, guess: str) -> Found:
    """Ours as the rig's ``joint``: matched by name where its name says one of ``parts`` (and
    ``side``, for a joint of a side), else guessed (``guess`` says how)."""
    said = tree.said[joint]
    named = said.part in parts and (side is None or said.side == side)
    return Found((tree.names[joint],), NAME if named else GUESSED, "" if named else guess)


def _derived(tree: _Tree, joints: Iterable[int], why: str) -> Found:
    return Found(tuple(tree.names[joint] for joint in joints), DERIVED, why)


def _shallowest(tree: _Tree, joints: Iterable[int]) -> int | None:
    joints = list(joints)
    return min(joints, key=lambda joint: tree.depth[joint]) if joints else None


def _ends(tree: _Tree) -> _Ends | str:
    """The ankles, wrists and head: by name where names give them, else by the hierarchy
    (:func:`_by_topology`); sides by name, else by the rest pose (:func:`_left_first`). A string
    says why there are none."""
    pairs = {part: _named_pair(tree, part) for part in ("foot", "hand")}
    head = _shallowest(tree, (j for j in tree.body if tree.said[j].part == "head"))
    if pairs["hand"] is not None and head is None:
        head = _head_of(tree, tree.meet(pairs["hand"]), pairs["hand"])
    if None in pairs.values() or head is None:
        shape = _by_topology(tree)
        if isinstance(shape, str):
            return shape
        pairs = {part: pairs[part] or shape[part] for part in pairs}
        head = head if head is not None else shape["head"][0]
    (ankles, feet_by), (wrists, hands_by) = (_sided(tree, pairs[part], head) for part in ("foot", "hand"))
    return _Ends(ankles, wrists, head, feet_by or hands_by)


def _named_pair(tree: _Tree, part: str) -> list[int] | None:
    """The two joints named ``part`` nearest the root: one of each side, or, where names leave a
    side out, the nearest ones named without a side."""
    named = [joint for joint in tree.body if tree.said[joint].part == part]
    sided = [_shallowest(tree, (j for j in named if tree.said[j].side == side)) for side in SIDES]
    unsided = sorted((j for j in named if tree.said[j].side is None), key=lambda j: tree.depth[j])
    pair = [joint for joint in sided if joint is not None] + unsided
    return pair[:2] if len(pair) >= 2 else None


def _sided(tree: _Tree, pair: list[int], head: int) -> tuple[dict[str, int], str]:
    """``pair`` by side, and what told them apart where their names do not both: the other's
    name, or the rest pose."""
    sides = [tree.said[joint].side for joint in pair]
    if sides[0] is None and sides[1] is not None:
        pair, sides = pair[::-1], sides[::-1]
    if sides[0] is not None and sides[1] != sides[0]:
        other = next(side for side in SIDES if side != sides[0])
        return {sides[0]: pair[0], other: pair[1]}, "" if sides[1] else "the other side's name"
    return dict(zip(SIDES, _left_first(tree, pair, head))), "the rest pose"


def _by_topology(tree: _Tree) -> dict[str, list[int]] | str:
    """The ankles (``foot``), wrists (``hand``) and head where names do not give them, from the
    hierarchy's long branches (:data:`LIMB`, :data:`NECK_OR_ARM`); or why there are none."""
    order = sorted(tree.body, key=lambda j: tree.depth[j])
    pelvis = next((j for j in order if len(tree.major_kids(j, LIMB)) >= 3), None)
    if pelvis is None:
        return "no joint where two legs and a spine part, by name or by the hierarchy"
    branches = tree.major_kids(pelvis, LIMB)
    chests = {
        branch: next((j for j in _breadth_first(tree, branch) if len(tree.major_kids(j, NECK_OR_ARM)) >= 3), None)
        for branch in branches
    }
    spine = [branch for branch in branches if chests[branch] is not None]
    legs = [branch for branch in branches if chests[branch] is None][:2]
    if len(spine) != 1 or len(legs) != 2:
        return "no two legs and a spine with two arms below one joint, by name or by the hierarchy"
    arms = tree.major_kids(chests[spine[0]], NECK_OR_ARM)[:2]
    ankles = [_nth_joint(tree, leg, 3) for leg in legs]
    wrists = [_wrist(tree, arm) for arm in arms]
    if None in ankles or None in wrists:
        return "legs or arms too short for a hip, knee and ankle, a shoulder, elbow and wrist"
    return {"foot": ankles, "hand": wrists, "head": [_head_of(tree, chests[spine[0]], wrists)]}


def _breadth_first(tree: _Tree, top: int) -> list[int]:
    order, at = [top], 0
    while at < len(order):
        order.extend(kid for kid in tree.kids[order[at]] if not tree.said[kid].helper)
        at += 1
    return order


def _nth_joint(tree: _Tree, top: int, count: int) -> int | None:
    """The ``count``-th joint down the main line from ``top``, joints on their parents passed over."""
    line = [j for j in tree.main_line(top) if not tree.on_parent(j) and not tree.said[j].skipped]
    return line[count - 1] if len(line) >= count else None


def _wrist(tree: _Tree, top: int) -> int | None:
    """Where an arm branching off at ``top`` branches into fingers (past a shoulder and an
    elbow), or else its fourth joint (clavicle, shoulder, elbow, wrist), or its third of three."""
    line = [j for j in tree.main_line(top) if not tree.said[j].skipped]
    branching = next((j for j in line[2:] if sum(not tree.said[k].helper for k in tree.kids[j]) > 1), None)
    if branching is not None:
        return branching
    return line[3] if len(line) >= 4 else line[2] if len(line) == 3 else None


def _head_of(tree: _Tree, chest: int, wrists: Iterable[int]) -> int | None:
    """The head above ``chest``: down the longest branch that leads to no wrist, the first joint
    that branches (into a face's joints), else the last one that is no chain's tip."""
    arms = {joint for wrist in wrists for joint in tree.ancestors(wrist)}
    kids = [kid for kid in tree.kids[chest] if kid not in arms and not tree.said[kid].helper]
    if not kids:
        return None
    line = [j for j in tree.main_line(max(kids, key=lambda kid: tree.reach[kid])) if not tree.said[j].end]
    return next((j for j in line if len(tree.kids[j]) > 1), line[-1]) if line else None


def _left_first(tree: _Tree, pair: list[int], head: int) -> list[int]:
    """The two joints of ``pair``, the character's left one first by the rest pose: left is
    up × forward, up from their midpoint to the head, forward where their children (toes) point,
    else the way a rig standing along that axis faces (:func:`~m2d2m.motion.rigs.up_axis.facing`)."""
    up = tree.rest[head] - tree.rest[pair].mean(axis=0)
    up /= np.linalg.norm(up) or 1.0
    ahead = [tree.rest[kid] - tree.rest[j] for j in pair for kid in tree.kids[j] if not tree.said[kid].skipped]
    forward = np.mean(ahead, axis=0) if ahead else np.zeros(3)
    forward -= up * np.dot(forward, up)
    if np.linalg.norm(forward) < tree.tolerance:
        forward = facing(axis_of(up))
    left = np.cross(up, forward)
    return pair if np.dot(tree.rest[pair[0]] - tree.rest[pair[1]], left) >= 0 else pair[::-1]


def _pelvis(tree: _Tree, ends: _Ends) -> int:
    """Where the legs and the head's path part, or the joint named pelvis or hips just above it."""
    meeting = tree.meet([*ends.ankles.values(), ends.head])
    return next((j for j in tree.ancestors(meeting) if tree.said[j].part == "pelvis"), meeting)


def _trunk(tree: _Tree, pelvis: int, chest: int, trunk: list[int]) -> dict[str, Found]:
    """spine1..3, the neck and the head along ``trunk`` (the path from the pelvis to the head):
    the spine up to the first joint named neck, or else up to the chest."""
    head = trunk[-1]
    between = [j for j in trunk[:-1] if j == chest or not (tree.on_parent(j) or tree.said[j].skipped)]
    named_neck = next((i for i, j in enumerate(between) if tree.said[j].part == "neck"), None)
    cut = named_neck if named_neck is not None else between.index(chest) + 1
    spine, necks = between[:cut], between[cut:]
    found = {"head": _found(tree, head, {"head"}, None, "the end of the path from the pelvis past the arms")}
    if necks:
        found["neck"] = _found(tree, necks[0], {"neck"}, None, "the first joint past the chest")
    else:
        found["neck"] = _derived(tree, (chest, head), "no neck: halfway from the chest to the head")
    along = "its place along the spine"
    if len(spine) >= 3:
        arc = np.cumsum(tree.length[spine])
        lower = min(range(len(spine) - 2), key=lambda i: abs(arc[i] / arc[-1] - SPINE1_AT))
        for ours, joint in zip(("spine1", "spine2", "spine3"), (spine[lower], spine[-2], spine[-1])):
            found[ours] = _found(tree, joint, {"spine"}, None, along)
    elif len(spine) == 2:
        found["spine1"] = _found(tree, spine[0], {"spine"}, None, along)
        found["spine2"] = _derived(tree, spine, "two spine joints: halfway between them")
        found["spine3"] = _found(tree, spine[1], {"spine"}, None, along)
    elif len(spine) == 1:
        found["spine1"] = _derived(tree, (pelvis, spine[0]), "one spine joint: halfway to it from the pelvis")
        found["spine2"] = _derived(tree, (pelvis, spine[0], spine[0]), "one spine joint: 2/3 of the way to it")
        found["spine3"] = _found(tree, spine[0], {"spine"}, None, "the one spine joint")
    else:
        neck = found["neck"].theirs
        for ours, (low, high) in (("spine1", (2, 1)), ("spine2", (1, 1)), ("spine3", (1, 2))):
            joints = (tree.names[pelvis],) * low + neck * high
            found[ours] = Found(joints, DERIVED, f"no spine joint: {high}/{low + high} of the way to the neck")
    return found


# A limb's roles, counted back from its end: (role, the parts its name may say, the parts that pick
# a joint for it by name). The shoulder is picked by "upper arm" names only, as "shoulder" is
# Mixamo's clavicle; where none is so named, the joint above the elbow is the shoulder (CMU's).
_LEG = (("knee", {"shin"}, {"shin"}), ("hip", {"thigh"}, {"thigh"}))
_ARM = (
    ("elbow", {"forearm"}, {"forearm"}),
    ("shoulder", {"upperarm", "shoulder"}, {"upperarm"}),
    ("collar", {"clavicle", "shoulder"}, {"clavicle", "shoulder"}),
)


def _leg(tree: _Tree, side: str, pelvis: int, ends: _Ends) -> dict[str, Found]:
    """A leg's hip and knee above its ankle, and the ankle."""
    ankle = ends.ankles[side]
    line = [
        j
        for j in tree.path(pelvis, ankle)[:-1]
        if not (tree.on_parent(j) or tree.said[j].skipped or tree.said[j].part in ("pelvis", "spine"))
    ]
    return _limb(tree, side, line, _LEG, ankle, "ankle", {"foot"}, ends.sides_by)


def _arm(tree: _Tree, side: str, chest: int, ends: _Ends) -> dict[str, Found]:
    """An arm's collar, shoulder and elbow above its wrist, and the wrist: the collar is the
    clavicle where it stands off the chest, else halfway from it (or the chest) to the shoulder."""
    wrist = ends.wrists[side]
    line = [j for j in tree.path(chest, wrist)[:-1] if not tree.said[j].skipped]
    found = _limb(tree, side, line, _ARM, wrist, "wrist", {"hand"}, ends.sides_by)
    collar, shoulder = found.get(f"{side}_collar"), found[f"{side}_shoulder"]
    if shoulder.how == MISSING:
        found[f"{side}_collar"] = Found((), MISSING, "no shoulder")
    elif collar is None:
        found[f"{side}_collar"] = Found(
            (tree.names[chest], *shoulder.theirs), DERIVED, "no clavicle: halfway from the chest to the shoulder"
        )
    elif tree.on_parent(tree.names.index(collar.theirs[0])):
        found[f"{side}_collar"] = Found(
            collar.theirs + shoulder.theirs, DERIVED, "the clavicle sits on the chest: halfway from it to the shoulder"
        )
    return found


def _limb(
    tree: _Tree,
    side: str,
    line: list[int],
    roles: tuple[tuple[str, set[str], set[str]], ...],
    end: int,
    end_role: str,
    end_parts: set[str],
    sides_by: str,
) -> dict[str, Found]:
    """A limb's joints of ours: its ``end`` and ``roles`` along ``line`` (from the trunk down to
    just above the end), each role the first joint named for it above the one placed before,
    else the joint just above that one; missing where the line runs out (a collar may).
    ``sides_by``: what told the limbs' sides apart, where names did not."""
    sided = f"; its side by {sides_by}" if sides_by else ""
    guess = "its place along the limb" + sided
    found = {f"{side}_{end_role}": _found(tree, end, end_parts, side, "the end of the limb" + sided)}
    above = len(line)
    for role, parts, naming in roles:
        named = next((i for i in range(above) if tree.said[line[i]].part in naming), None)
        above = named if named is not None else above - 1
        if above < 0:
            if role != "collar":
                found[f"{side}_{role}"] = Found((), MISSING, f"too few joints above the {end_role}")
            continue
        found[f"{side}_{role}"] = _found(tree, line[above], parts, side, guess)
    return found


def _toe(tree: _Tree, found: dict[str, Found], side: str, ankle: int) -> Found:
    """Our foot (the ball of the foot) on a leg: the joint named toe nearest below the ankle (or
    one named foot, below SMPL's ankle), else the ankle's one child, else a point ahead of it."""
    below = _breadth_first(tree, ankle)[1:]
    named = _shallowest(tree, (j for j in below if tree.said[j].part == "toe"))
    named = named if named is not None else _shallowest(tree, (j for j in below if tree.said[j].part == "foot"))
    kids = [kid for kid in tree.kids[ankle] if not tree.said[kid].skipped and not tree.on_parent(kid)]
    if named is not None:
        return Found((tree.names[named],), NAME)
    if len(kids) == 1:
        return Found((tree.names[kids[0]],), GUESSED, "the ankle's one child")
    return _ahead(tree, found, side, ankle)


def _ahead(tree: _Tree, found: dict[str, Found], side: str, ankle: int) -> Found:
    """Our foot on a rig without toes: a point fixed to the ankle, :data:`FOOT_LENGTH` of the leg
    ahead of it, along its End Site where that points forward, else forward and
    :data:`FOOT_DROP` down; forward is left × up of the rest pose (where the hips are apart)."""

    def at(ours: str) -> np.ndarray:
        return tree.rest[[tree.names.index(name) for name in found[ours].theirs]].mean(axis=0)

    up = at("head") - at("pelvis")
    up /= np.linalg.norm(up)
    forward = np.cross(at("left_hip") - at("right_hip"), up)
    forward = forward / np.linalg.norm(forward) if np.linalg.norm(forward) > tree.tolerance else facing(axis_of(up))
    hip, knee = at(f"{side}_hip"), at(f"{side}_knee")
    leg = np.linalg.norm(knee - hip) + np.linalg.norm(tree.rest[ankle] - knee)
    site = tree.end_sites.get(ankle)
    if site is not None and np.dot(site, forward) > 0.5 * np.linalg.norm(site):
        direction, why = site / np.linalg.norm(site), "no toe: ahead of the ankle, along its End Site"
    else:
        direction, why = np.cos(FOOT_DROP) * forward - np.sin(FOOT_DROP) * up, "no toe: ahead of the ankle"
    offset = tuple(round(float(v), 4) for v in direction * FOOT_LENGTH * leg)
    return Found((tree.names[ankle],), DERIVED, why, offset)
