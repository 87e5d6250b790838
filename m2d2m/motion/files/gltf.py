"""glTF 2.0 binary (GLB) export of a clip, and FBX through Blender's own exporter.

A GLB is what web viewers, game engines and DCC tools all open (the Khronos glTF 2.0
specification, https://registry.khronos.org/glTF/specs/2.0/glTF-2.0.html, cited below as "§").
The rig is the one the BVH gets (:mod:`m2d2m.motion.representation.pose`): one node per joint, each holding its
rest offset as its translation and its rotation relative to its parent keyed per frame; the root
node's translation is keyed too. A skin (§3.7.3) binds a simple body mesh, a tapered box per bone,
so that any viewer shows a figure and not only an invisible skeleton. Units are metres and +Y is up
(§3.4): KIT's joints are converted from its own units; the character faces +Z, the glTF "front".

The container is written by pygltflib (https://gitlab.com/dodgyville/pygltflib), which lays out
the GLB header and chunks (§4.4); this module only fills its buffer views and accessors.
"""

from __future__ import annotations

import re
import subprocess
import tempfile
from collections.abc import Callable, Sequence
from fractions import Fraction
from pathlib import Path

import numpy as np
import pygltflib as gl

from m2d2m.atomic import atomic_path
from m2d2m.motion.files.blender import find_blender
from m2d2m.motion.representation.pose import pose_of, topological_order
from m2d2m.motion.representation.rotations import cross, matrix_to_quat, normalize
from m2d2m.motion.representation.skeleton import T2M, Skeleton

CLIP_ANIMATION = "clip"
ROOT_MOTION_ANIMATION = "root motion"

# accessor type and component type of each array shape and dtype (§3.6.2.2)
_ACCESSOR_TYPES = {(): gl.SCALAR, (3,): gl.VEC3, (4,): gl.VEC4, (4, 4): gl.MAT4}
_COMPONENT_TYPES = {
    np.dtype(np.float32): gl.FLOAT,
    np.dtype(np.uint8): gl.UNSIGNED_BYTE,
    np.dtype(np.uint16): gl.UNSIGNED_SHORT,
}

# the body: a box per bone, its half-width a fraction of the bone's length within bounds (metres),
# narrowing towards the bone's end; a cube around the head
_HALF_WIDTH, _THINNEST, _THICKEST, _TAPER = 0.22, 0.02, 0.07, 0.7
_HEAD_HALF_SIZE = 0.09
_SKIN_COLOUR = [0.72, 0.74, 0.78, 1.0]
# the 8 corners of a box are numbered x + 2y + 4z (x: across, y: across, z: along the bone); its six
# faces as quads wound counter-clockwise seen from outside, glTF's front faces (§3.7.4)
_BOX_QUADS = np.array([[0, 4, 6, 2], [1, 3, 7, 5], [0, 1, 5, 4], [2, 6, 7, 3], [0, 2, 3, 1], [4, 5, 7, 6]])
_BOX_TRIANGLES = np.concatenate([_BOX_QUADS[:, [0, 1, 2]], _BOX_QUADS[:, [0, 2, 3]]])


def save_glb(
    path: str | Path,
    joints: np.ndarray,
    skeleton: Skeleton = T2M,
    fps: float | None = None,
    segments: Sequence[tuple[int, int, str]] = (),
    rest_pose: str = "skeleton",
    root_track: np.ndarray | None = None,
    closing_key: bool = False,
) -> Path:
    """Write joint positions (T, J, 3) as a glTF 2.0 binary file (written whole or not at all) and
    return its path.

    The file holds one scene: the joint nodes (named as the skeleton's joints, nested as its tree)
    and a skinned body mesh. The bind pose is ``rest_pose`` (:func:`m2d2m.motion.representation.pose.rest_offsets`)
    with the root where it is in the first frame. Keys are at ``frame / fps`` seconds (default
    fps: the skeleton's), interpolated LINEAR (rotations: slerp, Appendix C). Animations:
    ``"clip"``, the whole clip; then one per ``(start, end, text)`` segment (``end`` exclusive),
    named by its text, whose keys are the clip's frames ``start..end-1`` at their times in the
    clip; the scene's ``extras`` list the actions and their frames.

    ``root_track`` (T, 3), when given, is what the root node's translation is keyed to in those
    animations — e.g. an in-place path — and the clip's own root path is kept as one more animation,
    ``"root motion"``, which keys the root's translation only.

    ``closing_key``: the last frame of ``joints`` (and ``root_track``) is no frame of the clip but
    a loop's first again, where the loop runs on into it: ``"clip"`` and ``"root motion"`` key it
    at the clip's end, ``T / fps``, so that an engine looping them plays one cycle of ``T``
    frames; the actions and the ``extras`` count the clip's ``T`` frames.
    """
    joints = skeleton.check_joints(joints)
    fps = float(skeleton.fps if fps is None else fps)
    frames = len(joints) - closing_key
    segments = checked_segments(segments, frames)
    pose = pose_of(joints, skeleton, rest_pose=rest_pose)
    metres = skeleton.metres_per_unit
    path_keys = pose.root * metres
    if root_track is not None:
        root_track = np.asarray(root_track, dtype=np.float64)
        if root_track.shape != path_keys.shape:
            raise ValueError(f"root_track must have shape {path_keys.shape}, got {root_track.shape}")
        path_keys = root_track * metres

    gltf = new_gltf()
    blob = Blob(gltf)
    root = topological_order(skeleton)[0]
    offsets = pose.offsets * metres
    translations = offsets.copy()
    translations[root] = path_keys[0]
    add_joint_nodes(gltf, skeleton.joint_names, skeleton.parents, translations)
    rest = _rest_positions(skeleton, offsets, path_keys[0])
    body = add_body(gltf, blob, skeleton.parents, skeleton.bones, rest, skeleton.head_joint, skeleton.name)

    rotations = dict(enumerate(np.moveaxis(pose.local, 1, 0)))
    keys = animate(gltf, blob, fps, segments, {root: path_keys}, rotations, closing_key)
    if root_track is not None:
        motion = keys.add(root, gl.TRANSLATION, pose.root * metres)
        gltf.animations.append(keys.animation(ROOT_MOTION_ANIMATION, [motion], 0, frames, closing_key))
    gltf.scenes = [gl.Scene(name="m2d2m", nodes=[root, body], extras=clip_extras(skeleton.name, fps, frames, segments))]
    gltf.scene = 0
    return write_glb(gltf, blob, path)


def new_gltf() -> gl.GLTF2:
    """An empty glTF naming its writer."""
    return gl.GLTF2(asset=gl.Asset(generator=f"m2d2m with pygltflib {gl.__version__}"))


def animate(
    gltf: gl.GLTF2,
    blob: Blob,
    fps: float,
    segments: Sequence[tuple[int, int, str]],
    translations: dict[int, np.ndarray],
    rotations: dict[int, np.ndarray],
    closing_key: bool = False,
) -> _Keys:
    """Key nodes' translations (node → (T, 3)) and rotations (node → (T, 3, 3) matrices) at
    ``frame / fps`` seconds, and add the animations :func:`save_glb` describes: ``"clip"`` (with
    ``closing_key``, up to the last key, a loop's first frame again), then one per checked segment;
    returns the keys, for more animations over the same tracks."""
    keyed = len(next(iter(translations.values())))
    keys = _Keys(blob, (np.arange(keyed) / fps).astype(np.float32))
    tracks = [keys.add(node, gl.TRANSLATION, track) for node, track in translations.items()]
    tracks += [keys.add(node, gl.ROTATION, _continuous(_xyzw(track))) for node, track in rotations.items()]
    gltf.animations.append(keys.animation(CLIP_ANIMATION, tracks, 0, keyed - closing_key, closing_key))
    gltf.animations += [keys.animation(text, tracks, start, end) for start, end, text in segments]
    return keys


def clip_extras(skeleton: str, fps: float, frames: int, segments: Sequence[tuple[int, int, str]]) -> dict:
    """What the glTF itself cannot say, for a scene's ``extras``: the clip's rate and its actions
    (the animations after "clip")."""
    return {
        "skeleton": skeleton,
        "fps": fps,
        "num_frames": frames,
        "actions": [{"text": text, "start_frame": start, "end_frame": end} for start, end, text in segments],
        "end_frame": "exclusive",
    }


def write_glb(gltf: gl.GLTF2, blob: Blob, path: str | Path) -> Path:
    """Write ``gltf`` with ``blob`` as its one binary buffer (§4.4.3.2), whole or not at all."""
    if gltf.buffers:
        gltf.buffers[0].byteLength = len(blob.data)
    else:
        gltf.buffers = [gl.Buffer(byteLength=len(blob.data))]
    gltf.set_binary_blob(bytes(blob.data))
    path = Path(path)
    with atomic_path(path) as partial:
        gltf.save_binary(str(partial))  # not .save(): it would replace our asset (generator) with pygltflib's
    return path


def save_fbx(
    path: str | Path,
    joints: np.ndarray,
    skeleton: Skeleton = T2M,
    fps: float | None = None,
    segments: Sequence[tuple[int, int, str]] = (),
    rest_pose: str = "skeleton",
    timeout_s: float = 300.0,
    closing_key: bool = False,
) -> Path:
    """Write joint positions as FBX, made by Blender's own FBX exporter from the GLB of
    :func:`save_glb` (FBX is a closed format: Blender's exporter is the one open writer that
    Autodesk's tools and game engines accept; ``closing_key`` as there), and return its path.
    Every animation becomes a take, the whole clip's first. Raises ``FileNotFoundError`` when
    ``blender`` is not on the PATH and ``RuntimeError`` with Blender's last line of errors when it
    fails."""
    fps = float(skeleton.fps if fps is None else fps)
    return fbx_of_glb(
        path,
        fps,
        lambda glb: save_glb(glb, joints, skeleton, fps, segments, rest_pose, closing_key=closing_key),
        timeout_s,
    )


def fbx_of_glb(path: str | Path, fps: float, write: Callable[[Path], Path], timeout_s: float = 300.0) -> Path:
    """Write FBX at ``path`` from the GLB that ``write`` puts at the path it is given (a temporary
    one), by Blender's glTF importer and FBX exporter at ``fps``; the errors of :func:`save_fbx`."""
    blender = find_blender()
    # Blender's glTF importer turns seconds into frames with the scene's integer frame rate only
    # (io_scene_gltf2/blender/imp/gltf2_blender_animation_node.py): a rate a whole multiple of the
    # clip's puts every key on a frame (12.5 fps: 25, every other frame)
    scene_fps = Fraction(fps).limit_denominator(100).numerator
    path = Path(path)
    with tempfile.TemporaryDirectory(prefix="m2d2m-fbx-") as folder, atomic_path(path) as partial:
        glb = write(Path(folder) / "clip.glb")
        command = [blender, "--background", "--factory-startup", "--python-exit-code", "1"]
        command += ["--python-expr", _BLENDER_GLB_TO_FBX, "--", str(glb), str(partial), str(scene_fps)]
        result = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s, check=False)
        if result.returncode != 0 or not partial.is_file():
            raise RuntimeError(f"blender could not export FBX: {_last_error(result.stdout + result.stderr)}")
    return path


def _last_error(output: str) -> str:
    """Blender's last Python exception line (it prints tracebacks to stdout), else its last line."""
    lines = re.findall(r"^[A-Z]\w*(?:Error|Exception): .*$", output, flags=re.MULTILINE)
    lines = lines or [line for line in output.splitlines() if line.strip()]
    return lines[-1] if lines else "no output"


# Run inside Blender (bpy): an empty scene at the clip's frame rate, Blender's glTF importer, then
# its FBX exporter (Blender manual: Import-Export > glTF 2.0, FBX); no leaf bones: the joints are the
# bones. Flat shading is what a mesh without normals gets anyway (§3.7.2.1), and it keeps Debian 12's
# Blender 3.4 off its importer's "smooth" path, which uses np.bool, gone from NumPy 1.24 (Debian's).
# The importer stashes each animation as a muted NLA track of its name, each new track first, holding
# one strip of the action "<animation>_<object>". The exporter's "all actions" takes would come in
# the actions' alphabetical order (a 2-s "a person jumps" before the whole clip, which engines then
# open on), each named "<object>|<action>" ("t2m|clip_t2m": the object's name twice); its NLA-strip
# takes come in the tracks' order, each named by its strip. So the tracks are laid again in the
# file's order, unmuted, each strip named as its animation: "clip" first, and each name once.
_BLENDER_GLB_TO_FBX = """
import sys, bpy
glb, fbx, fps = sys.argv[sys.argv.index("--") + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.fps, scene.render.fps_base, scene.frame_start = int(fps), 1.0, 0
bpy.ops.import_scene.gltf(filepath=glb, import_shading="FLAT")
for obj in bpy.data.objects:
    data = obj.animation_data
    if data is None:
        continue
    data.action = None
    stashed = [(t.name, t.strips[0].action, t.strips[0].frame_start) for t in reversed(data.nla_tracks)]
    for track in list(data.nla_tracks):
        data.nla_tracks.remove(track)
    track = None
    for name, action, start in stashed:
        track = data.nla_tracks.new(prev=track)
        track.name = name
        track.strips.new(name, int(start), action).name = name
bpy.ops.export_scene.fbx(
    filepath=fbx, add_leaf_bones=False, bake_anim=True, bake_anim_use_all_actions=False,
    bake_anim_use_nla_strips=True, bake_anim_simplify_factor=0.0,
)
"""


class Blob:
    """The GLB's one binary buffer as it fills: every array gets its own buffer view, 4-byte
    aligned (§3.6.2.4), and accessors read whole arrays or runs of their rows."""

    def __init__(self, gltf: gl.GLTF2) -> None:
        self.gltf = gltf
        self.data = bytearray()

    def view(self, array: np.ndarray, target: int | None = None) -> int:
        """Append ``array``'s bytes as a new buffer view (``target``: for vertex data or indices)."""
        self.data.extend(b"\0" * (-len(self.data) % 4))
        view = gl.BufferView(buffer=0, byteOffset=len(self.data), byteLength=array.nbytes, target=target)
        self.data.extend(np.ascontiguousarray(array).tobytes())
        self.gltf.bufferViews.append(view)
        return len(self.gltf.bufferViews) - 1

    def accessor(self, view: int, rows: np.ndarray, first: int = 0, bounds: bool = False) -> int:
        """An accessor of ``rows``, which start at row ``first`` of the array in ``view``; with
        their ``min`` and ``max``, which animation inputs and POSITION must have (§3.6.2.5)."""
        accessor = gl.Accessor(
            bufferView=view,
            byteOffset=first * rows[0].nbytes,
            componentType=_COMPONENT_TYPES[rows.dtype],
            count=len(rows),
            type=_ACCESSOR_TYPES[rows.shape[1:]],
        )
        if bounds:
            flat = rows.reshape(len(rows), -1)
            accessor.min, accessor.max = flat.min(axis=0).tolist(), flat.max(axis=0).tolist()
        self.gltf.accessors.append(accessor)
        return len(self.gltf.accessors) - 1

    def array(self, array: np.ndarray, target: int | None = None, bounds: bool = False) -> int:
        """A new buffer view of ``array`` and an accessor of all of it."""
        return self.accessor(self.view(array, target), array, bounds=bounds)


class _Keys:
    """Keyframes stored once: the key times and every track (a node's translation or rotation) get
    a buffer view each, and every animation (§3.11) reads a run of frames of them, so one per
    action costs accessors, not a copy of the clip."""

    def __init__(self, blob: Blob, times: np.ndarray) -> None:
        self.blob, self.times = blob, times
        self.times_view = blob.view(times)
        self.tracks: list[tuple[int, str, np.ndarray, int]] = []

    def add(self, node: int, target: str, keys: np.ndarray) -> int:
        """Store the keys (T, 3 or 4) of ``node``'s ``target`` path; returns the track's number."""
        keys = keys.astype(np.float32)
        self.tracks.append((node, target, keys, self.blob.view(keys)))
        return len(self.tracks) - 1

    def animation(self, name: str, tracks: list[int], start: int, end: int, closing_key: bool = False) -> gl.Animation:
        """An animation keying ``tracks`` at frames ``start..end-1``, LINEAR (rotations: slerp),
        and with ``closing_key`` at ``end`` too: a loop's first frame again (``extras``
        ``closing_key``), not a frame of the clip."""
        last = end + closing_key
        inputs = self.blob.accessor(self.times_view, self.times[start:last], first=start, bounds=True)
        extras = {"start_frame": start, "end_frame": end, **({"closing_key": True} if closing_key else {})}
        animation = gl.Animation(name=name, extras=extras)
        for track in tracks:
            node, target, keys, view = self.tracks[track]
            output = self.blob.accessor(view, keys[start:last], first=start)
            sampler = gl.AnimationSampler(input=inputs, output=output, interpolation=gl.ANIM_LINEAR)
            channel = gl.AnimationChannel(
                sampler=len(animation.samplers), target=gl.AnimationChannelTarget(node=node, path=target)
            )
            animation.samplers.append(sampler)
            animation.channels.append(channel)
        return animation


def checked_segments(segments: Sequence[tuple[int, int, str]], n_frames: int) -> list[tuple[int, int, str]]:
    checked = [(int(start), int(end), str(text)) for start, end, text in segments]
    for start, end, _ in checked:
        if not 0 <= start < end <= n_frames:
            raise ValueError(f"segment ({start}, {end}) must satisfy 0 <= start < end <= {n_frames}")
    return checked


def add_joint_nodes(gltf: gl.GLTF2, names: Sequence[str], parents: np.ndarray, translations: np.ndarray) -> None:
    """Node ``j`` is joint ``j``: its children, and ``translations[j]`` (its rest offset; the
    root's: where it is in the first frame). No rotation: identity, the bind pose."""
    for joint, name in enumerate(names):
        kids = np.flatnonzero(parents == joint).tolist()
        gltf.nodes.append(gl.Node(name=name, translation=translations[joint].tolist(), children=kids))


def _rest_positions(skeleton: Skeleton, offsets: np.ndarray, root_position: np.ndarray) -> np.ndarray:
    """(J, 3) every joint's world position in the bind pose."""
    rest = np.empty((skeleton.num_joints, 3))
    for joint in topological_order(skeleton):
        parent = skeleton.parents[joint]
        rest[joint] = root_position if parent < 0 else rest[parent] + offsets[joint]
    return rest


def add_body(
    gltf: gl.GLTF2, blob: Blob, parents: np.ndarray, bones: Sequence[int], rest: np.ndarray, head: int | None, name: str
) -> int:
    """A new glTF's skin ``name`` (its joints are the joint nodes 0..J-1 of a skeleton of ``parents``
    standing at ``rest`` (J, 3), §3.7.3) and a body mesh bound to it: a box along every bone, moved
    by the bone's parent joint whose rotation turns it (one a joint of ``bones``, in their order), and
    a cube on the ``head`` joint, if any.
    Each vertex has one joint of weight 1. The mesh's node is a root node without a transform,
    as its transform would be ignored anyway (§3.7.3.2); returns that node's index."""
    boxes, owners = [], []
    for bone in bones:
        parent = parents[bone]
        length = float(np.linalg.norm(rest[bone] - rest[parent]))
        if length > 1e-6:
            half = float(np.clip(_HALF_WIDTH * length, _THINNEST, _THICKEST))
            boxes.append(_box(rest[parent], rest[bone], half, _TAPER * half))
            owners.append(parent)
    if head is not None:
        up = np.array([0.0, _HEAD_HALF_SIZE, 0.0])
        boxes.append(_box(rest[head] - up, rest[head] + up, _HEAD_HALF_SIZE, _HEAD_HALF_SIZE))
        owners.append(head)

    positions = np.concatenate(boxes).astype(np.float32)
    corners = len(boxes[0])
    indices = (_BOX_TRIANGLES.ravel()[None, :] + corners * np.arange(len(boxes))[:, None]).astype(np.uint16)
    joints = np.zeros((len(positions), 4), dtype=np.uint8)
    joints[:, 0] = np.repeat(owners, corners)
    weights = np.zeros((len(positions), 4), dtype=np.float32)
    weights[:, 0] = 1.0
    attributes = gl.Attributes(
        POSITION=blob.array(positions, gl.ARRAY_BUFFER, bounds=True),
        JOINTS_0=blob.array(joints, gl.ARRAY_BUFFER),
        WEIGHTS_0=blob.array(weights, gl.ARRAY_BUFFER),
    )
    primitive = gl.Primitive(
        attributes=attributes, indices=blob.array(indices.ravel(), gl.ELEMENT_ARRAY_BUFFER), material=0
    )
    gltf.meshes.append(gl.Mesh(name="body", primitives=[primitive]))
    surface = gl.PbrMetallicRoughness(baseColorFactor=_SKIN_COLOUR, metallicFactor=0.0, roughnessFactor=0.8)
    gltf.materials.append(gl.Material(name="body", pbrMetallicRoughness=surface))

    # the bind pose has no rotations, so each inverse bind matrix (§3.7.3.1) is a translation by
    # minus the joint's rest position; matrices are stored column by column (§3.6.2.4), so the
    # array is indexed [joint, column, row] and column 3 is the translation
    inverse_bind = np.tile(np.eye(4, dtype=np.float32), (len(parents), 1, 1))
    inverse_bind[:, 3, :3] = -rest
    skin = gl.Skin(name=name, skeleton=int(np.flatnonzero(parents < 0)[0]), joints=list(range(len(parents))))
    skin.inverseBindMatrices = blob.array(inverse_bind)
    gltf.skins.append(skin)
    gltf.nodes.append(gl.Node(name="body", mesh=0, skin=0))
    return len(gltf.nodes) - 1


def _box(start: np.ndarray, end: np.ndarray, start_half: float, end_half: float) -> np.ndarray:
    """The 8 corners (numbered as :data:`_BOX_QUADS`) of a box from ``start`` to ``end``, square
    across, of half-widths ``start_half`` and ``end_half`` at its ends."""
    along = normalize(end - start)
    helper = np.eye(3)[np.argmin(np.abs(along))]  # the axis least along the bone
    across = normalize(cross(along, helper))
    other = cross(along, across)  # (across, other, along) is right-handed, so the winding is outward
    corners = []
    for corner in range(8):
        x, y, z = corner & 1, (corner >> 1) & 1, corner >> 2
        half = end_half if z else start_half
        corners.append((end if z else start) + half * ((2 * x - 1) * across + (2 * y - 1) * other))
    return np.array(corners)


def _xyzw(matrices: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) of rotation matrices, ``(x, y, z, w)`` as glTF stores rotations (§3.5.3)."""
    return matrix_to_quat(matrices)[..., [1, 2, 3, 0]]


def _continuous(quaternions: np.ndarray) -> np.ndarray:
    """Quaternions (T, ..., 4) with their signs chosen so that each key is on the same side as the
    one before (q and −q are one rotation). The specification's slerp takes the short way whatever
    the signs (Appendix C), but tools that interpolate or resample the components, as Blender's
    F-curves do, would turn the long way round between keys of opposite signs."""
    flips = np.sign(np.sum(quaternions[1:] * quaternions[:-1], axis=-1))
    flips[flips == 0] = 1.0
    signs = np.concatenate([np.ones((1, *flips.shape[1:])), np.cumprod(flips, axis=0)])
    return quaternions * signs[..., None]
