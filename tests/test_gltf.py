"""glTF (GLB) and FBX export (m2d2m/motion/files/gltf.py): the GLB, read back by pygltflib and posed by a
forward kinematics of its nodes written here, reproduces the joints; its actions are named
animations over their frames; the Khronos glTF Validator finds no error in it; Blender's glTF
importer puts the bones where the joints are, and Blender's FBX exporter writes a file that reads
back the same.

The validator is the npm package ``gltf-validator``, installed once into pytest's cache folder
(``.pytest_cache/d/gltf-validator-<version>``, ignored by git; ``pytest --cache-clear`` removes it)
and run with node. The Blender tests need Debian's ``blender`` and ``python3-numpy``."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pygltflib as gl
import pytest

from m2d2m.motion.files.gltf import CLIP_ANIMATION, ROOT_MOTION_ANIMATION, _xyzw, save_fbx, save_glb
from m2d2m.motion.representation.rotations import qnormalize, quat_to_matrix
from m2d2m.motion.representation.skeleton import KIT, T2M, Skeleton
from tests.test_export import build_rigid_clip

GLTF_VALIDATOR = "2.0.0-dev.3.10"  # npm gltf-validator, the Khronos glTF Validator
BLENDER = shutil.which("blender")
needs_blender = pytest.mark.skipif(BLENDER is None, reason="no blender here (apt-get install blender python3-numpy)")
SEGMENTS = [(0, 50, "a person walks forward"), (50, 120, "a person jumps"), (120, 170, "a person sits down")]

_DTYPES = {gl.FLOAT: np.float32, gl.UNSIGNED_BYTE: np.uint8, gl.UNSIGNED_SHORT: np.uint16}
_WIDTHS = {gl.SCALAR: (), gl.VEC3: (3,), gl.VEC4: (4,), gl.MAT4: (4, 4)}


def accessor_data(gltf: gl.GLTF2, index: int) -> np.ndarray:
    """The elements of accessor ``index`` of a GLB read by pygltflib (tightly packed views)."""
    accessor = gltf.accessors[index]
    view = gltf.bufferViews[accessor.bufferView]
    assert view.byteStride is None
    shape = _WIDTHS[accessor.type]
    dtype = np.dtype(_DTYPES[accessor.componentType])
    start = (view.byteOffset or 0) + (accessor.byteOffset or 0)
    size = accessor.count * int(np.prod(shape, dtype=int)) * dtype.itemsize
    assert (accessor.byteOffset or 0) + size <= view.byteLength
    return np.frombuffer(gltf.binary_blob()[start : start + size], dtype=dtype).reshape(accessor.count, *shape)


def xyzw_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4) stored x, y, z, w."""
    x, y, z, w = np.moveaxis(q.astype(np.float64), -1, 0)
    rows = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    return np.stack([np.stack(row, -1) for row in rows], -2)


def animation(gltf: gl.GLTF2, name: str) -> gl.Animation:
    [found] = [a for a in gltf.animations if a.name == name]
    return found


def posed_nodes(gltf: gl.GLTF2, name: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Key times (n,) of animation ``name`` and every node's world position (n, nodes, 3) and
    rotation (n, nodes, 3, 3) at them: forward kinematics of the scene's node tree, each node's
    keyed or default translation and rotation composed as T·R (glTF 2.0 §3.5.3)."""
    played = animation(gltf, name)
    inputs = {played.samplers[c.sampler].input for c in played.channels}
    assert len(inputs) == 1
    times = accessor_data(gltf, inputs.pop()).astype(np.float64)
    keyed = {
        (c.target.node, c.target.path): accessor_data(gltf, played.samplers[c.sampler].output) for c in played.channels
    }
    n = len(times)
    positions = np.zeros((n, len(gltf.nodes), 3))
    rotations = np.zeros((n, len(gltf.nodes), 3, 3))

    def visit(node: int, parent_rotation: np.ndarray, parent_position: np.ndarray) -> None:
        spec = gltf.nodes[node]
        translation = keyed.get((node, "translation"), np.tile(spec.translation or [0.0, 0.0, 0.0], (n, 1)))
        rotation = keyed.get((node, "rotation"), np.tile(spec.rotation or [0.0, 0.0, 0.0, 1.0], (n, 1)))
        positions[:, node] = parent_position + np.einsum("tij,tj->ti", parent_rotation, translation)
        rotations[:, node] = parent_rotation @ xyzw_to_matrix(rotation)
        for child in spec.children:
            visit(child, rotations[:, node], positions[:, node])

    for root in gltf.scenes[gltf.scene].nodes:
        visit(root, np.broadcast_to(np.eye(3), (n, 3, 3)), np.zeros((n, 3)))
    return times, positions, rotations


def joint_nodes(gltf: gl.GLTF2, skeleton: Skeleton) -> list[int]:
    """The node of each of the skeleton's joints, found by name."""
    names = [node.name for node in gltf.nodes]
    return [names.index(joint) for joint in skeleton.joint_names]


@pytest.mark.parametrize(
    ("skeleton", "rest_pose"), [(T2M, "skeleton"), (T2M, "tpose"), (KIT, "skeleton")], ids=["t2m", "t2m-tpose", "kit"]
)
def test_the_nodes_posed_by_the_clip_animation_are_the_joints(tmp_path, skeleton, rest_pose):
    joints, _ = build_rigid_clip(skeleton, n_frames=40)
    path = save_glb(tmp_path / "clip.glb", joints, skeleton, fps=25.0, rest_pose=rest_pose)
    gltf = gl.GLTF2.load(path)

    nodes = joint_nodes(gltf, skeleton)
    parent_of = {child: node for node, spec in enumerate(gltf.nodes) for child in spec.children}
    assert [gltf.nodes[parent_of[n]].name if n in parent_of else None for n in nodes] == [
        skeleton.joint_names[p] if p >= 0 else None for p in skeleton.parents
    ]
    times, positions, _ = posed_nodes(gltf, CLIP_ANIMATION)
    np.testing.assert_allclose(times, np.arange(40) / 25.0, atol=1e-6)
    error = np.abs(positions[:, nodes] - joints * skeleton.metres_per_unit).max()
    print(f"{skeleton.name} {rest_pose}: largest FK error {error * 1000:.5f} mm")
    assert error < 1e-5  # metres, at every frame and joint


def test_a_real_humanml3d_clip_reads_back_within_a_hundredth_of_a_millimetre(tmp_path, sample_joints):
    path = save_glb(tmp_path / "clip.glb", sample_joints, segments=SEGMENTS)
    gltf = gl.GLTF2.load(path)
    _, positions, _ = posed_nodes(gltf, CLIP_ANIMATION)
    error = np.abs(positions[:, joint_nodes(gltf, T2M)] - sample_joints).max()
    print(f"HumanML3D 012314: largest FK error {error * 1000:.5f} mm, {path.stat().st_size} bytes")
    assert error < 1e-5
    assert gltf.asset.version == "2.0" and gltf.scenes[gltf.scene].extras["fps"] == 20.0


def test_each_action_is_an_animation_over_its_own_frames(tmp_path, sample_joints):
    path = save_glb(tmp_path / "clip.glb", sample_joints, fps=20.0, segments=SEGMENTS)
    gltf = gl.GLTF2.load(path)
    assert [a.name for a in gltf.animations] == [CLIP_ANIMATION] + [text for _, _, text in SEGMENTS]
    assert gltf.scenes[gltf.scene].extras["actions"] == [
        {"text": text, "start_frame": start, "end_frame": end} for start, end, text in SEGMENTS
    ]
    whole_times, whole, _ = posed_nodes(gltf, CLIP_ANIMATION)
    clip = animation(gltf, CLIP_ANIMATION)
    for start, end, text in SEGMENTS:
        action = animation(gltf, text)
        assert action.extras == {"start_frame": start, "end_frame": end}
        times, positions, _ = posed_nodes(gltf, text)
        np.testing.assert_array_equal(times, whole_times[start:end])
        inputs = gltf.accessors[action.samplers[0].input]
        assert (inputs.min, inputs.max) == ([times[0]], [times[-1]])
        np.testing.assert_array_equal(positions, whole[start:end])
        # the action's keys are the clip's own, not a copy of them
        assert sorted(gltf.accessors[s.output].bufferView for s in action.samplers) == sorted(
            gltf.accessors[s.output].bufferView for s in clip.samplers
        )


def test_an_in_place_root_track_keeps_the_path_as_root_motion(tmp_path, sample_joints):
    in_place = sample_joints[:, 0] * [0.0, 1.0, 0.0]
    path = save_glb(tmp_path / "clip.glb", sample_joints, segments=SEGMENTS[:1], root_track=in_place)
    gltf = gl.GLTF2.load(path)
    assert [a.name for a in gltf.animations] == [CLIP_ANIMATION, SEGMENTS[0][2], ROOT_MOTION_ANIMATION]
    _, positions, _ = posed_nodes(gltf, CLIP_ANIMATION)
    moved = sample_joints - (sample_joints[:, :1] - in_place[:, None])
    assert np.abs(positions[:, joint_nodes(gltf, T2M)] - moved).max() < 1e-5
    [channel] = animation(gltf, ROOT_MOTION_ANIMATION).channels
    assert (gltf.nodes[channel.target.node].name, channel.target.path) == ("pelvis", "translation")
    _, travelled, _ = posed_nodes(gltf, ROOT_MOTION_ANIMATION)
    np.testing.assert_allclose(travelled[:, 0], sample_joints[:, 0], atol=1e-6)


def test_the_body_mesh_is_skinned_to_the_bones_and_faces_outwards(tmp_path, sample_joints):
    path = save_glb(tmp_path / "clip.glb", sample_joints)
    gltf = gl.GLTF2.load(path)
    [skin], [mesh] = gltf.skins, gltf.meshes
    [mesh_node] = [n for n, spec in enumerate(gltf.nodes) if spec.mesh is not None]
    assert mesh_node in gltf.scenes[gltf.scene].nodes and gltf.nodes[mesh_node].translation is None
    [primitive] = mesh.primitives
    vertices = accessor_data(gltf, primitive.attributes.POSITION).astype(np.float64)
    bound = gltf.accessors[primitive.attributes.POSITION]
    assert (bound.min, bound.max) == (vertices.min(axis=0).tolist(), vertices.max(axis=0).tolist())
    joints = accessor_data(gltf, primitive.attributes.JOINTS_0)[:, 0]
    np.testing.assert_array_equal(accessor_data(gltf, primitive.attributes.WEIGHTS_0), [[1.0, 0, 0, 0]] * len(joints))
    triangles = accessor_data(gltf, primitive.indices).reshape(-1, 3)
    boxes = triangles.reshape(-1, 12, 3)  # 8 corners and 12 triangles a box

    # outward faces: each closed box encloses a positive volume (divergence theorem)
    a, b, c = (vertices[boxes[..., k]] for k in range(3))
    assert (np.einsum("bti,bti->b", a, np.cross(b, c)) > 0).all()

    # skinning (glTF 2.0 §3.7.3): a bone's box follows the bone, its far end centred on the child joint
    inverse_bind = accessor_data(gltf, skin.inverseBindMatrices).transpose(0, 2, 1).astype(np.float64)
    frame = 100
    _, positions, rotations = posed_nodes(gltf, CLIP_ANIMATION)
    world = np.tile(np.eye(4), (len(skin.joints), 1, 1))
    world[:, :3, :3], world[:, :3, 3] = rotations[frame, skin.joints], positions[frame, skin.joints]
    skinned = np.einsum("vij,vj->vi", world[joints] @ inverse_bind[joints], np.c_[vertices, np.ones(len(vertices))])
    nodes = joint_nodes(gltf, T2M)
    for box, bone in enumerate(T2M.bones):
        far_end = skinned[8 * box + 4 : 8 * box + 8, :3].mean(axis=0)
        np.testing.assert_allclose(far_end, positions[frame, nodes[bone]], atol=1e-5)


def test_rotations_become_unit_quaternions_near_half_turns_too():
    rng = np.random.default_rng(0)
    axes = rng.normal(size=(200, 3))
    angles = np.concatenate([rng.uniform(0, np.pi, 100), np.pi - rng.uniform(0, 1e-7, 100)])
    wxyz = np.concatenate([np.cos(angles / 2)[:, None], np.sin(angles / 2)[:, None] * qnormalize(axes)], axis=1)
    xyzw = _xyzw(quat_to_matrix(wxyz))
    np.testing.assert_allclose(np.linalg.norm(xyzw, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(xyzw * np.roll(wxyz, -1, axis=-1), axis=-1)), 1.0, atol=1e-12)


@pytest.mark.parametrize(
    ("segments", "message"),
    [([(0, 200, "too long")], r"segment \(0, 200\) must satisfy"), ([(30, 30, "empty")], r"segment \(30, 30\)")],
)
def test_segments_outside_the_clip_are_refused(tmp_path, sample_joints, segments, message):
    with pytest.raises(ValueError, match=message):
        save_glb(tmp_path / "clip.glb", sample_joints, segments=segments)
    assert not (tmp_path / "clip.glb").exists()


def test_a_root_track_of_the_wrong_shape_is_refused(tmp_path, sample_joints):
    with pytest.raises(ValueError, match=r"root_track must have shape \(170, 3\)"):
        save_glb(tmp_path / "clip.glb", sample_joints, root_track=np.zeros((10, 3)))


@pytest.fixture(scope="session")
def gltf_validator(pytestconfig) -> Path:
    """A node script printing the Khronos glTF Validator's JSON report of the GLB named on its
    command line; the npm package is installed into pytest's cache on first use."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if not (node and npm):
        pytest.skip("no node and npm here (apt-get install nodejs npm): the Khronos glTF Validator runs on node")
    folder = pytestconfig.cache.mkdir(f"gltf-validator-{GLTF_VALIDATOR}")
    if not (folder / "node_modules" / "gltf-validator" / "package.json").is_file():
        install = [npm, "install", "--prefix", str(folder), "--no-audit", "--no-fund", "--no-save"]
        result = subprocess.run(
            [*install, f"gltf-validator@{GLTF_VALIDATOR}"], capture_output=True, text=True, timeout=300, check=False
        )
        if result.returncode != 0:
            first = (result.stderr.strip().splitlines() or ["no output"])[0]  # npm's error code
            pytest.skip(f"npm could not install gltf-validator@{GLTF_VALIDATOR} (offline?): {first}")
    script = folder / "validate.js"
    script.write_text(
        'const fs = require("fs");\n'
        'const validator = require("gltf-validator");\n'
        "validator.validateBytes(new Uint8Array(fs.readFileSync(process.argv[2])), { maxIssues: 0 })\n"
        "  .then((report) => console.log(JSON.stringify(report)))\n"
        "  .catch((error) => { console.error(String(error)); process.exit(1); });\n",
        encoding="utf-8",
    )
    return script


@pytest.mark.parametrize(("skeleton", "n_frames"), [(T2M, 60), (KIT, 60), (T2M, 1)], ids=["t2m", "kit", "one-frame"])
def test_the_khronos_validator_finds_no_error(tmp_path, gltf_validator, skeleton, n_frames):
    joints, _ = build_rigid_clip(skeleton, n_frames=n_frames)
    segments = [(0, n_frames // 3, "first"), (n_frames // 3, n_frames, "second")] if n_frames > 1 else [(0, 1, "only")]
    path = save_glb(tmp_path / "clip.glb", joints, skeleton, segments=segments, root_track=joints[:, 0])
    result = subprocess.run(
        ["node", str(gltf_validator), str(path)], capture_output=True, text=True, timeout=120, check=False
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    issues = report["issues"]
    for message in issues["messages"]:
        print(message)
    print(f"validator {report['validatorVersion']}: {issues['numErrors']} errors, {issues['numWarnings']} warnings")
    assert issues["numErrors"] == 0
    assert report["info"]["animationCount"] == 2 + len(segments) and report["info"]["hasSkins"]


# Run inside Blender: import a GLB (Blender's glTF importer) or an FBX (its FBX importer, keys not
# offset), play the action whose name holds "clip" and write every pose bone's head in world
# coordinates per frame, with the actions' frame ranges, as JSON.
BLENDER_HEADS = """
import json, sys, bpy
source, out, fps, frames = sys.argv[sys.argv.index("--") + 1:]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.context.scene.render.fps = int(fps)
if source.endswith(".glb"):
    bpy.ops.import_scene.gltf(filepath=source, import_shading="FLAT")
else:
    bpy.ops.import_scene.fbx(filepath=source, anim_offset=0.0)
armature = next(o for o in bpy.data.objects if o.type == "ARMATURE")
armature.animation_data.action = next(a for a in bpy.data.actions if "clip" in a.name)
heads = []
for frame in range(int(frames)):
    bpy.context.scene.frame_set(frame)
    heads.append({bone.name: list(armature.matrix_world @ bone.head) for bone in armature.pose.bones})
actions = {action.name: list(action.frame_range) for action in bpy.data.actions}
json.dump({"heads": heads, "actions": actions}, open(out, "w"))
"""


def blender_heads(
    source: Path, n_frames: int, names: Sequence[str] = T2M.joint_names
) -> tuple[np.ndarray, dict[str, list[float]]]:
    """The joints ``names`` (T, J, 3; T2M's by default) where Blender puts the bones of ``source``,
    back in glTF's Y-up axes (Blender is Z-up: its importers map glTF's (x, y, z) to (x, −z, y)),
    and its actions."""
    out = source.with_suffix(".json")
    command = [BLENDER, "--background", "--factory-startup", "--python-exit-code", "1", "--python-expr"]
    result = subprocess.run(
        [*command, BLENDER_HEADS, "--", str(source), str(out), "20", str(n_frames)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    read = json.loads(out.read_text())
    z_up = np.array([[frame[name] for name in names] for frame in read["heads"]])
    return np.stack([z_up[..., 0], z_up[..., 2], -z_up[..., 1]], axis=-1), read["actions"]


@pytest.mark.slow
@needs_blender
def test_blenders_gltf_importer_puts_the_bones_on_the_joints(tmp_path, sample_joints):
    path = save_glb(tmp_path / "clip.glb", sample_joints, segments=SEGMENTS)
    heads, actions = blender_heads(path, len(sample_joints))
    error = np.abs(heads - sample_joints).max()
    print(f"Blender glTF import: largest bone head error {error * 1000:.4f} mm; actions {sorted(actions)}")
    assert error < 1e-3
    assert {name.rsplit("_", 1)[0] for name in actions} == {CLIP_ANIMATION} | {text for _, _, text in SEGMENTS}


def fbx_takes(path: Path) -> list[str]:
    """The names of a binary FBX's takes (its AnimationStack objects, stored as ``name\\0\\1AnimStack``)
    in the order the file lists them."""
    return [name.decode() for name in re.findall(rb"([ -~]+)\x00\x01AnimStack", path.read_bytes())]


@pytest.mark.slow
@needs_blender
def test_the_fbx_opens_on_the_whole_clip_and_names_each_take_once(tmp_path, sample_joints):
    """Issue 53, finding 8: the FBX's takes came in alphabetical order, so engines opened it on a
    2-s "a person jumps", and were named "t2m|a person jumps_t2m" (the armature's name twice)."""
    path = save_fbx(tmp_path / "clip.fbx", sample_joints, segments=SEGMENTS)
    assert fbx_takes(path) == [CLIP_ANIMATION, *(text for _, _, text in SEGMENTS)]


@pytest.mark.slow
@needs_blender
def test_blender_exports_fbx_that_reads_back_as_the_joints(tmp_path, sample_joints):
    path = save_fbx(tmp_path / "clip.fbx", sample_joints, segments=SEGMENTS)
    assert path.read_bytes().startswith(b"Kaydara FBX Binary")
    heads, actions = blender_heads(path, len(sample_joints))
    error = np.abs(heads - sample_joints).max()
    print(f"FBX through Blender: {path.stat().st_size} bytes, largest bone head error {error * 1000:.4f} mm")
    assert error < 1e-3
    # one take per animation; each action's take starts at frame 0 (its NLA strip's start)
    lengths = {name.split("|")[-1].rsplit("_", 1)[0]: end - start for name, (start, end) in actions.items()}
    assert lengths == {CLIP_ANIMATION: 169, **{text: end - start - 1 for start, end, text in SEGMENTS}}


def test_fbx_without_blender_names_the_package(tmp_path, sample_joints, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(
        FileNotFoundError, match=r"^FBX is written by Blender, and no blender is on the PATH: apt-get install blender"
    ):
        save_fbx(tmp_path / "clip.fbx", sample_joints)
    assert not list(tmp_path.iterdir())
