"""A motion on a user's rig as GLB and FBX (m2d2m/motion/rigs/gltf_export.py; issue 52 §3): read back by
pygltflib and posed by a forward kinematics of its nodes' own keys (translation, rotation and
scale, glTF 2.0 §3.5.3), a GLB on CMU's BVH rig and one on Mixamo's X Bot character put every
joint where the BVH on the same rig puts it; the X Bot's file keeps its own nodes, skin and
meshes; each action is an animation; the Khronos glTF Validator finds no error; Blender makes FBX
of it; ``m2d2m export --rig`` writes it and refuses a format a rig does not go with."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pygltflib as gl
import pytest

from m2d2m.motion.files.bvh_reader import read_bvh
from m2d2m.motion.files.gltf import CLIP_ANIMATION
from m2d2m.motion.representation.rigid import on_rigid_skeleton
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.motion.rigs.gltf_export import save_rig_fbx, save_rig_glb
from m2d2m.motion.rigs.retarget import read_target, retarget_to_bvh
from orchestration.cli import main
from tests.conftest import HUMANML3D_SAMPLE
from tests.test_bvh_reader import CMU
from tests.test_gltf import (  # noqa: F401
    accessor_data,
    animation,
    blender_heads,
    fbx_takes,
    gltf_validator,
    needs_blender,
    xyzw_to_matrix,
)

XBOT = Path(__file__).parent / "fixtures" / "mixamo" / "xbot-skeleton.glb"
RIGS = [CMU / "131_01.bvh", XBOT]
SEGMENTS = [(0, 30, "a person walks forward"), (30, 80, "a person turns")]


@pytest.fixture(scope="module")
def ours() -> np.ndarray:
    """HumanML3D's sample clip, its first 80 frames, on one rigid body."""
    return on_rigid_skeleton(np.load(HUMANML3D_SAMPLE / "new_joints" / "012314.npy")[:80], T2M)


def posed_world(gltf: gl.GLTF2, played: gl.Animation) -> np.ndarray:
    """Every node's world transform (n, nodes, 4, 4) at the keys of animation ``played``: its keyed
    or rest translation, rotation and scale composed T·R·S (or its matrix), from the scene's roots."""
    keyed = {
        (c.target.node, c.target.path): accessor_data(gltf, played.samplers[c.sampler].output).astype(np.float64)
        for c in played.channels
    }
    frames = len(accessor_data(gltf, played.samplers[0].input))
    world = np.zeros((frames, len(gltf.nodes), 4, 4))

    def visit(node: int, above: np.ndarray) -> None:
        spec = gltf.nodes[node]
        local = np.tile(np.eye(4), (frames, 1, 1))
        if spec.matrix is not None:
            local[:] = np.reshape(spec.matrix, (4, 4)).T
        else:
            rotation = keyed.get((node, "rotation"), np.tile(spec.rotation or [0.0, 0.0, 0.0, 1.0], (frames, 1)))
            local[:, :3, :3] = xyzw_to_matrix(rotation) * np.asarray(spec.scale or [1.0, 1.0, 1.0])
            local[:, :3, 3] = keyed.get((node, "translation"), np.tile(spec.translation or [0.0] * 3, (frames, 1)))
        world[:, node] = above @ local
        for child in spec.children or []:
            visit(child, world[:, node])

    for root in gltf.scenes[gltf.scene].nodes:
        visit(root, np.eye(4))
    return world


@pytest.mark.parametrize("rig_file", RIGS, ids=["cmu-bvh", "xbot-glb"])
def test_the_glb_on_a_rig_puts_its_joints_where_its_bvh_does(tmp_path, ours, rig_file):
    target = read_target(rig_file)
    path = save_rig_glb(tmp_path / "on-rig.glb", target, ours, 20.0, SEGMENTS)
    bvh = read_bvh(retarget_to_bvh(tmp_path / "on-rig.bvh", ours, rig_file, fps=20.0))
    gltf = gl.GLTF2.load(str(path))
    names = [node.name for node in gltf.nodes]
    joints = [names.index(name) for name in bvh.names]
    # a BVH rig's GLB is in metres (glTF 2.0 §3.4); a character's keeps its own units, as its BVH does
    metres = target.metres_per_unit if target.character is None else 1.0
    expected = bvh.positions() * metres
    clip = posed_world(gltf, animation(gltf, CLIP_ANIMATION))[:, joints][..., :3, 3]
    error = np.abs(clip - expected).max()
    print(f"{rig_file.name}: largest joint error against the BVH {error * 1000:.4f} mm")
    assert error < 1e-4
    for start, end, text in SEGMENTS:  # each action keys its own frames, at their times in the clip
        times = accessor_data(gltf, animation(gltf, text).samplers[0].input)
        np.testing.assert_allclose(times, np.arange(start, end) / 20.0, atol=1e-6)
        np.testing.assert_allclose(
            posed_world(gltf, animation(gltf, text))[:, joints][..., :3, 3], expected[start:end], atol=1e-4
        )
    extras = gltf.scenes[gltf.scene].extras
    assert extras["fps"] == 20.0 and [a["text"] for a in extras["actions"]] == [t for _, _, t in SEGMENTS]


def test_the_glb_on_a_bvh_rig_is_its_skeleton_with_a_body(tmp_path, ours):
    path = save_rig_glb(tmp_path / "on-cmu.glb", read_target(CMU / "131_01.bvh"), ours, 20.0, SEGMENTS)
    gltf = gl.GLTF2.load(str(path))
    assert [node.name for node in gltf.nodes] == [*read_bvh(CMU / "131_01.bvh").names, "body"]
    assert [a.name for a in gltf.animations] == [CLIP_ANIMATION, *(text for _, _, text in SEGMENTS)]
    assert len(gltf.skins) == len(gltf.meshes) == 1 and gltf.skins[0].joints == list(range(31))


def test_the_glb_on_a_character_is_its_own_file_moving(tmp_path, ours):
    source = gl.GLTF2.load(str(XBOT))
    path = save_rig_glb(tmp_path / "on-xbot.glb", read_target(XBOT), ours, 20.0, SEGMENTS)
    gltf = gl.GLTF2.load(str(path))
    assert [node.name for node in gltf.nodes] == [node.name for node in source.nodes]
    assert [node.children for node in gltf.nodes] == [node.children for node in source.nodes]
    counts = [(len(g.meshes), len(g.skins), len(g.materials), len(g.images)) for g in (source, gltf)]
    assert counts[0] == counts[1]
    assert gltf.skins[0].joints == source.skins[0].joints
    assert gltf.skins[0].inverseBindMatrices == source.skins[0].inverseBindMatrices  # none: its nodes' rest
    added = [a.name for a in gltf.animations[len(source.animations) :]]
    assert added == [CLIP_ANIMATION, *(text for _, _, text in SEGMENTS)]
    keyed = {c.target.node for a in gltf.animations[len(source.animations) :] for c in a.channels}
    assert keyed == set(source.skins[0].joints)


@pytest.mark.parametrize("rig_file", RIGS, ids=["cmu-bvh", "xbot-glb"])
def test_the_khronos_validator_finds_no_error_in_the_glb_on_a_rig(tmp_path, gltf_validator, ours, rig_file):  # noqa: F811
    path = save_rig_glb(tmp_path / "on-rig.glb", read_target(rig_file), ours, 20.0, SEGMENTS)
    result = subprocess.run(
        ["node", str(gltf_validator), str(path)], capture_output=True, text=True, timeout=120, check=False
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    for message in report["issues"]["messages"]:
        print(message)
    assert report["issues"]["numErrors"] == 0
    assert report["info"]["animationCount"] == 1 + len(SEGMENTS) and report["info"]["hasSkins"]


@pytest.mark.slow
@needs_blender
@pytest.mark.parametrize("rig_file", RIGS, ids=["cmu-bvh", "xbot-glb"])
def test_blender_makes_fbx_of_the_glb_on_a_rig(tmp_path, ours, rig_file):
    """Read back by Blender's FBX importer, the FBX on a rig puts every bone of the rig where the
    BVH on the same rig puts its joint (in metres)."""
    target = read_target(rig_file)
    path = save_rig_fbx(tmp_path / "on-rig.fbx", target, ours, 20.0, SEGMENTS)
    assert path.read_bytes().startswith(b"Kaydara FBX Binary")
    assert fbx_takes(path) == [CLIP_ANIMATION, *(text for _, _, text in SEGMENTS)]
    bvh = read_bvh(retarget_to_bvh(tmp_path / "on-rig.bvh", ours, rig_file, fps=20.0))
    heads, _ = blender_heads(path, len(ours), bvh.names)
    error = np.abs(heads - bvh.positions() * target.metres_per_unit).max()
    print(f"{rig_file.name}: FBX on the rig through Blender, largest bone head error {error * 1000:.3f} mm")
    assert error < 1e-3


def test_fbx_on_a_rig_without_blender_names_the_package(tmp_path, ours, monkeypatch):
    target = read_target(CMU / "131_01.bvh")
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(
        FileNotFoundError, match=r"^FBX is written by Blender, and no blender is on the PATH: apt-get install blender"
    ):
        save_rig_fbx(tmp_path / "on-rig.fbx", target, ours)
    assert not list(tmp_path.iterdir())


def test_export_writes_the_glb_on_the_x_bot_and_a_format_off_rigs_is_one_line(tmp_path, ours, capsys):
    np.save(tmp_path / "clip.npy", ours)
    assert main(["export", str(tmp_path / "clip.npy"), "--rig", str(XBOT), "--out", str(tmp_path / "x.glb")]) == 0
    written = gl.GLTF2.load(str(tmp_path / "x.glb"))
    assert [node.name for node in written.nodes] == [node.name for node in gl.GLTF2.load(str(XBOT)).nodes]
    assert "root motion" not in [a.name for a in written.animations]
    capsys.readouterr()
    assert main(["export", str(tmp_path / "clip.npy"), "--rig", str(XBOT), "--out", str(tmp_path / "x.npy")]) == 2
    error = capsys.readouterr().err.strip()
    assert "--rig goes with a BVH, GLB or FBX, the formats written on a rig" in error and "\n" not in error
    assert not (tmp_path / "x.npy").exists()


def test_a_characters_mesh_skin_and_material_are_kept_and_move_with_its_joints(tmp_path, ours):
    """Our own GLB as the character (a body mesh skinned by inverse bind matrices, a material):
    its mesh's data come back as they were, and the joints it skins go where its BVH puts them."""
    from m2d2m.motion.files.gltf import save_glb

    save_glb(tmp_path / "ours.glb", ours[:1], T2M)
    source = gl.GLTF2.load(str(tmp_path / "ours.glb"))
    target = read_target(tmp_path / "ours.glb", "smpl")
    gltf = gl.GLTF2.load(str(save_rig_glb(tmp_path / "on-ours.glb", target, ours, 20.0, SEGMENTS)))
    assert [(len(g.meshes), len(g.skins), len(g.materials)) for g in (source, gltf)] == [(1, 1, 1)] * 2
    for accessor in (source.meshes[0].primitives[0].attributes.POSITION, source.skins[0].inverseBindMatrices):
        np.testing.assert_array_equal(accessor_data(gltf, accessor), accessor_data(source, accessor))
    bvh = read_bvh(retarget_to_bvh(tmp_path / "on-ours.bvh", ours, tmp_path / "ours.glb", "smpl", fps=20.0))
    names = [node.name for node in gltf.nodes]
    placed = posed_world(gltf, gltf.animations[len(source.animations)])[:, [names.index(name) for name in bvh.names]][
        ..., :3, 3
    ]
    assert np.abs(placed - bvh.positions()).max() < 1e-4
