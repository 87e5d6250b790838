"""What a rig joint's name says: its side and the part of the body it belongs to, in the naming
conventions characters are exported with (docs/generation.md, "On your own rig").

A name is cut into words (``mixamorig:LeftUpLeg`` → left, up, leg; ``Bip01 L Thigh`` → bip, 01,
l, thigh; ``upper_arm.L`` → upper, arm, l; ``lShldrBend`` → l, shldr, bend), a namespace before
the last colon dropped (Mixamo's ``mixamorig:``, ``mixamorig1:``). The side is a word ``l``,
``left``, ``r`` or ``right`` anywhere in it, which covers ``Left``/``Right``, ``_L``/``_R``,
``.L``/``.R``, Biped's `` L `` and Daz's ``l``/``r`` prefixes. The part is read from the other
words run together (``upleg``, ``forearm``, ``toebase``) against patterns tried in order, in the
spirit of Unreal's IK Rig auto-characterization, which matches a skeleton's names against known
templates (dev.epicgames.com, the IKRigEditor API's ``FAutoCharacterizer``). Names only suggest: which joint of a
chain is which is decided by the chain (:mod:`m2d2m.motion.rigs.auto_map`), so an ambiguous word such
as "shoulder" (Mixamo's clavicle, CMU's upper arm) is its own part.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_WORDS = re.compile(r"[A-Z]+(?=[A-Z][a-z])|[A-Z]?[a-z]+|[A-Z]+|\d+")
_LEFT = {"l", "left", "lft"}
_RIGHT = {"r", "right", "rt", "rgt"}
# words that say nothing of the part: exporters' prefixes and suffixes
_NOISE = {"bip", "def", "org", "cc", "base", "joint", "jnt", "bone", "mixamorig", "b", "j"}
# a helper for animators, not a part of the body: IK targets, controls, props; their children too
_HELPER = {
    "ik", "ctrl", "control", "target", "pole", "prop", "weapon", "attach", "socket", "camera", "cam",
    "helper", "mch", "dummy", "null", "locator", "effector", "gun", "grip", "slot", "trajectory", "vb",
}  # fmt: skip
_END = {"end", "nub", "tip", "top", "site"}  # the tip of a chain (HeadTop_End, Toe0Nub): no joint of ours
_TWIST = {"twist", "roll", "share", "corrective", "jiggle"}  # a bone along a limb's bone, not a joint of it
_FINGER = re.compile(r"thumb|index|middle|ring|pinky|pinkie|finger|digit|carpal|inhand")

# (part, pattern of the name's words run together), the first that matches wins: "forearm"
# before "arm", "upperleg" before "leg"
_PARTS = (
    ("toe", r"toe|ball"),
    ("forearm", r"forearm|lowerarm|loarm|elbow|radius|ulna"),
    ("upperarm", r"upperarm|uparm|shldr|humerus|^arm"),
    ("shoulder", r"shoulder"),  # a clavicle (Mixamo, Unity, Bandai Namco) or an upper arm (CMU, SMPL)
    ("clavicle", r"clavicle|collar|clav"),
    ("hand", r"hand|wrist"),
    ("thigh", r"upleg|upperleg|thigh|femur"),
    ("shin", r"lowerleg|loleg|knee|shin|calf|tibia|^leg"),
    ("foot", r"foot|ankle"),
    ("pelvis", r"^hips?$|pelvis"),
    ("spine", r"spine|chest|abdomen|torso|back|waist|belly|thorax|ribcage|lumbar"),
    ("neck", r"neck"),
    ("head", r"head"),
)
SIDED = {"toe", "forearm", "upperarm", "shoulder", "clavicle", "hand", "thigh", "shin", "foot"}


@dataclass(frozen=True)
class BoneName:
    """What one joint's name says: ``side`` (left, right or None), ``part`` (a part of
    :data:`_PARTS`, or None for a joint that is none), and whether it is a ``helper`` (an IK
    target, a prop: it and its children are no part of the body), an ``end`` (a chain's tip), a
    ``twist`` bone or a ``finger``, none of which is a part."""

    side: str | None
    part: str | None
    helper: bool = False
    end: bool = False
    twist: bool = False
    finger: bool = False

    @property
    def skipped(self) -> bool:
        """Whether the joint stands for none of ours even where a chain runs through it."""
        return self.helper or self.end or self.twist or self.finger


def words(name: str) -> list[str]:
    """The lower-case words of a joint's name, its namespace (before the last colon) dropped."""
    return [word.lower() for word in _WORDS.findall(name.rsplit(":", 1)[-1])]


def read_name(name: str) -> BoneName:
    """What ``name`` says of its joint's side and part."""
    said = words(name)
    left, right = bool(_LEFT & set(said)), bool(_RIGHT & set(said))
    side = "left" if left and not right else "right" if right and not left else None
    body = "".join(w for w in said if w not in _LEFT | _RIGHT | _NOISE and not w.isdigit())
    flags = {
        "helper": bool(_HELPER & set(said)),
        "end": bool(_END & set(said)),
        "twist": bool(_TWIST & set(said)),
        "finger": bool(_FINGER.search(body)),
    }
    part = None if any(flags.values()) else next((part for part, pattern in _PARTS if re.search(pattern, body)), None)
    if part == "pelvis" and side is not None:  # CMU's LeftHip is a thigh; Rigify's pelvis.L a hip bone
        part = "thigh" if body.startswith("hip") else None
    return BoneName(side if part in SIDED or part is None else None, part, **flags)
