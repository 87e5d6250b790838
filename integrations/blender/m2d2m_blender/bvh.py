"""The armature as the rig the server takes (a one-frame BVH of its rest pose) and the clip the
server sends back on it (a BVH of the same joints), turned into Blender's pose-bone keys.

Pure Python, no ``bpy``: Blender's own BVH importer and exporter are operators that make or read
an armature object, where the add-on needs text to send and keys to put on the armature the user
chose. Keeping the arithmetic here lets it be tested outside Blender (tests/test_blender_addon.py).

Axes: Blender's armature space is Z-up, BVH (and m2d2m) Y-up; a point (x, y, z) of Blender is
(x, z, -y) in the BVH, as Blender's own BVH exporter writes it (forward -Z, up Y).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

Vector = tuple[float, float, float]
Matrix = tuple[Vector, Vector, Vector]  # rows; a rotation acting on column vectors
Quaternion = tuple[float, float, float, float]  # w, x, y, z: mathutils' order

TO_BVH: Matrix = ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0))  # Blender (x, y, z) -> BVH (x, z, -y)
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROOT_CHANNELS = "Xposition Yposition Zposition Zrotation Yrotation Xrotation"
JOINT_CHANNELS = "Zrotation Yrotation Xrotation"


class BvhError(ValueError):
    """A BVH the add-on cannot read, in one sentence."""


@dataclass(frozen=True)
class Bone:
    """One bone of the armature at rest, in armature space (Blender's axes, its units): its name,
    its parent's index (-1: none; parents come before their children), its head and tail."""

    name: str
    parent: int
    head: Vector
    tail: Vector


@dataclass(frozen=True)
class Clip:
    """A BVH read: its joints' names in file order, their parents, each joint's channels, the
    frames' channel values and the seconds between frames."""

    names: list[str]
    parents: list[int]
    channels: list[list[str]]
    frames: list[list[float]]
    frame_time: float

    def pose(self, frame: int) -> tuple[Vector, list[Matrix]]:
        """Frame ``frame``: the root's position (the file's axes and units; a root without
        position channels stands at the origin) and every joint's rotation from its parent's."""
        values = iter(self.frames[frame])
        root: list[float] = [0.0, 0.0, 0.0]
        rotations = []
        for joint, channels in enumerate(self.channels):
            rotation = IDENTITY
            for channel in channels:
                value = next(values)
                if channel in ROTATION_CHANNELS:  # BVH: R = R1 · R2 · R3 in the order the channels are listed
                    rotation = multiply(rotation, axis_rotation(channel[0], math.radians(value)))
                elif joint == 0:
                    root[POSITION_CHANNELS.index(channel)] = value
            rotations.append(rotation)
        return (root[0], root[1], root[2]), rotations


IDENTITY: Matrix = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


def bvh_names(names: Sequence[str]) -> list[str]:
    """Each bone's name as a BVH joint's: a BVH names a joint with one word, so whitespace becomes
    ``_`` (``Bip01 L Thigh`` is ``Bip01_L_Thigh``), and a name made twice so is numbered."""
    written: list[str] = []
    for name in names:
        word = re.sub(r"\s+", "_", name.strip()) or "bone"
        candidate, count = word, 1
        while candidate in written:
            count += 1
            candidate = f"{word}.{count:03d}"
        written.append(candidate)
    return written


def rest_bvh(bones: Sequence[Bone]) -> str:
    """The armature's rest pose as a BVH of one frame (every rotation zero), in the BVH's Y-up
    axes: each bone a joint at its head, a bone with no children ending in an End Site at its tail.
    The root's OFFSET is where it stands, so a character standing on the floor tells the server
    where its floor is (docs/generation.md, "How well it lands")."""
    if not bones or bones[0].parent != -1 or any(bone.parent < 0 for bone in bones[1:]):
        raise ValueError("the bones must be one tree, its root first")
    names = bvh_names([bone.name for bone in bones])
    children: list[list[int]] = [[] for _ in bones]
    for index, bone in enumerate(bones[1:], start=1):
        children[bone.parent].append(index)
    lines = ["HIERARCHY"]

    def write(joint: int, depth: int) -> None:
        pad = "\t" * depth
        bone = bones[joint]
        start = bones[bone.parent].head if bone.parent >= 0 else (0.0, 0.0, 0.0)
        kind = "ROOT" if bone.parent < 0 else "JOINT"
        lines.append(f"{pad}{kind} {names[joint]}")
        lines.append(f"{pad}{{")
        lines.append(f"{pad}\tOFFSET {_triple(to_bvh(_minus(bone.head, start)))}")
        lines.append(
            f"{pad}\tCHANNELS {6 if bone.parent < 0 else 3} {ROOT_CHANNELS if bone.parent < 0 else JOINT_CHANNELS}"
        )
        for child in children[joint]:
            write(child, depth + 1)
        if not children[joint]:
            end_site = _triple(to_bvh(_minus(bone.tail, bone.head)))
            lines.extend([f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET {end_site}", f"{pad}\t}}"])
        lines.append(f"{pad}}}")

    write(0, 0)
    root = to_bvh(bones[0].head)
    lines += [
        "MOTION",
        "Frames: 1",
        "Frame Time: 0.0333333",
        f"{_triple(root)} 0 0 0 " + " ".join(["0 0 0"] * (len(bones) - 1)),
    ]
    return "\n".join(lines).rstrip() + "\n"


def read_bvh(text: str) -> Clip:
    """A BVH file's joints, channels and frames; a BvhError in one sentence for text that is none."""
    tokens = text.split()
    if not tokens or tokens[0] != "HIERARCHY":
        raise BvhError("the server's answer is no BVH (it does not start with HIERARCHY)")
    names: list[str] = []
    parents: list[int] = []
    channels: list[list[str]] = []
    stack: list[int] = []
    at, in_end_site = 1, False
    try:
        while tokens[at] != "MOTION":
            token = tokens[at]
            if token in ("ROOT", "JOINT"):
                names.append(tokens[at + 1])
                parents.append(stack[-1] if stack else -1)
                channels.append([])
                at += 2
            elif token == "End":
                in_end_site, at = True, at + 2
            elif token == "{":
                if not in_end_site:
                    stack.append(len(names) - 1)
                at += 1
            elif token == "}":
                if in_end_site:
                    in_end_site = False
                else:
                    stack.pop()
                at += 1
            elif token == "OFFSET":
                at += 4
            elif token == "CHANNELS":
                count = int(tokens[at + 1])
                channels[-1] = tokens[at + 2 : at + 2 + count]
                at += 2 + count
            else:
                raise BvhError(f"the BVH has {token!r} where its hierarchy was expected")
        count = int(tokens[at + 2])
        frame_time = float(tokens[at + 5])
        values = [float(value) for value in tokens[at + 6 :]]
    except (IndexError, ValueError) as error:
        raise BvhError(f"the BVH is cut short or malformed ({error})") from error
    width = sum(len(joint) for joint in channels)
    if len(values) != count * width:
        raise BvhError(f"the BVH says {count} frames of {width} values but holds {len(values)} values")
    frames = [values[i * width : (i + 1) * width] for i in range(count)]
    return Clip(names, parents, channels, frames, frame_time)


def pose_basis(rest: Matrix, local: Matrix) -> Quaternion:
    """A pose bone's rotation (its ``rotation_quaternion``) that turns it as a BVH joint's rotation
    from its parent ``local`` (BVH axes) turns the joint: Blender poses a bone in its own rest
    frame (``rest``: its ``matrix_local``'s rotation, armature space), and a BVH joint at rest is
    unturned, so the bone's rotation is ``local`` seen from its rest frame, rest⁻¹ · local · rest,
    with ``local`` brought to Blender's axes first."""
    in_blender = multiply(transpose(TO_BVH), multiply(local, TO_BVH))
    return to_quaternion(multiply(transpose(rest), multiply(in_blender, rest)))


def root_location(rest: Matrix, head: Vector, position: Vector) -> Vector:
    """The root bone's ``location`` that puts its head at the BVH root's ``position`` (BVH axes):
    the move from its rest head, in the bone's rest frame."""
    return apply(transpose(rest), _minus(from_bvh(position), head))


def to_bvh(point: Vector) -> Vector:
    return apply(TO_BVH, point)


def from_bvh(point: Vector) -> Vector:
    return apply(transpose(TO_BVH), point)


def axis_rotation(axis: str, angle: float) -> Matrix:
    """The rotation by ``angle`` radians about axis ``axis`` (``X``, ``Y`` or ``Z``)."""
    c, s = math.cos(angle), math.sin(angle)
    if axis == "X":
        return ((1.0, 0.0, 0.0), (0.0, c, -s), (0.0, s, c))
    if axis == "Y":
        return ((c, 0.0, s), (0.0, 1.0, 0.0), (-s, 0.0, c))
    return ((c, -s, 0.0), (s, c, 0.0), (0.0, 0.0, 1.0))


def multiply(a: Matrix, b: Matrix) -> Matrix:
    rows = tuple(tuple(sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)) for i in range(3))
    return rows  # type: ignore[return-value]


def transpose(a: Matrix) -> Matrix:
    return ((a[0][0], a[1][0], a[2][0]), (a[0][1], a[1][1], a[2][1]), (a[0][2], a[1][2], a[2][2]))


def apply(a: Matrix, v: Vector) -> Vector:
    return (
        a[0][0] * v[0] + a[0][1] * v[1] + a[0][2] * v[2],
        a[1][0] * v[0] + a[1][1] * v[1] + a[1][2] * v[2],
        a[2][0] * v[0] + a[2][1] * v[1] + a[2][2] * v[2],
    )


def to_quaternion(m: Matrix) -> Quaternion:
    """A rotation matrix as a unit quaternion (w, x, y, z), w ≥ 0 (Shepperd's method: from the
    largest of the trace and the diagonal, so it stays exact near 180°)."""
    trace = m[0][0] + m[1][1] + m[2][2]
    if trace > max(m[0][0], m[1][1], m[2][2]):
        s = 2.0 * math.sqrt(1.0 + trace)
        q = (0.25 * s, (m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s)
    elif m[0][0] >= m[1][1] and m[0][0] >= m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[0][0] - m[1][1] - m[2][2])
        q = ((m[2][1] - m[1][2]) / s, 0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s)
    elif m[1][1] >= m[2][2]:
        s = 2.0 * math.sqrt(1.0 + m[1][1] - m[0][0] - m[2][2])
        q = ((m[0][2] - m[2][0]) / s, (m[0][1] + m[1][0]) / s, 0.25 * s, (m[1][2] + m[2][1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2][2] - m[0][0] - m[1][1])
        q = ((m[1][0] - m[0][1]) / s, (m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, 0.25 * s)
    norm = math.sqrt(sum(c * c for c in q))
    sign = 1.0 if q[0] >= 0 else -1.0
    return (sign * q[0] / norm, sign * q[1] / norm, sign * q[2] / norm, sign * q[3] / norm)


def _minus(a: Vector, b: Vector) -> Vector:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def _triple(v: Vector) -> str:
    return " ".join(f"{c:.6f}" for c in v)
