"""What `m2d2m generate` leaves on disk: formats and ``--out`` checked before any model is loaded,
files that appear whole or not at all, a run folder that says how it ended, a cap on length said
before sampling, and one rigid body in every file (a BVH read back by forward kinematics matches
the ``.npy``)."""

from __future__ import annotations

import json
import os
import signal
import socket
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import orchestration.generate.loading
import orchestration.generate.sampling
from m2d2m.generators.m2d2m.generator import M2D2MGenerator
from m2d2m.motion.clip import Motion
from m2d2m.motion.files import render
from m2d2m.motion.representation.rigid import bone_length_spread, on_rigid_skeleton
from m2d2m.motion.representation.rotations import quat_from_axis_angle
from m2d2m.motion.representation.skeleton import T2M
from orchestration.cli import main
from orchestration.generate import Output, plan_output, save_generation
from tests.helpers import pose_clip

PROMPTS = ["a person walks forward", "a person jumps"]
QUICK = ["--dataset", "tiny", "--ts", "4", "--no-split", "--no-track", "--seconds", "1.2"]


# ------------------------------------------------------------------------ the rigid skeleton
def _rigid_branches_clip(frames: int) -> np.ndarray:
    """A T2M body by forward kinematics whose pelvis and upper-spine children turn together (no
    own rotation at joints 1, 2, 3, 6, 9, 12, 13, 14), so every part of the BVH hierarchy is rigid."""
    rng = np.random.default_rng(5)
    axes = rng.normal(size=(T2M.num_joints, 3))
    axes /= np.linalg.norm(axes, axis=-1, keepdims=True)
    angles = 0.5 * np.sin(np.linspace(0, 2 * np.pi, frames)[:, None] * rng.uniform(0.5, 2.0, T2M.num_joints))
    angles[:, [1, 2, 3, 6, 9, 12, 13, 14]] = 0.0
    local = quat_from_axis_angle(axes[None], angles)
    root = np.stack([np.linspace(0, 2, frames), np.full(frames, 0.9), np.zeros(frames)], axis=-1)
    return T2M.forward_kinematics(local, root)


def test_a_rigid_body_with_stretched_bones_comes_back_exactly():
    rigid = _rigid_branches_clip(40)
    bones = np.zeros_like(rigid)
    bones[:, T2M.bones] = rigid[:, T2M.bones] - rigid[:, T2M.parents[T2M.bones]]
    stretch = np.random.default_rng(0).uniform(0.7, 1.3, size=bones.shape[:2] + (1,))
    stretched = rigid[:, :1] + np.einsum("jb,tbk->tjk", T2M.ancestors, bones * stretch)
    assert bone_length_spread(stretched, T2M)["max"] > 10.0
    assert np.abs(on_rigid_skeleton(stretched, T2M) - rigid).max() < 1e-9


def test_any_clip_gets_constant_lengths_its_root_path_and_its_bone_directions():
    joints = pose_clip(T2M, 50, seed=2) + np.random.default_rng(1).normal(scale=0.03, size=(50, 22, 3))
    fitted = on_rigid_skeleton(joints, T2M)
    lengths = T2M.bone_lengths_of(fitted)
    assert np.abs(lengths - T2M.bone_lengths).max() < 1e-9
    assert bone_length_spread(fitted, T2M)["max"] < 1e-9
    assert np.array_equal(fitted[:, 0], joints[:, 0])
    single = [b for b in T2M.bones if (T2M.parents == T2M.parents[b]).sum() == 1]  # only child of its parent
    before = joints[:, single] - joints[:, T2M.parents[single]]
    after = fitted[:, single] - fitted[:, T2M.parents[single]]
    cosine = (before * after).sum(-1) / np.linalg.norm(before, axis=-1) / np.linalg.norm(after, axis=-1)
    assert cosine.min() > 1 - 1e-12
    for joint in (0, 9):  # a branching joint and its children keep one shape
        group = [joint, *np.flatnonzero(T2M.parents == joint)]
        distances = np.linalg.norm(fitted[:, group, None] - fitted[:, None, group], axis=-1)
        assert np.ptp(distances, axis=0).max() < 1e-9


def test_the_spread_is_each_bones_standard_deviation_in_millimetres():
    joints = np.repeat(_rigid_branches_clip(1), 4, axis=0)
    joints[:, 21] += (joints[:, 21] - joints[:, 19]) * np.array([0.1, -0.1, 0.1, -0.1])[:, None] / T2M.bone_lengths[21]
    spread = bone_length_spread(joints, T2M)  # the right wrist's bone: ±0.1 m → σ = 100 mm
    assert spread["max"] == pytest.approx(100.0) and spread["mean"] == pytest.approx(100.0 / 21)


# ---------------------------------------------------------------- a BVH read back by FK
def _rotation(axis: str, degrees: float) -> np.ndarray:
    a = np.radians(degrees)
    c, s = np.cos(a), np.sin(a)
    i, j = {"X": (1, 2), "Y": (2, 0), "Z": (0, 1)}[axis]
    matrix = np.eye(3)
    matrix[i, i], matrix[i, j], matrix[j, i], matrix[j, j] = c, -s, s, c
    return matrix


def read_bvh(path: Path) -> dict[str, np.ndarray]:
    """Joint positions (T, 3) by name: HIERARCHY offsets and channels, then forward kinematics of
    the MOTION rows, each joint's rotations composed in the order its channels are written."""
    tokens = path.read_text().split()
    assert tokens[0] == "HIERARCHY"
    nodes: list[dict] = []
    open_nodes: list[int] = []
    at = 1
    while tokens[at] != "MOTION":
        token = tokens[at]
        if token in ("ROOT", "JOINT", "End"):
            nodes.append(
                {
                    "name": tokens[at + 1] if token != "End" else None,
                    "parent": open_nodes[-1] if open_nodes else None,
                    "channels": [],
                }
            )
            at += 2
        elif token == "{":
            open_nodes.append(len(nodes) - 1)
            at += 1
        elif token == "}":
            open_nodes.pop()
            at += 1
        elif token == "OFFSET":
            nodes[open_nodes[-1]]["offset"] = np.array(tokens[at + 1 : at + 4], dtype=float)
            at += 4
        elif token == "CHANNELS":
            count = int(tokens[at + 1])
            nodes[open_nodes[-1]]["channels"] = tokens[at + 2 : at + 2 + count]
            at += 2 + count
        else:
            raise AssertionError(f"unexpected BVH token {token!r}")
    frames = int(tokens[at + 2])  # MOTION Frames: n Frame Time: dt
    rows = np.array(tokens[at + 6 :], dtype=float).reshape(frames, -1)
    positions: dict[str, list[np.ndarray]] = {}
    for row in rows:
        column, world = 0, {}
        for index, node in enumerate(nodes):
            if node["name"] is None:
                continue
            rotation, translation = np.eye(3), np.zeros(3)
            for channel in node["channels"]:
                if channel.endswith("position"):
                    translation["XYZ".index(channel[0])] = row[column]
                else:
                    rotation = rotation @ _rotation(channel[0], row[column])
                column += 1
            if node["parent"] is None:
                world[index] = (rotation, node["offset"] + translation)
            else:
                parent_rotation, parent_position = world[node["parent"]]
                world[index] = (parent_rotation @ rotation, parent_position + parent_rotation @ node["offset"])
            positions.setdefault(node["name"], []).append(world[index][1])
    return {name: np.array(values) for name, values in positions.items()}


def test_every_joint_of_a_generated_bvh_is_where_the_npy_has_it(trained_project, monkeypatch, capsys):
    monkeypatch.chdir(trained_project)
    out = trained_project / "fk"
    code = main(["generate", *PROMPTS, *QUICK, "--formats", "npy", "bvh", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    joints = np.load(out / "motion.npy")
    sidecar = json.loads((out / "motion.json").read_text(encoding="utf-8"))
    read_back = read_bvh(out / "motion.bvh")
    from_bvh = np.stack([read_back[name] for name in sidecar["joint_names"]], axis=1)
    assert from_bvh.shape == joints.shape
    assert np.linalg.norm(from_bvh - joints, axis=-1).max() < 1e-3  # metres: under 1 mm, every joint and frame
    assert bone_length_spread(joints, T2M)["max"] < 0.01  # the file's body is rigid (float32 rounding)
    quality = sidecar["quality"]  # the decoded motion's spread, before the rigid skeleton
    assert quality["bone_length_std_mm_max"] >= quality["bone_length_std_mm_mean"] > 0.01


# --------------------------------------------------------------- checked before any loading
def _loading_fails(monkeypatch) -> None:
    def refuse(*_, **__):
        raise AssertionError("the model was loaded before the arguments were checked")

    monkeypatch.setattr(orchestration.generate.loading, "load_generator", refuse)


@pytest.mark.parametrize(
    "arguments, message",
    [
        (["--formats", "xyz"], "unknown format xyz: choose from npy, bvh, glb, fbx, gif, mp4"),
        (["--formats", "gif", "mp4"], "mp4 needs ffmpeg"),
        (["--out", "notes.txt"], "--out notes.txt is an existing file, not a folder"),
        (["--out", "clip.gif", "--formats", "bvh"], "--out clip.gif names one .gif file; drop --formats"),
        (["--out", "made.gif"], "--out made.gif is a folder"),
        (["--name", "a/b"], "--name must be a plain file name"),
        (["--out", "clip.obj"], "--out clip.obj names a .obj file, a format m2d2m does not write (.npy, .bvh"),
    ],
)
def test_bad_outputs_are_one_line_before_loading(tmp_path, monkeypatch, capsys, arguments, message):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(render, "_find_ffmpeg", lambda: None)
    (tmp_path / "notes.txt").write_text("keep me\n")
    (tmp_path / "made.gif").mkdir()
    _loading_fails(monkeypatch)
    code = main(["generate", "a person jumps", "--dataset", "tiny", "--no-track", *arguments])
    err = capsys.readouterr().err.strip()
    assert code == 2 and message in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "runs").exists() and (tmp_path / "notes.txt").read_text() == "keep me\n"
    assert not (tmp_path / "clip.obj").exists()  # it was once made into a folder of npy, BVH and GIF


def test_the_length_cap_is_one_line_before_sampling(trained_project, monkeypatch, capsys):
    monkeypatch.chdir(trained_project)
    monkeypatch.setattr(M2D2MGenerator, "generate", lambda *_: pytest.fail("sampled past the cap"))
    code = main(["generate", *PROMPTS, *QUICK, "--max-seconds", "2"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert "2.4 s of motion in 2 action(s), over the 2-s cap" in err and "--max-seconds 3" in err


# -------------------------------------------------------------------- what ends on disk
def test_out_with_a_format_suffix_is_one_file(trained_project, monkeypatch, capsys):
    monkeypatch.chdir(trained_project)
    target = trained_project / "clips" / "clip.gif"
    assert main(["generate", PROMPTS[0], *QUICK, "--out", str(target)]) == 0, capsys.readouterr().err
    assert target.is_file() and sorted(p.name for p in target.parent.iterdir()) == ["clip.gif"]
    with Image.open(target) as gif:
        assert gif.n_frames == 24 and gif.info["duration"] == 50 and gif.info["loop"] == 0


def test_a_run_folder_says_finished_or_failed(trained_project, monkeypatch, capsys):
    monkeypatch.chdir(trained_project)
    runs = trained_project / "runs" / "tiny" / "generate"
    before = set(runs.iterdir()) if runs.exists() else set()
    assert main(["generate", PROMPTS[0], *QUICK, "--formats", "npy"]) == 0, capsys.readouterr().err
    (finished,) = set(runs.iterdir()) - before
    info = json.loads((finished / "run.json").read_text(encoding="utf-8"))
    assert info["status"] == "finished" and info["files"]["npy"].endswith("motion.npy")
    assert info["quality"]["bone_length_std_mm_mean"] > 0 and info["actions"] == [PROMPTS[0]]

    def broken_encoder(*_, **__):
        raise RuntimeError("ffmpeg failed writing motion.mp4: out of disk")

    monkeypatch.setattr("m2d2m.motion.files.render.render_motion", broken_encoder)
    code = main(["generate", PROMPTS[0], *QUICK, "--formats", "npy", "gif"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "out of disk" in err and len(err.splitlines()) == 1
    (failed,) = set(runs.iterdir()) - before - {finished}
    info = json.loads((failed / "run.json").read_text(encoding="utf-8"))
    assert info["status"] == "failed" and "out of disk" in info["error"]
    assert (failed / "motion.npy").exists() and not (failed / "motion.gif").exists()


def test_an_interrupted_animation_leaves_the_old_file_or_none(tmp_path):
    joints = pose_clip(T2M, 12, seed=0)

    def stop_at_frame_5(t: int) -> None:
        if t == 5:
            raise KeyboardInterrupt

    for name in ("new.gif", "old.gif"):
        if name == "old.gif":
            (tmp_path / name).write_bytes(b"an earlier file")
        with pytest.raises(KeyboardInterrupt):
            render.render_motion(joints, tmp_path / name, T2M, size=64, progress=stop_at_frame_5)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.gif"]
    assert (tmp_path / "old.gif").read_bytes() == b"an earlier file"


def test_sigterm_while_rendering_marks_the_run_failed_and_leaves_no_gif(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    joints = pose_clip(T2M, 12, seed=0)
    motion = Motion(
        np.zeros((12, T2M.feature_dim), np.float32), joints, 20.0, "t2m", ["a person jumps"], [(0, 12)]
    ).on_rigid_skeleton()
    real = render.render_motion

    def killed_at_frame_3(*args, progress=None, **options):
        def tick(t: int) -> None:
            if t == 3:
                os.kill(os.getpid(), signal.SIGTERM)

        return real(*args, progress=tick, **{**options, "size": 64})

    monkeypatch.setattr("m2d2m.motion.files.render.render_motion", killed_at_frame_3)
    with pytest.raises(KeyboardInterrupt):
        save_generation(motion, Output(None, "motion", ("npy", "gif")), ["a person jumps"], "tiny", track=False)
    (run,) = (tmp_path / "runs" / "tiny" / "generate").iterdir()
    assert json.loads((run / "run.json").read_text(encoding="utf-8"))["status"] == "failed"
    assert sorted(p.name for p in run.iterdir()) == ["motion.features.npy", "motion.json", "motion.npy", "run.json"]


@pytest.mark.parametrize("out", ["v1.2", "runs/take.3"])
def test_a_folder_name_with_a_dot_is_still_a_folder(out):
    assert plan_output(out, "motion", None).directory == Path(out)


def test_an_existing_folder_named_like_a_file_is_used(tmp_path):
    (tmp_path / "takes.final").mkdir()
    assert plan_output(tmp_path / "takes.final", "motion", None).directory == tmp_path / "takes.final"


@pytest.mark.parametrize("server", ["refuses", "never answers"])
def test_a_dead_tracking_server_costs_one_warning_and_keeps_the_files(tmp_path, monkeypatch, capsys, server):
    """Issue 38, item 4: with MLFLOW_TRACKING_URI at a dead server `generate` hung (killed after
    150 s in MLflow's retries) although its files were written."""
    monkeypatch.chdir(tmp_path)
    joints = pose_clip(T2M, 12, seed=0)
    motion = Motion(
        np.zeros((12, T2M.feature_dim), np.float32), joints, 20.0, "t2m", ["a person jumps"], [(0, 12)]
    ).on_rigid_skeleton()
    with socket.socket() as dead:
        dead.bind(("127.0.0.1", 0))
        if server == "never answers":
            dead.listen()  # connections wait in its backlog; nothing is ever read or written
        port = dead.getsockname()[1]
        if server == "refuses":
            dead.close()
        monkeypatch.setenv("MLFLOW_TRACKING_URI", f"http://127.0.0.1:{port}")
        files, run_id = save_generation(motion, Output(None, "motion", ("npy",)), ["a person jumps"], "tiny")
    assert run_id is None and files["npy"].is_file()
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"warning: the MLflow server at http://127.0.0.1:{port} did not answer in 5 s")
    assert line.endswith(f"the generation is not tracked, its files are in {files['npy'].parent}")
    info = json.loads((files["npy"].parent / "run.json").read_text(encoding="utf-8"))
    assert info["status"] == "finished" and info["mlflow_run_id"] is None


# --------------------------------------------------- all or nothing: never two clips in one place
def _sampling_a_fixed_clip(monkeypatch, frames: int = 12) -> None:
    """`m2d2m generate` without a model: loading gives nothing and sampling a fixed clip."""
    motion = Motion(
        np.zeros((frames, T2M.feature_dim), np.float32),
        pose_clip(T2M, frames, seed=0),
        20.0,
        "t2m",
        ["a person jumps"],
        [(0, frames)],
        {"method": "fixed"},
    ).on_rigid_skeleton()
    monkeypatch.setattr(orchestration.generate.loading, "load_generator", lambda *_, **__: None)
    monkeypatch.setattr(orchestration.generate.sampling, "generate", lambda *_, **__: motion)


def _files(folder: Path) -> dict[str, bytes]:
    return {path.name: path.read_bytes() for path in sorted(folder.iterdir())}


FIXED = ["generate", "a person jumps", "--no-track"]


def test_generate_into_a_folder_of_an_earlier_clip_is_refused_or_replaced_whole(tmp_path, monkeypatch, capsys):
    """Issue 53, finding 5: `generate --out DIR` into a folder holding an earlier clip replaced
    npy/json/bvh/gif and left the old GLB beside them: one folder, two clips."""
    monkeypatch.chdir(tmp_path)
    _sampling_a_fixed_clip(monkeypatch)
    out = tmp_path / "clip"
    assert main([*FIXED, "--out", str(out), "--formats", "npy", "bvh", "glb"]) == 0, capsys.readouterr().err
    before = _files(out)
    assert sorted(before) == ["motion.bvh", "motion.features.npy", "motion.glb", "motion.json", "motion.npy"]
    capsys.readouterr()

    assert main([*FIXED, "--out", str(out), "--formats", "npy", "bvh"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"m2d2m generate: error: --out {out} holds an earlier result (5 files); give a new folder, "
        "or --overwrite to replace the folder and every file in it"
    )
    assert _files(out) == before

    assert main([*FIXED, "--out", str(out), "--formats", "npy", "bvh", "--overwrite"]) == 0
    assert sorted(_files(out)) == ["motion.bvh", "motion.features.npy", "motion.json", "motion.npy"]  # no old GLB
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip"]  # no temporary folder left


def test_a_failed_overwrite_leaves_the_earlier_clip_as_it_was(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    _sampling_a_fixed_clip(monkeypatch)
    out = tmp_path / "clip"
    assert main([*FIXED, "--out", str(out), "--formats", "npy"]) == 0, capsys.readouterr().err
    before = _files(out)

    def broken_encoder(*_, **__):
        raise RuntimeError("ffmpeg failed writing motion.gif: out of disk")

    monkeypatch.setattr("m2d2m.motion.files.render.render_motion", broken_encoder)
    assert main([*FIXED, "--out", str(out), "--formats", "bvh", "gif", "--overwrite"]) == 2
    assert "out of disk" in capsys.readouterr().err
    assert _files(out) == before and sorted(p.name for p in tmp_path.iterdir()) == ["clip"]


def test_a_folder_of_folders_or_the_working_folder_is_never_replaced(tmp_path, monkeypatch, capsys):
    _sampling_a_fixed_clip(monkeypatch)
    (tmp_path / "project" / "data").mkdir(parents=True)
    (tmp_path / "clips").mkdir()
    (tmp_path / "clips" / "notes.txt").write_text("keep me\n")
    monkeypatch.chdir(tmp_path)
    assert main([*FIXED, "--out", "project", "--overwrite"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("--out project holds folders (data), not an earlier result's files; give a new folder")
    monkeypatch.chdir(tmp_path / "clips")
    assert main([*FIXED, "--out", ".", "--overwrite"]) == 2
    assert capsys.readouterr().err.strip().endswith("--out . is the working folder; give a new folder")
    assert (tmp_path / "clips" / "notes.txt").read_text() == "keep me\n" and (tmp_path / "project" / "data").is_dir()


def test_an_empty_folder_made_for_the_clip_is_taken(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    _sampling_a_fixed_clip(monkeypatch)
    (tmp_path / "takes.v2").mkdir()
    assert main([*FIXED, "--out", "takes.v2", "--formats", "bvh"]) == 0, capsys.readouterr().err
    assert sorted(_files(tmp_path / "takes.v2")) == ["motion.bvh"]


@pytest.mark.parametrize(
    "verb, out, written",
    [("generate", "clip.glb", b"glTF"), ("export", "clip.glb", b"glTF"), ("render", "clip.gif", b"GIF8")],
)
def test_an_existing_file_is_refused_unless_overwrite(tmp_path, monkeypatch, capsys, verb, out, written):
    """Issue 53, finding 5: `--out existing.glb` and `export --out existing.glb` overwrote,
    though docs/generation.md said an existing file is refused."""
    monkeypatch.chdir(tmp_path)
    _sampling_a_fixed_clip(monkeypatch)
    np.save(tmp_path / "take.npy", pose_clip(T2M, 12, seed=1).astype(np.float32))
    command = [*FIXED] if verb == "generate" else [verb, "take.npy"]
    (tmp_path / out).write_bytes(b"an earlier file")
    assert main([*command, "--out", out]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"m2d2m {verb}: error: {out} exists; give another name, or --overwrite to replace it"
    assert (tmp_path / out).read_bytes() == b"an earlier file"
    assert main([*command, "--out", out, "--overwrite"]) == 0, capsys.readouterr().err
    assert (tmp_path / out).read_bytes()[:4] == written
    assert sorted(p.name for p in tmp_path.iterdir()) == [out, "take.npy"]


def test_export_over_an_npy_leaves_none_of_the_earlier_ones_companions(tmp_path, monkeypatch, capsys):
    """An in-place export writes `clip.root_motion.npy` beside `clip.npy`; an export over it that
    keeps the path makes none, and the old one would have been read as this clip's."""
    monkeypatch.chdir(tmp_path)
    np.save(tmp_path / "take.npy", pose_clip(T2M, 12, seed=1).astype(np.float32))
    assert main(["export", "take.npy", "--out", "clip.npy", "--root", "in-place"]) == 0, capsys.readouterr().err
    assert (tmp_path / "clip.root_motion.npy").is_file()
    assert main(["export", "take.npy", "--out", "clip.npy"]) == 2
    assert "clip.npy exists; give another name, or --overwrite" in capsys.readouterr().err
    assert main(["export", "take.npy", "--out", "clip.npy", "--overwrite"]) == 0, capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.json", "clip.npy", "take.npy"]
    assert "root_motion" not in json.loads((tmp_path / "clip.json").read_text(encoding="utf-8"))
