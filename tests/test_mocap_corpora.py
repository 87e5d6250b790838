"""Motion capture into corpora (issue 39, §1–§3): your own BVH takes and a captions table as the
``bvh`` corpus, and HumanML3D's registration-free rows as ``humanml3d-public``, from the real CMU
takes of tests/fixtures/cmu-bvh and the real HumanML3D rows of tests/fixtures/humanml3d-public.
Checked against HumanML3D's own rules: its frame counts and slices (index.csv), HumanAct12's
joints taken as they are, the 60-fps takes CMU wrote at 120, and every bad input one line of
the quarantine."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from m2d2m.layout import relative_to_project, shard_urls
from m2d2m.motion.files.bvh_reader import read_bvh
from m2d2m.motion.representation.features import joints_to_features
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.motion.rigs.joint_map import PRESETS, UNITS
from orchestration.cli import main
from orchestration.config import load_config
from pipelines.bvh_corpus import BVH_LAYOUT, list_takes, read_take, stable_split, take_joints
from pipelines.corpora import FrameBounds, Rejected, corpus
from pipelines.features import DataConfig, build_dataset, process_motion
from pipelines.humanml3d_public import frame_step, list_public_rows, read_public_motion
from tests.conftest import HUMANML3D_SAMPLE
from tests.test_bvh_reader import CMU, HUMANML3D_FRAMES
from tests.test_data_pipeline import read_split
from tests.test_joint_map import motionbuilder_release
from tests.test_up_axis import z_up_bvh

PUBLIC = Path(__file__).parent / "fixtures" / "humanml3d-public"
BOUNDS = FrameBounds(40, 200)
# HumanML3D's rows of the fixture takes (its index.csv): id → (take, start, end)
CMU_ROWS = {"013683": ("131_01", 0, 166), "001417": ("131_02", 10, 208), "010943": ("131_03", 0, 184)}


def cmu_joints(take: str) -> np.ndarray:
    return take_joints(CMU / f"{take}.bvh", units="cmu")[0]


# ------------------------------------------------------------------------------ the bvh corpus


def test_the_captions_table_lists_each_motion_once_with_its_captions_in_split_order():
    rows = list_takes(CMU)
    assert [(r["id"], r["split"]) for r in rows] == [
        ("131_01", "train"),
        ("scaled_131_01_0-5000ms", "train"),
        ("131_02_500-10400ms", "val"),
        ("131_03", "test"),
    ]
    assert rows[2]["captions"] == ["A person is dancing", "start walk stop"]
    assert (rows[2]["start"], rows[2]["end"]) == (0.5, 10.4)


def test_a_take_reads_at_humanml3ds_frame_count_and_a_span_as_its_frames():
    for take, frames in HUMANML3D_FRAMES.items():
        assert cmu_joints(take).shape == (frames, 22, 3)
    span = read_take(list_takes(CMU)[2], T2M)
    np.testing.assert_array_equal(span, cmu_joints("131_02")[10:208])


def test_the_unit_is_found_from_the_rigs_height():
    """131_01 in CMU's units and the same take in metres (converted by someone else) read alike,
    each in the unit it stands a person's height in; so does the take in centimetres."""
    in_cmu_units, _ = take_joints(CMU / "131_01.bvh")
    in_metres, _ = take_joints(CMU / "scaled_131_01.bvh")
    np.testing.assert_allclose(in_cmu_units, in_metres, atol=1e-4)
    in_centimetres = read_bvh(CMU / "131_01.bvh", UNITS["cmu"] / UNITS["cm"])
    assert PRESETS["cmu"].metres_per_unit(in_centimetres) == UNITS["cm"]
    assert PRESETS["cmu"].metres_per_unit(in_centimetres, "0.5") == 0.5


def stands(tall: float):
    """CMU's 131_01 rig standing ``tall`` units high."""
    clip = read_bvh(CMU / "131_01.bvh")
    return replace(clip, offsets=clip.offsets * tall / np.linalg.norm(PRESETS["cmu"].stature(clip)))


@pytest.mark.parametrize(
    "clip, units, message",
    [
        (stands(7.0), None, "cannot tell the unit: the rig stands 7 units tall; give --units"),
        (stands(1.7), "furlong", "unknown unit 'furlong'"),
        (stands(1.7), "-1", "metres per unit must be positive"),
    ],
)
def test_a_unit_that_cannot_be_told_is_one_line(clip, units, message):
    with pytest.raises(ValueError, match=message):
        PRESETS["cmu"].metres_per_unit(clip, units)


def test_a_take_standing_along_z_reads_as_the_y_up_one(tmp_path):
    """A rig standing along +Z was refused ("does not stand along +Y in its rest pose"); its
    motion now says where up is (m2d2m/motion/rigs/up_axis.py): 131_01 written Z-up reads as 131_01,
    found in CMU's unit as that is."""
    (tmp_path / "131_01.bvh").write_text(z_up_bvh((CMU / "131_01.bvh").read_text(encoding="utf-8")), encoding="utf-8")
    z_up, mapping = take_joints(tmp_path / "131_01.bvh")
    assert mapping is PRESETS["cmu"] and mapping.standing(read_bvh(tmp_path / "131_01.bvh")).axis == "+Z"
    np.testing.assert_allclose(z_up, take_joints(CMU / "131_01.bvh")[0], atol=1e-5)  # the file's six decimals


def test_a_take_without_a_split_goes_where_its_name_hashes_and_stays_there():
    splits = [stable_split(f"take_{i}") for i in range(2000)]
    shares = {s: splits.count(s) / len(splits) for s in ("train", "val", "test")}
    assert shares["train"] == pytest.approx(0.8, abs=0.03) and shares["test"] == pytest.approx(0.15, abs=0.03)
    assert stable_split("take_7") == splits[7]


def bad_file(folder: Path, name: str, text: str) -> dict:
    (folder / name).write_text(text, encoding="utf-8")
    return next(r for r in list_takes(folder) if r["id"] == Path(name).stem)


HIERARCHY = (CMU / "131_01.bvh").read_text(encoding="utf-8").split("MOTION")[0]
WIDTH = len((CMU / "131_01.bvh").read_text(encoding="utf-8").split("Frame Time:")[1].splitlines()[1].split())


@pytest.mark.parametrize(
    "name, text, reason",
    [
        ("notes.bvh", "these are not motions\n", "not a BVH file (it must start with HIERARCHY"),
        (
            "robot.bvh",
            "HIERARCHY\nROOT Base\n{\n OFFSET 0 0 0\n CHANNELS 3 Xrotation Yrotation Zrotation\n End Site\n {\n"
            "  OFFSET 0 1 0\n }\n}\nMOTION\nFrames: 1\nFrame Time: 0.05\n0 0 0\n",
            "cannot map the rig's joints onto ours: no joint where two legs and a spine part",
        ),
        ("empty.bvh", f"{HIERARCHY}MOTION\nFrames: 0\nFrame Time: 0.008333\n", "no frames"),
        (
            "nan.bvh",
            f"{HIERARCHY}MOTION\nFrames: 1\nFrame Time: 0.008333\n{' '.join(['nan'] * WIDTH)}\n",
            "a frame holds NaN or infinite values",
        ),
    ],
)
def test_a_bad_file_is_one_line_of_the_quarantine(tmp_path, name, text, reason):
    (tmp_path / "captions.csv").write_text(f"file,caption\n{name},a person walks\n", encoding="utf-8")
    row = bad_file(tmp_path, name, text)
    [record] = process_motion(row, BVH_LAYOUT, T2M, BOUNDS, make_mirror=True)
    assert record["status"] == "quarantined" and record["stage"] == "read"
    assert reason in record["reason"] and "\n" not in record["reason"]


def test_a_map_naming_a_joint_the_file_lacks_and_a_file_no_caption_names_are_quarantined(tmp_path):
    shutil.copy(CMU / "131_01.bvh", tmp_path / "131_01.bvh")
    shutil.copy(CMU / "131_03.bvh", tmp_path / "uncaptioned.bvh")
    (tmp_path / "captions.csv").write_text("file,caption\n131_01.bvh,a person walks\n", encoding="utf-8")
    rows = {r["id"]: r for r in list_takes(tmp_path, joint_map="cmu-motionbuilder")}
    [record] = process_motion(rows["131_01"], BVH_LAYOUT, T2M, BOUNDS, make_mirror=False)
    assert record["reason"].startswith("joint map cmu-motionbuilder reads LeftArm, LeftFoot")
    uncaptioned = {**rows["uncaptioned"], "joint_map": None}
    [record] = process_motion(uncaptioned, BVH_LAYOUT, T2M, BOUNDS, make_mirror=False)
    assert record["reason"] == "no caption in captions.csv names this file"


@pytest.mark.parametrize(
    "table, message",
    [
        ("take,text\n", "no column caption, file"),
        ("file,caption,split\n131_01.bvh,a person walks,training\n", "line 2: split 'training' is not one of"),
        ("file,caption,start,end\n131_01.bvh,a person walks,3,2\n", "line 2: end 2 s is not after start 3 s"),
        ("file,caption,start\n131_01.bvh,a person walks,soon\n", "line 2: start 'soon' is not a number"),
        ("file,caption\n131_01.bvh,\n", "line 2: a file and a caption are needed"),
    ],
)
def test_a_table_that_cannot_be_read_is_one_line(tmp_path, table, message):
    (tmp_path / "captions.csv").write_text(table, encoding="utf-8")
    with pytest.raises(ValueError, match=message):
        list_takes(tmp_path)


# ---------------------------------------------------------------------- humanml3d-public


def test_frame_step_follows_where_humanml3ds_rows_end():
    assert frame_step(996, 120.0, [166], 20.0) == 6  # ceil(996 / 6) = 166: a 120-fps take
    assert frame_step(498, 120.0, [166], 20.0) == 3  # half the frames, the same rows: captured at 60
    assert frame_step(996, 120.0, [120, 167], 20.0) == 6  # within a frame of the end still lines up
    assert frame_step(300, 120.0, [166], 20.0) is None  # past the take at either rate


def test_public_rows_read_what_needs_no_registration_and_say_why_not_for_the_rest():
    rows = {r["id"]: r for r in list_public_rows(PUBLIC, bvh=str(CMU))}
    assert set(rows) == {"000000", "000001", *CMU_ROWS}
    assert rows["000000"]["reason"].startswith("needs AMASS: from AMASS's KIT")
    assert rows["000000"]["split"] == "test" and rows["013683"]["split"] == "train"
    for motion_id, (take, start, end) in CMU_ROWS.items():
        assert rows[motion_id]["fps"] == 120.0
        np.testing.assert_array_equal(read_public_motion(rows[motion_id], T2M), cmu_joints(take)[start:end])
    with pytest.raises(Rejected, match="no HumanAct12 joints: P11G01R02F1812T1847A0402.npy is not in"):
        read_public_motion(rows["000001"], T2M)
    without_bvh = {r["id"]: r for r in list_public_rows(PUBLIC)}
    assert without_bvh["013683"]["reason"] == "needs CMU's BVH: pass --bvh <a folder of CMU's BVH>"


def public_copy(tmp_path: Path) -> Path:
    """The fixture with HumanAct12's row given joints: 24 of them as HumanAct12 ships, made from
    HumanML3D's own sample clip (no HumanAct12 file is in the repository)."""
    raw = tmp_path / "HumanML3D-clone"
    shutil.copytree(PUBLIC, raw)
    sample = np.load(HUMANML3D_SAMPLE / "new_joints" / "012314.npy")
    extra = sample[:, [20, 21]] + [0.0, 0.0, 0.08]  # hands, as HumanAct12's joints 22 and 23
    folder = raw / "pose_data" / "humanact12" / "humanact12"
    folder.mkdir(parents=True)
    np.save(folder / "P11G01R02F1812T1847A0402.npy", np.concatenate([sample, extra], axis=1))
    (raw / "HumanML3D" / "texts" / "000001.txt").write_text(
        "a person waves#a/DET person/NOUN wave/VERB#0.0#0.0\n", encoding="utf-8"
    )
    return raw


def test_humanact12_rows_are_its_first_22_joints_as_they_are(tmp_path):
    raw = public_copy(tmp_path)
    row = next(r for r in list_public_rows(raw) if r["id"] == "000001")
    shipped = np.load(raw / "pose_data" / "humanact12" / "humanact12" / "P11G01R02F1812T1847A0402.npy")
    np.testing.assert_array_equal(read_public_motion(row, T2M), shipped[:, :22])  # no slicing, no x negation


def test_a_take_captured_at_60_fps_yet_written_at_120_reads_every_third_frame(tmp_path):
    """131_01 with every other frame dropped and its Frame Time left at 1/120 s: HumanML3D's row
    (0–166) lies past it at 120 fps, so it is read at 60, giving 131_01's own joints."""
    lines = (CMU / "131_01.bvh").read_text(encoding="utf-8").splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("Frame Time")) + 1
    frames = lines[start:][::2]
    lines[start - 2] = f"Frames: {len(frames)}"
    folder = tmp_path / "bvh"
    folder.mkdir()
    (folder / "131_01.bvh").write_text("\n".join(lines[:start] + frames) + "\n", encoding="utf-8")
    row = next(r for r in list_public_rows(PUBLIC, bvh=str(folder)) if r["id"] == "013683")
    assert row["fps"] == 60.0
    np.testing.assert_allclose(read_public_motion(row, T2M), cmu_joints("131_01"), atol=1e-6)


def test_the_motionbuilder_release_gives_the_same_rows_its_t_pose_left_out(tmp_path):
    folder = tmp_path / "mb" / "131"
    folder.mkdir(parents=True)
    (folder / "131_01.bvh").write_text(motionbuilder_release("131_01"), encoding="utf-8")
    row = next(r for r in list_public_rows(PUBLIC, bvh=str(tmp_path / "mb")) if r["id"] == "013683")
    np.testing.assert_array_equal(read_public_motion(row, T2M), cmu_joints("131_01"))


def test_a_take_whose_rows_do_not_line_up_is_quarantined(tmp_path):
    folder = tmp_path / "bvh"
    folder.mkdir()
    lines = (CMU / "131_01.bvh").read_text(encoding="utf-8").splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("Frame Time")) + 1
    lines[start - 2] = "Frames: 300"
    (folder / "131_01.bvh").write_text("\n".join(lines[: start + 300]) + "\n", encoding="utf-8")
    row = next(r for r in list_public_rows(PUBLIC, bvh=str(folder)) if r["id"] == "013683")
    with pytest.raises(
        Rejected, match="does not line up: rows end at frame 166, past the take's 300 frames at 120 fps"
    ):
        read_public_motion(row, T2M)


# ---------------------------------------------------------------------- m2d2m data, end to end


@pytest.mark.slow
def test_data_says_in_one_line_when_a_corpus_does_not_take_an_option(capsys):
    assert main(["data", "--dataset", "synthetic", "--bvh", str(CMU), "--out", "/tmp/never"]) == 2
    assert "--bvh: the synthetic corpus does not take it (it takes none)" in capsys.readouterr().err
    assert main(["data", "--dataset", "bvh", "--raw", str(CMU), "--joint-map", "nope.yaml", "--out", "/tmp/x"]) == 2
    assert (
        "--joint-map: nope.yaml is neither a preset (cmu, cmu-motionbuilder, mixamo, smpl, bandai-namco), auto, nor a file"
        in capsys.readouterr().err
    )


def shard_samples(out: Path) -> dict[str, dict]:
    """Every sample of a built dataset, by key (a split with no shard has none)."""
    splits = [split for split in ("train", "val", "test") if shard_urls(out, split)]
    return {s["__key__"]: s for split in splits for s in read_split(out, split)}


@pytest.mark.slow
def test_the_bvh_fixture_becomes_shards_with_tagged_captions(tmp_path, ray_local):
    raw = tmp_path / "mocap"
    shutil.copytree(CMU, raw)
    (raw / "broken.bvh").write_text("not a bvh\n", encoding="utf-8")
    config = DataConfig(dataset="bvh", raw=str(raw), out=str(tmp_path / "out"), tagger_captions=300)
    manifest = build_dataset(config)
    assert {s: manifest["splits"][s]["originals"] for s in ("train", "val", "test")} == {
        "train": 2,
        "val": 1,
        "test": 1,
    }
    assert manifest["quarantine_reasons"] == {"read: not a BVH file": 1}
    assert manifest["tagger"].startswith("trained on 300 captions of the embedded corpus")
    [line] = (tmp_path / "out" / "quarantine.jsonl").read_text(encoding="utf-8").splitlines()
    assert json.loads(line)["id"] == "broken"
    samples = shard_samples(tmp_path / "out")
    np.testing.assert_allclose(
        samples["131_03"]["motion.npy"], joints_to_features(cmu_joints("131_03")), rtol=1e-5, atol=1e-5
    )
    captions = samples["131_03"]["meta.json"]["captions"]
    assert captions[0]["tokens"][:3] == ["a/DET", "person/NOUN", "is/AUX"]
    assert len(captions[0]["actions"]) == 2  # dancing, jumping around


@pytest.mark.slow
def test_humanml3d_public_becomes_shards_with_humanml3ds_ids_and_mirrors(tmp_path, ray_local, capsys):
    raw = public_copy(tmp_path)
    out = tmp_path / "data" / "humanml3d-public"
    status = main(["data", "--dataset", "humanml3d-public", "--raw", str(raw), "--bvh", str(CMU), "--out", str(out)])
    assert status == 0
    printed = capsys.readouterr().out
    assert "1 needs AMASS" in printed
    manifest = json.loads((out / "manifest.json").read_text(encoding="utf-8"))
    assert manifest["splits"]["train"]["originals"] == 4 and manifest["splits"]["train"]["mirrors"] == 4
    assert manifest["quarantine_reasons"] == {"read: needs AMASS": 1}
    assert manifest["config"]["layout_options"] == {"bvh": relative_to_project(CMU)}
    samples = shard_samples(out)
    assert sorted(samples) == sorted(["000001", "M000001", *CMU_ROWS, *(f"M{i}" for i in CMU_ROWS)])
    for motion_id, (take, start, end) in CMU_ROWS.items():
        assert len(samples[motion_id]["motion.npy"]) == end - start - 1  # features: one frame fewer
    assert samples["001417"]["meta.json"]["captions"][0]["text"] == "A person is dancing"
    assert corpus("humanml3d-public").skeleton is T2M


@pytest.mark.parametrize(
    "overrides, expected",
    [
        (["dataset=humanml3d-public"], "data/humanml3d-public"),
        (["data.dir=/elsewhere", "dataset=humanml3d-public"], "/elsewhere"),
        ([], "data/humanml3d"),
    ],
)
def test_a_config_set_to_another_dataset_reads_that_datasets_data(overrides, expected):
    """`make train-vq DATASET=humanml3d-public VQ_CONFIG=humanml3d` passes --set dataset=…"""
    config = load_config("vq", "humanml3d", overrides)
    assert config["data"]["dir"] == expected
