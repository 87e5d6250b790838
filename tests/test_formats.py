"""Issue 55 §2: one table of output formats (m2d2m/motion/files/formats.py) that everything writing,
listing or checking a format reads, and one sidecar type (m2d2m/motion/files/sidecar.py) written and
read by one module."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pygltflib
import pytest
from PIL import Image

from m2d2m.motion.clip import Motion
from m2d2m.motion.files.bvh_reader import read_bvh
from m2d2m.motion.files.formats import FORMATS, Format, Writing
from m2d2m.motion.files.sidecar import Sidecar, SidecarError
from m2d2m.motion.representation.skeleton import T2M
from orchestration.cli import build_parser, main
from orchestration.generate import plan_output
from orchestration.viewing import load_motion

DOCS = Path(__file__).resolve().parents[1] / "docs" / "generation.md"


@pytest.fixture
def motion(sample_joints: np.ndarray, sample_features: np.ndarray) -> Motion:
    """Two actions of HumanML3D's clip 012314 with a window between them, in place (a root track)."""
    joints = sample_joints[:60].astype(np.float32)
    track = np.zeros((60, 3), np.float32)
    track[:, 0] = joints[:, 0, 0]
    joints = joints - track[:, None]
    texts = ["a person walks", "a person jumps"]
    return Motion(sample_features[:60], joints, 20.0, "t2m", texts, [(0, 25), (30, 60)], root_track=track)


def loads(fmt: str, path: Path, motion: Motion) -> None:
    """What a reader of format ``fmt`` finds in ``path``: the motion's frames and rate."""
    if fmt == "npy":
        assert np.array_equal(np.load(path), motion.joints)
        assert Sidecar.read(path).num_frames == len(motion.joints)
    elif fmt == "bvh":
        clip = read_bvh(path)
        assert len(clip.values) == len(motion.joints) and clip.fps == pytest.approx(motion.fps)
    elif fmt == "glb":
        gltf = pygltflib.GLTF2().load(str(path))
        assert {"a person walks", "a person jumps"} <= {animation.name for animation in gltf.animations}
    elif fmt == "fbx":
        assert path.read_bytes().startswith(b"Kaydara FBX Binary")
    elif fmt == "gif":
        with Image.open(path) as image:
            assert image.n_frames == len(motion.joints)
    elif fmt == "mp4":
        assert path.read_bytes()[4:8] == b"ftyp"
    else:
        raise AssertionError(f"no reader in this test for {fmt}: add one")


# FBX starts Blender (seconds, a process of its own: marked slow as tests/test_gltf.py's Blender tests are)
@pytest.mark.parametrize("fmt", [pytest.param(f, marks=pytest.mark.slow) if f == "fbx" else f for f in FORMATS])
def test_each_formats_writer_writes_a_file_its_reader_loads(tmp_path, motion, fmt):
    lacking = FORMATS[fmt].lacking()
    if lacking is not None:
        pytest.skip(lacking)
    written = motion.save(tmp_path, "clip", (fmt,), size=64)
    assert list(written) == [fmt] and written[fmt] == tmp_path / f"clip.{fmt}"
    loads(fmt, written[fmt], motion)
    # every file it wrote is one it says it may write (what --out and --overwrite account for)
    assert {path.name for path in tmp_path.iterdir()} <= set(FORMATS[fmt].file_names("clip"))


def test_what_a_format_carries_is_what_its_file_holds(tmp_path, motion):
    """The root track goes where the table says it goes, and nowhere else."""
    written = motion.save(tmp_path, "clip", ("npy", "bvh", "glb"))
    keeping = {fmt for fmt in written if FORMATS[fmt].root_motion}
    assert keeping == {"npy", "glb"}
    assert np.array_equal(np.load(tmp_path / "clip.root_motion.npy"), motion.root_track)
    gltf = pygltflib.GLTF2().load(str(written["glb"]))
    assert "root motion" in [animation.name for animation in gltf.animations]
    bvh_root = read_bvh(written["bvh"]).values[:, :3]  # the BVH has no place for it: in place, as delivered
    assert np.allclose(bvh_root, motion.joints[:, 0], atol=1e-5)


def write_csv(motion: Motion, path: Path, writing: Writing) -> Path:
    """A format the table does not ship: the joints as comma-separated rows."""
    np.savetxt(path, motion.joints.reshape(len(motion.joints), -1), delimiter=",", fmt="%.5f")
    return path


CSV = Format("csv", "CSV", write_csv)


def test_a_format_added_to_the_table_is_written_and_offered_everywhere(tmp_path, monkeypatch, capsys, motion):
    """A new export format is a writer and one table entry: Motion.save, --formats, --out and
    `m2d2m export` take it, and the help lists it, with no other edit."""
    monkeypatch.setitem(FORMATS, "csv", CSV)
    written = motion.save(tmp_path / "saved", "clip", ("npy", "csv"))
    assert np.loadtxt(written["csv"], delimiter=",").shape == (60, 66)

    output = plan_output(tmp_path / "one.csv", "motion", None)
    assert (output.name, output.formats, output.one_file) == ("one", ("csv",), True)

    assert main(["export", str(written["npy"]), "--out", str(tmp_path / "exported.csv"), "--no-foot-fix"]) == 0
    assert np.loadtxt(tmp_path / "exported.csv", delimiter=",").shape == (60, 66)

    generate_help = build_parser()._subparsers._group_actions[0].choices["generate"].format_help()
    assert "csv" in generate_help and ".csv" in generate_help
    capsys.readouterr()


def test_an_unknown_format_names_the_tables_formats(tmp_path, motion):
    with pytest.raises(ValueError, match=r"unknown format xyz: choose from npy, bvh, glb, fbx, gif, mp4$"):
        motion.save(tmp_path, "clip", ("xyz",))


def test_the_docs_table_says_what_each_format_carries():
    """docs/generation.md's "Output formats" has a row per format of the table, and says "yes"
    or "no" where the table does (a rig) and names a place for the root motion where it keeps one."""
    text = DOCS.read_text(encoding="utf-8")
    rows = {
        match.group(1): [cell.strip() for cell in match.group(2).split("|")]
        for match in re.finditer(r"^\| `(\w+)` \|(.*)\|$", text, re.MULTILINE)
    }
    assert set(FORMATS) <= set(rows)
    for name, fmt in FORMATS.items():
        _, on_rig, root_motion, actions, loop, needs = rows[name]
        assert on_rig == ("yes" if fmt.on_rig else "no"), name
        assert (root_motion != "no") == bool(fmt.root_motion), name
        assert (actions != "no") == fmt.actions, name
        assert (loop != "no") == fmt.loop, name
        assert bool(needs) == (fmt.needs is not None), name


def test_the_sidecar_is_written_and_read_as_one_type(tmp_path, motion):
    (npy,) = motion.save(tmp_path, "clip", ("npy",)).values()
    sidecar = Sidecar.read(npy)
    assert sidecar == Sidecar(
        "clip.npy", "t2m", 20.0, 60, [(0, 25, "a person walks"), (30, 60, "a person jumps")], {}, "clip.root_motion.npy"
    )
    assert Sidecar.read(tmp_path / "clip.features.npy") == sidecar  # the features' sidecar is the joints'
    again = tmp_path / "again"
    again.mkdir()
    replace(sidecar, loop=True).write(again)
    assert Sidecar.read(again / "clip.npy") == replace(sidecar, loop=True)
    record = json.loads((again / "clip.json").read_text(encoding="utf-8"))
    assert record["joint_names"] == list(T2M.joint_names) and record["segments_end"] == "exclusive"
    # what `m2d2m export` and an edit read: the same record, the root track put back
    loaded = load_motion(npy)
    assert loaded.segments == sidecar.segments and loaded.fps == 20.0
    assert np.allclose(loaded.joints, motion.joints + motion.root_track[:, None])


@pytest.mark.parametrize(
    "broken",
    [{"fps": "fast"}, {"segments": [{"start_frame": 0}]}, {"num_frames": None}],
)
def test_a_sidecar_that_is_not_one_is_one_line(tmp_path, motion, broken):
    (npy,) = motion.save(tmp_path, "clip", ("npy",)).values()
    record = json.loads((tmp_path / "clip.json").read_text(encoding="utf-8"))
    (tmp_path / "clip.json").write_text(json.dumps({**record, **broken}), encoding="utf-8")
    with pytest.raises(SidecarError, match="clip.json: not the sidecar m2d2m writes beside a .npy") as error:
        Sidecar.read(npy)
    assert "\n" not in str(error.value)


def test_the_web_apps_files_come_from_the_table():
    from orchestration.web.generations import FILE_KINDS, WRITTEN

    assert set(WRITTEN) == {name for name, fmt in FORMATS.items() if not fmt.slow}
    assert {made_by for _, made_by in FILE_KINDS.values()} == set(FORMATS)
    assert FILE_KINDS["json"] == ("json", "npy") and FILE_KINDS["features"] == ("features.npy", "npy")


def test_a_served_generation_lists_the_tables_files_and_its_root_track(tmp_path, motion):
    """The web app's answer: a link per format this machine can make, the npy's companions it
    wrote (an in-place clip's root track among them), and the formats an uploaded rig takes."""
    from orchestration.web.generations import Generation, Generations

    motion.save(tmp_path, "motion", ("npy", "bvh", "glb"))
    served = Generations("tiny", track=False)
    generation = Generation("g1", tmp_path, motion, "m2d2m", "run", 0, "", None, None)
    offered = list(served.describe(generation)["files"])
    for_a_rig = [name for name in ("bvh", "glb", "fbx") if FORMATS[name].lacking() is None]
    assert offered[: len(for_a_rig)] == for_a_rig  # first, as the page has always listed them
    assert {"npy", "json", "features", "root_motion", "gif"} <= set(offered)
    assert served.describe(generation)["files"]["root_motion"] == "/api/generations/g1/motion.root_motion.npy"
    assert served.describe(generation)["on_rig"] == ["bvh", "glb", "fbx"]
    (tmp_path / "motion.root_motion.npy").unlink()  # a clip that keeps its path has no track to offer
    assert "root_motion" not in served.describe(generation)["files"]


def test_a_served_glb_comes_on_the_bind_pose_asked_as_the_bvh_does(tmp_path, motion):
    """`?rest=tpose` gives each format a rig takes on a T-pose; before, a GLB's was dropped (the
    skeleton's GLB came back) and an FBX's was kept under the plain name, served to later plain asks."""
    from orchestration.web.generations import Generation, Generations

    served = Generations("tiny", track=False)
    motion.save(tmp_path, "motion", ("npy", "bvh", "glb"))
    # nothing here samples: the generation is put in by hand, as record() would after sampling
    served._kept["g1"] = Generation("g1", tmp_path, motion, "m2d2m", "run", 0, "", None, None)
    plain, tpose = served.file("g1", "motion.glb"), served.file("g1", "motion.glb", rest_pose="tpose")
    assert (plain.name, tpose.name) == ("motion.glb", "motion.tpose.glb")
    assert plain.read_bytes() != tpose.read_bytes()
    assert served.file("g1", "motion.glb") == plain and served.file("g1", "motion.gif", "tpose").name == "motion.gif"


@pytest.mark.slow
def test_the_command_line_reads_the_table_without_numpy_or_a_writers_library():
    """The command line builds its choices from the table before it imports anything: reading it
    must cost no NumPy, torch, Matplotlib or pygltflib (a fresh interpreter, so nothing is loaded)."""
    import subprocess
    import sys

    heavy = ("numpy", "torch", "matplotlib", "pygltflib")
    script = f"import sys, orchestration.cli; print([m for m in {heavy!r} if m in sys.modules])"
    root = Path(__file__).resolve().parents[1]
    result = subprocess.run([sys.executable, "-c", script], cwd=root, capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "[]"
