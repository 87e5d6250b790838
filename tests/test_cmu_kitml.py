"""CMU's motion capture with KIT-ML's captions as the ``cmu-kitml`` corpus (pipelines/cmu_kitml.py),
on the two real takes of tests/fixtures/cmu-kitml: each read at the rate it was captured at
(recovered from KIT-ML's duration, 60 fps for 106_22 though its file says 120), its T-pose left
out, bones rigid, feet on the studio's floor, features that decode back; KIT-ML's captions, CMU's
description where it is one, KIT-ML's splits; every entry that cannot be read one quarantine line
(KIT's own take, a missing BVH, a duration that lines up with no rate, a take too long); and
`m2d2m data` building the fixture's shards."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from m2d2m.motion.files.bvh_reader import read_bvh, read_bvh_header
from m2d2m.motion.representation.features import canonicalize, features_to_joints, joints_to_features
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.motion.rigs.joint_map import PRESETS, UNITS, joint_map_for
from orchestration.cli import main
from pipelines.bvh_corpus import stable_split, take_joints
from pipelines.cmu_kitml import (
    ABOUT,
    CMU_KITML_LAYOUT,
    FRAME_BOUNDS,
    capture_rate,
    cmu_description,
    list_cmu_kitml,
    read_index_text,
    read_take,
    read_take_captions,
)
from pipelines.corpora import FrameBounds, corpus
from pipelines.features import process_motion
from tests.test_mocap_corpora import shard_samples

FIXTURE = Path(__file__).parent / "fixtures" / "cmu-kitml"
ANNOTATIONS = FIXTURE / "kitml" / "annotations.json"
BOUNDS = FrameBounds(*FRAME_BOUNDS)
# The fixture's takes: KIT-ML's id → (take, KIT-ML's duration in s, the rate it was captured at)
TAKES = {"03474": ("102_01", 2.308, 120), "03655": ("106_22", 3.3, 60)}


def bvh(take: str) -> Path:
    return FIXTURE / "data" / take.split("_")[0] / f"{take}.bvh"


def joints_of(motion_id: str) -> np.ndarray:
    take, _, rate = TAKES[motion_id]
    return take_joints(bvh(take), units="cmu", fps=rate)[0]


def rows_by_id(raw: Path = FIXTURE, annotations: Path | None = ANNOTATIONS) -> dict[str, dict]:
    return {row["id"]: row for row in list_cmu_kitml(raw, None if annotations is None else str(annotations))}


# ------------------------------------------------------------------------------ reading a take


@pytest.mark.parametrize("motion_id", TAKES)
def test_a_take_reads_at_its_capture_rate_as_many_frames_as_kitmls_duration(motion_id):
    """The files say 120 fps; 102_01's 277 frames of motion last KIT-ML's 2.308 s at 120, 106_22's
    198 its 3.3 s at 60. Every 6th (3rd) frame makes 20 fps: the duration × 20, rounded up; 106_22
    read at the 120 its file says would last 1.65 s, half its length."""
    take, duration, rate = TAKES[motion_id]
    header = read_bvh_header(bvh(take))
    assert header.frame_time == pytest.approx(1 / 120, rel=1e-4)
    frames = header.frames - 1  # the T-pose
    assert round(frames / duration) == rate and capture_rate(frames, duration) == rate
    row = rows_by_id()[motion_id]
    assert row["fps"] == rate and row["take"] == take
    joints = read_take(row, T2M)
    assert joints.shape == (math.ceil(frames / (rate // T2M.fps)), 22, 3)
    assert len(joints) == math.ceil(duration * T2M.fps)
    np.testing.assert_array_equal(joints, joints_of(motion_id))


@pytest.mark.parametrize("motion_id", TAKES)
def test_the_t_pose_frame_is_left_out_and_lengths_are_metres(motion_id):
    """cgspeed's MotionBuilder-friendly release opens every take with a T-pose (wrists level with
    the shoulders); the motion's first frame has the arms down. In metres, the person's head is
    1.1–1.3 m over the toes (CMU's head joint is the skull's base) and the studio's floor is y = 0."""
    take, _, _ = TAKES[motion_id]
    clip = read_bvh(bvh(take))
    assert joint_map_for(clip) is PRESETS["cmu-motionbuilder"] and PRESETS["cmu-motionbuilder"].rest_frames == 1
    t_pose = clip.positions()[0]
    hand, arm = clip.names.index("LeftHand"), clip.names.index("LeftArm")
    assert abs(t_pose[hand, 1] - t_pose[arm, 1]) * UNITS["cmu"] < 0.1  # about level
    joints = joints_of(motion_id)
    wrists = [T2M.joint_names.index(f"{side}_wrist") for side in ("left", "right")]
    shoulders = [T2M.joint_names.index(f"{side}_shoulder") for side in ("left", "right")]
    assert (joints[0, wrists, 1] < joints[0, shoulders, 1] - 0.2).all()
    tall = np.median(joints[:, T2M.head_joint, 1] - joints[:, [10, 11], 1].min(axis=1))
    assert 1.1 < tall < 1.3
    assert 0.0 < joints[..., 1].min() < 0.05
    assert UNITS["cmu"] == pytest.approx(0.056444, abs=1e-6)


@pytest.mark.parametrize("motion_id", TAKES)
def test_its_bones_keep_their_lengths(motion_id):
    """Every n-th frame of forward kinematics: each bone its rig's length in every frame."""
    spread = np.ptp(T2M.bone_lengths_of(joints_of(motion_id)), axis=0)
    assert spread.max() < 1e-5


@pytest.mark.parametrize("motion_id", TAKES)
def test_its_feet_touch_the_floor_in_stance(motion_id):
    """On the clip's floor (its lowest joint), a foot in stance (ankle and toe slower than 0.3 m/s)
    rests within 10 cm of it: CMU's feet differ by a few centimetres between sides, and 106_22
    rocks on a heel with its toes up; 102_01's swinging feet rise 30 cm and more. Every frame has
    a foot on the floor (within 10 cm)."""
    body = canonicalize(joints_of(motion_id))
    assert body[..., 1].min() == pytest.approx(0.0, abs=1e-9)
    for ankle, toe in ((7, 10), (8, 11)):
        speed = np.linalg.norm(np.diff(body[:, [ankle, toe]], axis=0), axis=-1).max(axis=1) * T2M.fps
        stance = speed < 0.3
        assert stance.sum() >= 10
        assert body[1:, [ankle, toe], 1].min(axis=1)[stance].max() < 0.1
    assert body[:, [7, 8, 10, 11], 1].min(axis=1).max() < 0.1
    if motion_id == "03474":  # starts to run
        assert body[:, [10, 11], 1].max() > 0.3


@pytest.mark.parametrize("motion_id", TAKES)
def test_its_features_decode_back_to_its_joints(motion_id):
    """HumanML3D's 263-d features decode to the take on HumanML3D's skeleton, losing the last frame."""
    joints = joints_of(motion_id)
    features = joints_to_features(joints)
    assert features.shape == (len(joints) - 1, 263) and np.isfinite(features).all()
    np.testing.assert_allclose(np.asarray(features_to_joints(features)), canonicalize(joints)[:-1], atol=1e-5)


@pytest.mark.parametrize(
    "frames, duration, rate",
    [
        (277, 2.308, 120),  # the fixture's takes
        (198, 3.3, 60),
        (531, 8.85, 60),  # real takes of the mirror, their headers read: 107_01
        (507, 4.225, 120),  # 122_13
        (1165, 19.417, 60),  # 141_15
        (470, 3.917, 120),  # 83_41
        (276, 2.308, 120),  # a frame off still lines up
        (279, 2.308, None),  # two do not
        (198, 2.5, None),  # 79.2 fps
    ],
)
def test_the_capture_rate_is_the_one_the_frames_last_kitmls_duration_at(frames, duration, rate):
    assert capture_rate(frames, duration) == rate


# ------------------------------------------------------------------------------ the corpus's rows


def test_the_rows_are_kitmls_entries_in_its_splits_with_their_captions():
    """Every entry but the mirrors (the pipeline makes them), in split then file order: the two
    takes, KIT's own take, the made-up entry (no split file lists it: its hash says) and the
    missing take; 102_01 gets CMU's description as a second caption, 106_22 none ("clean")."""
    rows = list_cmu_kitml(FIXTURE, str(ANNOTATIONS))
    assert [(row["id"], row["split"]) for row in rows] == [
        ("00001", "train"),
        ("03474", "train"),
        ("03655", "train"),
        ("99001", stable_split("99001")),
        ("02248", "test"),
    ]
    by_id = {row["id"]: row for row in rows}
    assert read_take_captions(by_id["03474"]) == [
        {"text": "A human starts to run.", "start": 0.0, "end": 0.0, "tokens": None},
        {"text": "right wide turn", "start": 0.0, "end": 0.0, "tokens": None},
    ]
    assert [c["text"] for c in read_take_captions(by_id["03655"])] == ["a fat person high fives"]
    assert json.loads(json.dumps(rows)) == rows  # rows travel to Ray tasks as JSON


def test_annotations_default_to_kitml_under_raw_and_may_be_a_folder_or_a_tmr_clone(tmp_path):
    expected = rows_by_id()
    assert rows_by_id(annotations=None) == expected
    assert rows_by_id(annotations=ANNOTATIONS.parent) == expected
    clone = tmp_path / "TMR"
    shutil.copytree(ANNOTATIONS.parent, clone / "datasets" / "annotations" / "kitml")
    assert rows_by_id(annotations=clone) == expected


def test_a_take_is_found_by_its_name_in_any_subfolder(tmp_path):
    """An older layout of the mirror (``128/128_01.bvh``), or all files in one folder."""
    raw = tmp_path / "cmu"
    (raw / "all").mkdir(parents=True)
    for take, _, _ in TAKES.values():
        shutil.copy(bvh(take), raw / "all" / f"{take}.bvh")
    rows = rows_by_id(raw)
    assert rows["03655"]["path"] == str(raw / "all" / "106_22.bvh") and rows["03655"]["fps"] == 60
    assert [c["text"] for c in rows["03474"]["captions"]] == ["A human starts to run."]  # no index text here


@pytest.mark.parametrize(
    "line, caption",
    [
        ("RightWideTurn", "right wide turn"),
        ("walk, shake hands (2 subjects - subject A)", "walk, shake hands"),
        ("LeftTightTurn         CleanedGRS", "left tight turn"),
        ("Left_Lunges001", "left lunges"),
        ("playground - climb, hang, swing", "playground - climb, hang, swing"),
        ("Walk With Arms Out,  balancing", "walk with arms out, balancing"),
        ("clean", None),
        ("Unknown", None),
        ("bad AMC", None),
        ("106_15.amc", None),
        ("Motorcycle", None),
        ("MotorCyclePose", None),
        ("Range of Motion", None),
        ("rangeOfMotion_01", None),
        ("Subject calibration", None),
        ("T-Pose", None),
        ("15.5 lbs", None),
        ("360", None),
        ("lost marker", None),
        ("", None),
    ],
)
def test_cmus_line_is_a_caption_where_it_describes_the_motion(line, caption):
    assert cmu_description(line) == caption


def test_cmus_index_text_is_read_by_take():
    index = read_index_text(FIXTURE / "cmu-mocap-index-text.txt")
    assert index["102_01"] == "RightWideTurn" and index["106_22"] == "clean" and index["102_31"].endswith("right)")
    assert len(index) == 33 + 34


def quarantined(row: dict) -> dict:
    [record] = process_motion(row, CMU_KITML_LAYOUT, T2M, BOUNDS, make_mirror=True)
    assert record["status"] == "quarantined" and "\n" not in record["reason"]
    return record


@pytest.mark.parametrize(
    "motion_id, reason",
    [
        ("00001", "not CMU's motion: KIT/4/WalkingStraightForward01_poses is KIT's own (its mirror M00001 with it)"),
        ("02248", "no BVH: no 128_01.bvh under tests/fixtures/cmu-kitml (KIT-ML's CMU/128/128_01_poses)"),
        (
            "99001",
            "does not line up: 198 frames in KIT-ML's 2.5 s is 79.2 fps, more than a frame from 120 or 60 fps "
            "(at 120 fps they last 1.65 s, at 60 fps they last 3.3 s)",
        ),
    ],
)
def test_an_entry_that_cannot_be_read_is_one_quarantine_line(motion_id, reason):
    record = quarantined(rows_by_id()[motion_id])
    assert record["key"] == motion_id and record["stage"] == "read" and record["reason"] == reason


def test_a_take_longer_than_the_bounds_is_quarantined_not_cut(tmp_path):
    """A caption tells the whole take ("walks, bends down and continues walking"), so a piece of a
    long take could lack what it says: 102_01's motion five times over (11.5 s) is one line."""
    raw = tmp_path / "cmu"
    shutil.copytree(FIXTURE, raw)
    lines = bvh("102_01").read_text(encoding="utf-8").splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("Frame Time")) + 1
    motion = lines[start + 1 :] * 5
    lines[start - 2] = f"Frames: {len(motion) + 1}"
    (raw / "data" / "102" / "102_01.bvh").write_text("\n".join(lines[: start + 1] + motion) + "\n", encoding="utf-8")
    entries = json.loads((raw / "kitml" / "annotations.json").read_text(encoding="utf-8"))
    entries["03474"]["duration"] = round(len(motion) / 120, 3)
    (raw / "kitml" / "annotations.json").write_text(json.dumps(entries), encoding="utf-8")
    row = rows_by_id(raw, raw / "kitml" / "annotations.json")["03474"]
    assert row["fps"] == 120
    record = quarantined(row)
    assert (record["stage"], record["reason"]) == ("validate", "too many frames: 230 >= 200")  # 231 frames at 20 fps


@pytest.mark.parametrize(
    "change, error, message",
    [
        ("no annotations", FileNotFoundError, "no KIT-ML annotations: pass --annotations <a clone of"),
        ("no splits", FileNotFoundError, "no KIT-ML split file(s) train.txt, val.txt, test.txt"),
        ("not JSON", ValueError, "not KIT-ML's annotations.json"),
        ("a list", ValueError, "not KIT-ML's annotations.json (an object of ids is expected)"),
    ],
)
def test_annotations_that_cannot_be_read_are_one_line(tmp_path, change, error, message):
    raw = tmp_path / "cmu"
    shutil.copytree(FIXTURE, raw)
    annotations = raw / "kitml" / "annotations.json"
    if change == "no annotations":
        annotations.unlink()
    elif change == "no splits":
        shutil.rmtree(raw / "kitml" / "splits")
    else:
        annotations.write_text("{oops" if change == "not JSON" else "[]", encoding="utf-8")
    with pytest.raises(error) as raised:
        list_cmu_kitml(raw)
    assert message in str(raised.value) and "\n" not in str(raised.value)


def test_a_bad_entry_or_a_bvh_that_is_none_is_quarantined(tmp_path):
    raw = tmp_path / "cmu"
    shutil.copytree(FIXTURE, raw)
    (raw / "data" / "106" / "106_22.bvh").write_text("not a bvh\n", encoding="utf-8")
    entries = json.loads(ANNOTATIONS.read_text(encoding="utf-8"))
    entries["03474"] = {"path": "CMU/102/102_01_poses"}
    (raw / "kitml" / "annotations.json").write_text(json.dumps(entries), encoding="utf-8")
    rows = rows_by_id(raw, raw / "kitml" / "annotations.json")
    assert quarantined(rows["03474"])["reason"].startswith("bad entry: not {path, duration, annotations")
    assert quarantined(rows["03655"])["reason"].startswith("not a BVH file")


def test_the_corpus_says_its_licence_attribution_and_splits():
    layout = corpus("cmu-kitml").layout
    assert layout is CMU_KITML_LAYOUT and layout.about is ABOUT and layout.options == ("annotations",)
    assert "no licence stated" in ABOUT["licence"] and "MIT" in ABOUT["licence"]
    assert ABOUT["attribution"].startswith("The data used in this project was obtained from mocap.cs.cmu.edu.")
    assert "NSF EIA-0196217" in ABOUT["attribution"] and "doi:10.1089/big.2016.0028" in ABOUT["attribution"]
    assert "KIT-ML's own" in ABOUT["splits"]
    assert corpus("cmu-kitml").frame_bounds == (40, 200) and corpus("cmu-kitml").skeleton is T2M
    assert not layout.tagged_captions


# ------------------------------------------------------------------------------ m2d2m data


@pytest.mark.slow
def test_data_builds_the_fixture_and_every_entry_is_a_sample_or_a_quarantine_line(tmp_path, ray_local, capsys):
    out = tmp_path / "data" / "cmu-kitml"
    status = main(
        ["data", "--dataset", "cmu-kitml", "--raw", str(FIXTURE), "--annotations", str(ANNOTATIONS), "--out", str(out)]
    )
    assert status == 0
    printed = capsys.readouterr().out
    assert "licence: KIT-ML's captions: no licence stated" in printed
    assert "attribution: The data used in this project was obtained from mocap.cs.cmu.edu." in printed
    manifest = json.loads((out / "manifest.json").read_text(encoding="utf-8"))
    assert manifest["corpus"] == ABOUT
    assert manifest["splits"]["train"]["originals"] == 2 and manifest["splits"]["train"]["mirrors"] == 2
    assert manifest["quarantine_reasons"] == {
        "read: not CMU's motion": 1,
        "read: no BVH": 1,
        "read: does not line up": 1,
    }
    lines = [json.loads(line) for line in (out / "quarantine.jsonl").read_text(encoding="utf-8").splitlines()]
    samples = shard_samples(out)
    assert sorted(samples) == ["03474", "03655", "M03474", "M03655"]
    lost = {line["id"] for line in lines}
    assert lost == {"00001", "02248", "99001"}
    entries = json.loads(ANNOTATIONS.read_text(encoding="utf-8"))
    assert set(entries) == set(samples) | lost | {f"M{i}" for i in lost if f"M{i}" in entries}
    for motion_id in TAKES:
        np.testing.assert_allclose(
            samples[motion_id]["motion.npy"], joints_to_features(joints_of(motion_id)), atol=1e-5
        )
        mirrored = [c["text"] for c in samples[f"M{motion_id}"]["meta.json"]["captions"]]
        assert mirrored[0] == entries[f"M{motion_id}"]["annotations"][0]["text"]  # KIT-ML's own mirror caption
    captions = samples["03474"]["meta.json"]["captions"]
    assert [c["text"] for c in captions] == ["A human starts to run.", "right wide turn"]
    assert captions[0]["tokens"][:3] == ["a/DET", "human/NOUN", "start/VERB"]
    assert manifest["config"]["layout_options"] == {"annotations": "tests/fixtures/cmu-kitml/kitml/annotations.json"}
