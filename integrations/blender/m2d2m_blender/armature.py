"""The armature in Blender: its rest pose as the rig to send, and a clip from the server written
as keys of its pose bones (a new action, or a span of one replaced by an edit), with the clip's
record and the timeline's markers. The arithmetic is :mod:`.bvh`'s; this module is what touches ``bpy``."""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import bpy
from mathutils import Quaternion

from .bvh import Bone, Clip, Matrix, bvh_names, pose_basis, root_location
from .timeline import Span, marker_name, spans

RECORD = "m2d2m"  # the custom property of an action made here: what the server made it from, as JSON


@dataclass(frozen=True)
class Rig:
    """The bones of an armature sent as the rig: parents first, their BVH names, and the bones
    left out (those of other trees than the largest: a BVH has one root)."""

    bones: list[Bone]
    bone_of: dict[str, str]  # BVH joint name -> bone name
    left_out: list[str]


def rig_of(armature: bpy.types.Object) -> Rig:
    """The armature's largest tree of bones at rest, in armature space; a ValueError when it has none."""
    roots = [bone for bone in armature.data.bones if bone.parent is None]
    if not roots:
        raise ValueError(f"the armature {armature.name!r} has no bones")
    root = max(roots, key=lambda bone: len(bone.children_recursive))
    order, index = [root], {root.name: 0}
    for bone in order:  # breadth first: every parent before its children
        for child in bone.children:
            index[child.name] = len(order)
            order.append(child)
    bones = [
        Bone(
            bone.name,
            -1 if bone.parent is None else index[bone.parent.name],
            tuple(bone.head_local),
            tuple(bone.tail_local),
        )
        for bone in order
    ]
    left_out = [bone.name for bone in armature.data.bones if bone.name not in index]
    return Rig(bones, dict(zip(bvh_names([bone.name for bone in bones]), [bone.name for bone in bones])), left_out)


def new_action(armature: bpy.types.Object, name: str) -> bpy.types.Action:
    """A new action on the armature; the one it had is kept in the file (a fake user), not replaced."""
    animation = armature.animation_data or armature.animation_data_create()
    if animation.action is not None:
        animation.action.use_fake_user = True
    action = bpy.data.actions.new(name)
    animation.action = action
    return action


def write_keys(
    armature: bpy.types.Object, action: bpy.types.Action, clip: Clip, rig: Rig, start: int, frames: Iterable[int]
) -> int:
    """Key the armature's bones in ``action`` with ``frames`` of ``clip`` (its indices), each at
    scene frame ``start`` + index, replacing any key there and keeping every other; the root bone
    also keyed in place. The number of frames keyed."""
    frames = list(frames)
    bones = armature.pose.bones
    joints = [(joint, rig.bone_of.get(name)) for joint, name in enumerate(clip.names)]
    missing = [clip.names[joint] for joint, bone in joints if bone is None or bone not in bones]
    if missing:
        raise ValueError(f"the clip has joints the armature lacks ({', '.join(missing[:5])}); generate it again")
    rests: dict[str, Matrix] = {bone: _rest(bones[bone]) for _, bone in joints}
    root_bone = bones[joints[0][1]]
    keys: dict[tuple[str, str, int], list[tuple[float, float]]] = {}  # (bone, property, index) -> (frame, value)
    previous: dict[str, Quaternion] = {}
    euler: dict[str, Any] = {}
    for frame in frames:
        position, rotations = clip.pose(frame)
        at = float(start + frame)
        for joint, bone in joints:
            pose_bone = bones[bone]
            quaternion = Quaternion(pose_basis(rests[bone], rotations[joint]))
            if bone in previous and quaternion.dot(previous[bone]) < 0:  # the same turn, no flip between keys
                quaternion.negate()
            previous[bone] = quaternion
            if pose_bone.rotation_mode in ("QUATERNION", "AXIS_ANGLE"):
                pose_bone.rotation_mode = "QUATERNION"  # an axis and angle do not interpolate as one turn
                values, attribute = tuple(quaternion), "rotation_quaternion"
            else:  # the bone's own Euler order, each key the nearest to the one before (no 360° jumps)
                euler[bone] = quaternion.to_euler(pose_bone.rotation_mode, *([euler[bone]] if bone in euler else []))
                values, attribute = tuple(euler[bone]), "rotation_euler"
            for index, value in enumerate(values):
                keys.setdefault((bone, attribute, index), []).append((at, value))
        location = root_location(rests[root_bone.name], tuple(root_bone.bone.head_local), position)
        for index, value in enumerate(location):
            keys.setdefault((root_bone.name, "location", index), []).append((at, value))
    first, last = (start + min(frames), start + max(frames)) if frames else (0, -1)
    for (bone, attribute, index), points in keys.items():
        path = bones[bone].path_from_id(attribute)
        curve = action.fcurves.find(path, index=index) or action.fcurves.new(path, index=index, action_group=bone)
        for point in reversed(list(curve.keyframe_points)):
            if first <= point.co[0] <= last:
                curve.keyframe_points.remove(point, fast=True)
        for at, value in points:
            curve.keyframe_points.insert(at, value, options={"FAST"})
        curve.update()
    return len(frames)


def _rest(pose_bone: bpy.types.PoseBone) -> Matrix:
    rest = pose_bone.bone.matrix_local.to_3x3().normalized()
    return tuple(tuple(row) for row in rest)  # type: ignore[return-value]


def record_of(action: bpy.types.Action | None) -> dict[str, Any] | None:
    """What the server made ``action`` from (:func:`set_record`), or None for an action not made here."""
    if action is None or RECORD not in action:
        return None
    return json.loads(action[RECORD])


def set_record(action: bpy.types.Action, record: dict[str, Any]) -> None:
    action[RECORD] = json.dumps(record)


def clip_spans(record: dict[str, Any]) -> list[Span]:
    return spans(record["actions"], record["start"])


def mark(scene: bpy.types.Scene, old: list[Span], new: list[Span]) -> None:
    """The timeline's markers for the clip's actions: those of its ``old`` actions taken away, one
    at each ``new`` action's first frame named by its text."""
    for span in old:
        for marker in list(scene.timeline_markers):
            if marker.frame == span.first and marker.name == marker_name(span.text):
                scene.timeline_markers.remove(marker)
    for span in new:
        scene.timeline_markers.new(marker_name(span.text), frame=span.first)
