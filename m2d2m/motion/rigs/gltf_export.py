"""A motion on someone else's rig (:mod:`m2d2m.motion.rigs.retarget`) as a GLB, and as FBX made from it,
for the engines that import no BVH, Unity's and Unreal's (issue 52 §3; docs/generation.md, "On
your own rig"). The Khronos glTF 2.0 specification is cited as "§".

* A rig that came as a glTF character (:mod:`m2d2m.motion.files.gltf_rig`) gets its own file back, its
  nodes, meshes, skins, materials and animations as they were, with the clip's animations added
  as :func:`m2d2m.motion.files.gltf.save_glb` names them (``"clip"``, then one per action), keying its
  joint nodes: the user gets their character moving (its own animations come first). With ``M`` a node's rest transform in the
  scene and ``D_j(t)`` the rigid motion carrying joint ``j`` from its rest place to its place at
  ``t`` (its world rotation about its rest position, then moved there), joint ``j``'s node takes
  ``M_parent⁻¹ · D_a(t)⁻¹ · D_j(t) · M_j`` from its parent node, ``a`` the nearest joint above it
  (none: the identity), so that every vertex it skins moves as the joint does (§3.7.3). Its
  translation stays its rest one, but the root's, and its scale its own.
* A rig that came as a BVH gets a GLB as our own skeleton's is: a node per joint at its OFFSET in
  metres (§3.4), keyed rotations and root path, and the same body of boxes skinned to it. Without
  a skin Blender imports the nodes as empties, not as an armature, so its FBX would have no
  skeleton for an engine to take, and a viewer would show nothing.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pygltflib as gl

from m2d2m.motion.files.bvh_reader import rest_positions
from m2d2m.motion.files.gltf import (
    Blob,
    add_body,
    add_joint_nodes,
    animate,
    checked_segments,
    clip_extras,
    fbx_of_glb,
    new_gltf,
    write_glb,
)
from m2d2m.motion.files.gltf_rig import joint_name, load_gltf, local_matrix, node_parents, rest_world
from m2d2m.motion.representation.rotations import matrix_to_quat
from m2d2m.motion.representation.skeleton import T2M, Skeleton
from m2d2m.motion.rigs.retarget import RigMotion, Target

# a node's keys: node → (T, 3) translations, node → (T, 3, 3) rotations
Tracks = tuple[dict[int, np.ndarray], dict[int, np.ndarray]]


def save_rig_glb(
    path: str | Path,
    target: Target,
    joints: np.ndarray,
    fps: float | None = None,
    segments: Sequence[tuple[int, int, str]] = (),
    skeleton: Skeleton = T2M,
    closing_key: bool = False,
) -> Path:
    """Our joints (T, J, 3) retargeted onto ``target`` as a GLB (written whole or not at all): its
    character's file animated, or a skinned skeleton of its BVH's; keys at ``frame / fps``
    seconds, animations, a loop's ``closing_key`` and scene ``extras`` as
    :func:`~m2d2m.motion.files.gltf.save_glb` has them. ValueError in one line for a character whose
    data are not all in its file."""
    joints = skeleton.check_joints(joints)
    fps = float(skeleton.fps if fps is None else fps)
    frames = len(joints) - closing_key
    segments = checked_segments(segments, frames)
    motion = target.retargeted(joints, skeleton)
    if target.character is None:
        gltf, blob, tracks = _skeleton_of(target, motion, skeleton)
    else:
        gltf, blob, tracks = _character_of(target, motion)
    animate(gltf, blob, fps, segments, *tracks, closing_key)
    scene = gltf.scenes[gltf.scene or 0]
    scene.extras = {**(scene.extras or {}), **clip_extras("rig", fps, frames, segments)}
    return write_glb(gltf, blob, path)


def save_rig_fbx(
    path: str | Path,
    target: Target,
    joints: np.ndarray,
    fps: float | None = None,
    segments: Sequence[tuple[int, int, str]] = (),
    skeleton: Skeleton = T2M,
    timeout_s: float = 300.0,
    closing_key: bool = False,
) -> Path:
    """Our joints on ``target`` as FBX, by Blender from the GLB of :func:`save_rig_glb`
    (:func:`~m2d2m.motion.files.gltf.fbx_of_glb`, whose errors it raises)."""
    fps = float(skeleton.fps if fps is None else fps)
    return fbx_of_glb(
        path, fps, lambda glb: save_rig_glb(glb, target, joints, fps, segments, skeleton, closing_key), timeout_s
    )


def _skeleton_of(target: Target, motion: RigMotion, skeleton: Skeleton) -> tuple[gl.GLTF2, Blob, Tracks]:
    """A new glTF of the rig's joints in metres with a body skinned to them, and their keys; a
    rig standing along another axis than +Y (a Z-up BVH) turned to stand along glTF's +Y (§3.4):
    its offsets and root path turned by R, each local rotation L made R L R⁻¹."""
    rig, root_path, local = motion.rig, motion.root, motion.local  # in metres
    if target.bind.turned:
        turn = target.bind.turn
        rig = replace(rig, offsets=rig.offsets @ turn.T)
        root_path, local = root_path @ turn.T, turn @ local @ turn.T
    root = int(np.flatnonzero(rig.parents < 0)[0])
    translations = rig.offsets.copy()
    translations[root] = root_path[0]
    gltf = new_gltf()
    blob = Blob(gltf)
    add_joint_nodes(gltf, rig.names, rig.parents, translations)
    head = target.joint_map.sources.get(skeleton.joint_names[skeleton.head_joint], ())
    head_joint = rig.names.index(head[0]) if len(head) == 1 and head[0] in rig.names else None
    bones = np.flatnonzero(rig.parents >= 0)  # a rig's parents come first
    body = add_body(gltf, blob, rig.parents, bones, rest_positions(rig.parents, translations), head_joint, "rig")
    gltf.scenes = [gl.Scene(name="m2d2m", nodes=[root, body])]
    gltf.scene = 0
    return gltf, blob, ({root: root_path}, dict(enumerate(np.moveaxis(local, 1, 0))))


def _character_of(target: Target, motion: RigMotion) -> tuple[gl.GLTF2, Blob, Tracks]:
    """The character's glTF, its binary buffer open for more, and its joint nodes' keys."""
    file = target.character
    gltf = load_gltf(file)
    if len(gltf.buffers) > 1 or any(image.uri and not image.uri.startswith("data:") for image in gltf.images):
        raise ValueError(f"{file}: its data are in several files; export the character as one GLB to animate it")
    gltf.convert_buffers(gl.BufferFormat.BINARYBLOB)  # a .gltf's buffer (data URI or .bin) into the GLB's
    blob = Blob(gltf)
    blob.data = bytearray(gltf.binary_blob() or b"")
    named = {joint_name(gltf, node): node for node in gltf.skins[0].joints}
    nodes = [named[name] for name in target.rig.names]
    parent_node = node_parents(gltf)
    world = rest_world(gltf)

    rotations, positions = motion.pose()
    frames = len(rotations)
    carry = np.tile(np.eye(4), (frames, len(nodes), 1, 1))  # D_j(t): rest place → place at t
    carry[..., :3, :3] = rotations
    carry[..., :3, 3] = (
        positions / target.metres_per_unit - (rotations @ target.rig.rest_positions()[:, :, None])[..., 0]
    )
    translations, turns = {}, {}
    for joint, node in enumerate(nodes):
        parent, above = target.rig.parents[joint], parent_node.get(node)
        moved = carry[:, joint] @ world[node]
        if parent >= 0:
            moved = _rigid_inverse(carry[:, parent]) @ moved
        if above is not None:
            moved = np.linalg.inv(world[above]) @ moved
        rest = local_matrix(gltf.nodes[node])
        scale = np.linalg.norm(rest[:3, :3], axis=0)
        turns[node] = _nearest_rotation(moved[:, :3, :3] / scale)
        if parent < 0:
            translations[node] = moved[:, :3, 3]
        if gltf.nodes[node].matrix is not None:  # an animated node holds T, R, S, not a matrix (§3.5.3)
            gltf.nodes[node].matrix = None
            gltf.nodes[node].translation = rest[:3, 3].tolist()
            gltf.nodes[node].rotation = matrix_to_quat(_nearest_rotation(rest[:3, :3] / scale))[[1, 2, 3, 0]].tolist()
            gltf.nodes[node].scale = scale.tolist()
    return gltf, blob, (translations, turns)


def _rigid_inverse(transforms: np.ndarray) -> np.ndarray:
    """The inverses of rigid transforms (..., 4, 4): the rotation transposed, the translation undone."""
    inverse = np.zeros_like(transforms)
    turn = np.swapaxes(transforms[..., :3, :3], -1, -2)
    inverse[..., :3, :3] = turn
    inverse[..., :3, 3] = -(turn @ transforms[..., :3, 3:])[..., 0]
    inverse[..., 3, 3] = 1.0
    return inverse


def _nearest_rotation(matrices: np.ndarray) -> np.ndarray:
    """The rotations (..., 3, 3) nearest matrices that are rotations up to rounding (a scale of
    0.9999999 left in a character's rest pose): the orthogonal factor of their polar decomposition."""
    u, _, vt = np.linalg.svd(matrices)
    return u @ vt
