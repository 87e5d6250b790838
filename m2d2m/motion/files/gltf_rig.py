"""A character's skeleton read from a glTF 2.0 file (``.glb`` or ``.gltf``), so that a motion can be
retargeted to it as to a BVH rig (:mod:`m2d2m.motion.rigs.retarget`; docs/generation.md, "On your own
rig").

The skeleton is the first skin's joints (the Khronos glTF 2.0 specification, §3.7.3 "Skins":
``skin.joints`` lists the nodes that are joints; a joint's parent is its nearest ancestor node that
is a joint too). Its rest pose is the pose the nodes stand in, their translation, rotation and
scale (or matrix, §3.5.3) composed from the scene's root down, ancestors that are not joints (an
"Armature" node) included, with no animation applied. The result is a :class:`BvhClip` of one
frame whose OFFSETs are those rest positions' differences, every rotation zero: the same skeleton
in BVH's terms, which the joint maps and the retargeting read. glTF's units are metres and +Y is up
(§3.4).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pygltflib as gl

from m2d2m.motion.files.bvh_reader import BvhClip, BvhError
from m2d2m.motion.representation.rotations import quat_to_matrix

GLTF_SUFFIXES = (".glb", ".gltf")


def local_matrix(node: gl.Node) -> np.ndarray:
    """The node's 4×4 transform from its parent's frame (§3.5.3: ``matrix``, column-major, or T·R·S)."""
    if node.matrix is not None:
        return np.asarray(node.matrix, dtype=np.float64).reshape(4, 4).T
    matrix = np.eye(4)
    x, y, z, w = node.rotation if node.rotation is not None else (0.0, 0.0, 0.0, 1.0)
    scale = node.scale if node.scale is not None else (1.0, 1.0, 1.0)
    matrix[:3, :3] = quat_to_matrix(np.array([w, x, y, z], dtype=np.float64)) * np.asarray(scale)
    matrix[:3, 3] = node.translation if node.translation is not None else (0.0, 0.0, 0.0)
    return matrix


def node_parents(gltf: gl.GLTF2) -> dict[int, int]:
    """Each node that is a child → its parent node (§3.5.2: a node has at most one)."""
    return {child: index for index, node in enumerate(gltf.nodes) for child in node.children or []}


def rest_world(gltf: gl.GLTF2) -> np.ndarray:
    """(N, 4, 4) every node's transform in the scene's frame as the nodes stand, no animation applied."""
    parent_node = node_parents(gltf)
    world: dict[int, np.ndarray] = {}

    def world_of(index: int) -> np.ndarray:
        if index not in world:
            above = parent_node.get(index)
            world[index] = (np.eye(4) if above is None else world_of(above)) @ local_matrix(gltf.nodes[index])
        return world[index]

    return np.array([world_of(index) for index in range(len(gltf.nodes))]).reshape(-1, 4, 4)


def joint_name(gltf: gl.GLTF2, node: int) -> str:
    """A joint node's name as a rig's joint: its own, else ``joint<index>``."""
    return gltf.nodes[node].name or f"joint{node}"


def load_gltf(path: str | Path) -> gl.GLTF2:
    """The glTF file at ``path``; a BvhError in one line when it is not one."""
    try:
        return gl.GLTF2().load(str(path))
    except Exception as error:  # pygltflib raises what its JSON and binary readers raise
        raise BvhError(f"{path}: not a glTF file ({type(error).__name__}: {error})") from error


def read_gltf_rig(path: str | Path) -> BvhClip:
    """The skeleton of the first skin in the glTF file at ``path``, as a one-frame BVH clip in its
    rest pose; a BvhError in one line when the file is not glTF or has no skinned skeleton."""
    path = Path(path)
    gltf = load_gltf(path)
    if gltf is None or not gltf.skins:
        raise BvhError(f"{path}: no skin, so no skeleton to retarget to; export the character with its armature")
    nodes = gltf.nodes
    joints = list(dict.fromkeys(gltf.skins[0].joints))
    if any(not 0 <= j < len(nodes) for j in joints):
        raise BvhError(f"{path}: its skin names a node the file does not have")
    parent_node = node_parents(gltf)
    world = rest_world(gltf)
    joint_set = set(joints)

    def joint_parent(index: int) -> int | None:
        above = parent_node.get(index)
        while above is not None and above not in joint_set:
            above = parent_node.get(above)
        return above

    roots = [j for j in joints if joint_parent(j) is None]
    if len(roots) != 1:
        names = ", ".join(str(nodes[j].name) for j in roots)
        raise BvhError(f"{path}: its skeleton has {len(roots)} root joints ({names}); a rig has one")
    kids = {j: [k for k in joints if joint_parent(k) == j] for j in joints}
    order: list[int] = []
    pending = [roots[0]]
    while pending:  # depth first, children in the file's order: the order a BVH lists them in
        joint = pending.pop()
        order.append(joint)
        pending.extend(reversed(kids[joint]))
    position = {j: world[j][:3, 3] for j in order}
    index_of = {node: i for i, node in enumerate(order)}
    parents = np.array([-1] + [index_of[joint_parent(j)] for j in order[1:]])
    offsets = np.array([position[j] - (position[order[p]] if p >= 0 else 0.0) for j, p in zip(order, parents)])
    names = tuple(joint_name(gltf, j) for j in order)
    if len(set(names)) != len(names):
        raise BvhError(f"{path}: two joints share a name; a joint map reads joints by name")
    channels = (("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"),) + (
        ("Zrotation", "Xrotation", "Yrotation"),
    ) * (len(order) - 1)
    values = np.zeros((1, 3 * len(order) + 3))
    values[0, :3] = offsets[0]  # the root stands where its OFFSET puts it, as in CMU's BVH
    return BvhClip(names, parents, offsets, {}, channels, values, 1.0 / 30.0)
