"""The Bandai Namco Research Motion Dataset as the ``bandai-namco`` corpus (pipelines/bandai_namco.py),
on the five real takes of tests/fixtures/bandai-namco: read at 20 fps from 30 on the 22 T2M joints,
bones rigid, feet on the floor, features that decode back, a Z-up copy read as the Y-up take; the
captions, splits, still ends and long-take pieces; every input that cannot be read one quarantine
line; and `m2d2m data` building the fixture's shards with the licence in the manifest."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from m2d2m.motion.files.bvh_reader import read_bvh
from m2d2m.motion.representation.features import canonicalize, features_to_joints, joints_to_features
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.motion.rigs.joint_map import PRESETS, UNITS, joint_map_for
from orchestration.cli import main
from pipelines.bandai_namco import (
    ABOUT,
    BANDAI_NAMCO_LAYOUT,
    FRAME_BOUNDS,
    STILL_KEPT,
    list_bandai_namco,
    moving_span,
    pieces,
    read_take,
    read_take_captions,
)
from pipelines.bandai_namco_captions import CONTENTS, STYLES, captions_for
from pipelines.bvh_corpus import stable_split, take_joints
from pipelines.corpora import FrameBounds, corpus
from pipelines.features import process_motion
from pipelines.language import Tagger, decompose, parse_tagged_tokens, train_tagger
from pipelines.synthetic.corpus import tagged_captions
from tests.test_mocap_corpora import shard_samples
from tests.test_up_axis import z_up_bvh

BANDAI = Path(__file__).parent / "fixtures" / "bandai-namco"
DATASET_1 = BANDAI / "dataset" / "Bandai-Namco-Research-Motiondataset-1"
DATASET_2 = BANDAI / "dataset" / "Bandai-Namco-Research-Motiondataset-2"
TAKES = sorted((BANDAI / "dataset").rglob("*.bvh"))
BOUNDS = FrameBounds(*FRAME_BOUNDS)
TOE_OVER_SOLE = 0.0425  # m: the toe joint's height when the foot is flat (every frame of the standing raise-up take)


def bandai_joints(path: Path) -> np.ndarray:
    return take_joints(path, joint_map="bandai-namco", units="cm")[0]


def rows_by_id(raw: Path = BANDAI, **options: str) -> dict[str, dict]:
    return {row["id"]: row for row in list_bandai_namco(raw, **options)}


# ------------------------------------------------------------------------------ reading a take


@pytest.mark.parametrize("path", TAKES, ids=lambda p: p.stem)
def test_a_take_reads_at_20_fps_from_its_30_on_the_bandai_map_in_centimetres(path):
    """Every 1.5 captured frames become one: floor((T − 1) · 2/3) + 1 frames at 20 fps. The rig's
    rest pose lies along its bones' X axes, yet its motion stands along +Y a person's height in
    centimetres, so the map and the unit are found without being named."""
    clip = read_bvh(path)
    assert clip.fps == pytest.approx(30.0, rel=1e-5) and len(clip.names) == 22
    mapping = joint_map_for(clip)
    assert mapping is PRESETS["bandai-namco"]
    assert np.argmax(np.abs(mapping.stature(clip))) == 0  # the rest pose lies along X
    assert mapping.standing(clip).axis == "+Y"
    assert mapping.metres_per_unit(clip) == UNITS["cm"]
    joints, _ = take_joints(path)
    assert joints.shape == ((len(clip.values) - 1) * 2 // 3 + 1, 22, 3)
    np.testing.assert_allclose(joints, bandai_joints(path), atol=1e-6)
    assert 1.2 < np.median(joints[:, T2M.head_joint, 1] - joints[:, [10, 11], 1].min(axis=1)) < 1.7


@pytest.mark.parametrize("path", TAKES, ids=lambda p: p.stem)
def test_its_bones_keep_their_lengths_over_the_clip(path):
    """Read at 20 fps's instants with each rotation slerped, every bone keeps its length to well
    under a millimetre (blending 30-fps positions would shorten the run's forearm by 1 cm); the
    collar bones alone change, by under a centimetre, since each collar is the midpoint of the
    clavicle's two ends and its distance from the chest follows the clavicle (as CMU's does)."""
    spread = np.ptp(T2M.bone_lengths_of(bandai_joints(path)), axis=0)
    collars = [T2M.joint_names.index("left_collar"), T2M.joint_names.index("right_collar")]
    assert np.delete(spread, collars).max() < 1e-3
    assert spread[collars].max() < 1e-2


@pytest.mark.parametrize("path", TAKES, ids=lambda p: p.stem)
def test_its_feet_touch_the_floor_in_stance_and_never_sink(path):
    """The studio's floor is y = 0. In stance (a toe slower than 0.2 m/s) the toe joint rests
    within 2 cm of where it is when the foot is flat, and no frame puts it more than 1 cm under
    that; on the features' floor (the clip's lowest joint) the stance toes are within 2 cm of 0."""
    joints = bandai_joints(path)
    toes = joints[:, [10, 11]]
    stance = np.linalg.norm(np.diff(toes, axis=0), axis=-1) * T2M.fps < 0.2
    assert stance.any()
    above_flat = toes[1:, :, 1][stance] - TOE_OVER_SOLE
    assert np.abs(above_flat).max() < 0.02
    assert toes[..., 1].min() > TOE_OVER_SOLE - 0.01
    body = canonicalize(joints)
    assert body[1:, [10, 11], 1][stance].max() < 0.02 and body[..., 1].min() == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("path", TAKES, ids=lambda p: p.stem)
def test_its_features_decode_back_to_its_joints(path):
    """HumanML3D's 263-d features of the take decode to the take on HumanML3D's skeleton: the
    representation loses nothing but the last frame and float rounding (1e-5 m, as CMU's takes)."""
    joints = bandai_joints(path)
    features = joints_to_features(joints)
    assert features.shape == (len(joints) - 1, 263) and np.isfinite(features).all()
    np.testing.assert_allclose(np.asarray(features_to_joints(features)), canonicalize(joints)[:-1], atol=1e-5)


def test_the_walk_goes_forward_with_left_and_right_where_they_belong():
    """Forward in the body's own frame (features 1–2: sideways, forward velocity): a rig whose
    left were its right would face backwards and walk back."""
    features = joints_to_features(bandai_joints(DATASET_1 / "data" / "dataset-1_walk_normal_001.bvh"))
    forward, sideways = features[:, 2].sum(), abs(features[:, 1].sum())
    assert forward > 5.0 and forward > 5 * sideways  # 8 m in 6.5 s


def test_a_z_up_copy_of_a_take_reads_as_the_take(tmp_path):
    """The walk written as a Z-up exporter writes it (rest pose, offsets and motion turned +90°
    about X): its motion stands along +Z, is turned back to +Y, and gives the same joints."""
    source = DATASET_1 / "data" / "dataset-1_walk_normal_001.bvh"
    (tmp_path / source.name).write_text(z_up_bvh(source.read_text(encoding="utf-8")), encoding="utf-8")
    assert PRESETS["bandai-namco"].standing(read_bvh(tmp_path / source.name)).axis == "+Z"
    z_up, mapping = take_joints(tmp_path / source.name)
    assert mapping is PRESETS["bandai-namco"]
    np.testing.assert_allclose(z_up, bandai_joints(source), atol=1e-6)


# ------------------------------------------------------------------------------ the corpus's rows


def test_the_rows_are_the_fixtures_takes_in_split_order_with_their_hash_splits():
    rows = list_bandai_namco(BANDAI)
    assert [(row["id"], row["split"]) for row in rows] == [
        ("dataset-1_bow_normal_001", "train"),
        ("dataset-1_dance-long_normal_001", "train"),
        ("dataset-2_wave-right-hand_normal_015", "train"),
        ("dataset-2_raise-up-left-hand_normal_035", "val"),
        ("dataset-1_walk_normal_001", "test"),
        ("dataset-2_run_normal_001", "test"),
    ]
    assert all(row["split"] == stable_split(row["take"]) for row in rows)


def test_a_take_keeps_its_split_when_others_are_added(tmp_path):
    raw = tmp_path / "clone"
    shutil.copytree(BANDAI, raw)
    before = {row["id"]: row["split"] for row in list_bandai_namco(raw)}
    data = raw / "dataset" / "Bandai-Namco-Research-Motiondataset-2" / "data"
    for n in range(900, 920):
        shutil.copy(data / "dataset-2_run_normal_001.bvh", data / f"dataset-2_run_normal_{n}.bvh")
        shutil.copy(data / "dataset-2_run_normal_001.json", data / f"dataset-2_run_normal_{n}.json")
    after = {row["id"]: row["split"] for row in list_bandai_namco(raw)}
    assert {take: after[take] for take in before} == before and len(after) == len(before) + 20
    assert {after[f"dataset-2_run_normal_{n}"] for n in range(900, 920)} == {"train", "val", "test"}


@pytest.mark.parametrize(
    "raw, subset, datasets",
    [
        (BANDAI, None, {"dataset-1", "dataset-2"}),
        (BANDAI, "both", {"dataset-1", "dataset-2"}),
        (BANDAI, "dataset-2", {"dataset-2"}),
        (BANDAI / "dataset", "dataset-1", {"dataset-1"}),
        (DATASET_2, None, {"dataset-2"}),
    ],
    ids=["clone", "both", "clone, dataset-2", "dataset folder, dataset-1", "one dataset's folder"],
)
def test_raw_is_the_clone_or_a_dataset_folder_and_subset_picks_the_datasets(raw, subset, datasets):
    assert {row["dataset"] for row in list_bandai_namco(raw, subset)} == datasets


@pytest.mark.parametrize(
    "raw, subset, error, message",
    [
        (BANDAI, "dataset-3", ValueError, "--subset: 'dataset-3' is not one of dataset-1, dataset-2 or both"),
        (DATASET_2, "dataset-1", ValueError, "--subset dataset-1: .* holds only dataset-2"),
        (BANDAI / "dataset" / "nothing", None, FileNotFoundError, "no dataset folder with data/ and cfg/; --raw is"),
    ],
)
def test_a_bad_raw_or_subset_is_one_line(raw, subset, error, message):
    with pytest.raises(error, match=message) as raised:
        list_bandai_namco(raw, subset)
    assert "\n" not in str(raised.value)


def quarantined(row: dict) -> dict:
    [record] = process_motion(row, BANDAI_NAMCO_LAYOUT, T2M, BOUNDS, make_mirror=True)
    assert record["status"] == "quarantined" and "\n" not in record["reason"]
    return record


def test_a_json_without_its_bvh_is_quarantined_with_its_reason():
    record = quarantined(rows_by_id()["dataset-1_dance-long_normal_001"])
    assert record["stage"] == "read"
    assert record["reason"] == (
        "no BVH file: dataset-1_dance-long_normal_001.bvh is not in Bandai-Namco-Research-Motiondataset-1/data, "
        "its JSON is"
    )


@pytest.mark.parametrize(
    "change, reason",
    [
        (
            lambda data: (data / "dataset-2_run_normal_001.json").unlink(),
            "no JSON annotation: dataset-2_run_normal_001",
        ),
        (
            lambda data: (data / "dataset-2_run_normal_001.json").write_text('{"content": 12, "style": 0}'),
            "bad annotation: dataset-2_run_normal_001.json's content 12 is no line of cfg/content_label.txt",
        ),
        (
            lambda data: (data / "dataset-2_run_normal_001.json").write_text("{content: 3}"),
            "bad annotation: dataset-2_run_normal_001.json is not {'content': i, 'style': j}",
        ),
        (
            lambda data: (data / "dataset-2_run_normal_001.json").write_text('{"content": 0, "style": 0}'),
            "labels unlike the file name: dataset-2_run_normal_001.json says dataset-2_walk, dataset-2_active",
        ),
        (
            lambda data: (data / "dataset-2_run_normal_001.bvh").write_text("not a bvh\n"),
            "not a BVH file (no Frames: and Frame Time: lines)",
        ),
    ],
    ids=["no JSON", "label out of range", "JSON unreadable", "JSON unlike the name", "not a BVH"],
)
def test_every_input_that_cannot_be_read_is_one_quarantine_line(tmp_path, change, reason):
    raw = tmp_path / "clone"
    shutil.copytree(BANDAI, raw)
    change(raw / "dataset" / "Bandai-Namco-Research-Motiondataset-2" / "data")
    record = quarantined(rows_by_id(raw)["dataset-2_run_normal_001"])
    assert record["stage"] == "read" and record["reason"].startswith(reason)


def test_an_unknown_label_has_no_captions_and_is_quarantined(tmp_path):
    raw = tmp_path / "clone"
    shutil.copytree(BANDAI, raw)
    cfg = raw / "dataset" / "Bandai-Namco-Research-Motiondataset-2" / "cfg"
    data = cfg.parent / "data"
    shutil.copy(data / "dataset-2_run_normal_001.bvh", data / "dataset-2_run_dizzy_001.bvh")
    styles = cfg / "style_label.txt"
    styles.write_text(styles.read_text(encoding="utf-8").rstrip() + "\ndataset-2_dizzy\n", encoding="utf-8")
    (data / "dataset-2_run_dizzy_001.json").write_text('{"content": 3, "style": 7}', encoding="utf-8")
    record = quarantined(rows_by_id(raw)["dataset-2_run_dizzy_001"])
    assert record["reason"] == "no captions: none are written for the style 'dizzy'"


# ------------------------------------------------------------------------------ still ends, long takes


def take_of(frames: list[str], source: Path, folder: Path, name: str) -> Path:
    """A copy of ``source`` (with its JSON) named ``name`` whose motion is ``frames``."""
    head = source.read_text(encoding="utf-8").split("MOTION")[0]
    path = folder / f"{name}.bvh"
    motion = f"MOTION\nFrames: {len(frames)}\nFrame Time: 0.0333333\n" + "\n".join(frames) + "\n"
    path.write_text(head + motion, encoding="utf-8")
    shutil.copy(source.with_suffix(".json"), folder / f"{name}.json")
    return path


def frames_of(path: Path) -> list[str]:
    return path.read_text(encoding="utf-8").split("Frame Time:")[1].strip().splitlines()[1:]


def copy_of_dataset(tmp_path: Path, folder: Path) -> Path:
    """An empty ``data/`` beside a copy of ``folder``'s ``cfg/``, under ``tmp_path``."""
    data = tmp_path / folder.name / "data"
    shutil.copytree(folder / "cfg", data.parent / "cfg")
    data.mkdir()
    return data


def test_still_ends_beyond_a_second_are_left_out(tmp_path):
    """The bow with 3 s of its first pose before it and 2 s of its last after: all but one second
    of stillness before its first move and after its last is left out."""
    source = DATASET_1 / "data" / "dataset-1_bow_normal_001.bvh"
    frames = frames_of(source)
    take = take_of(
        [frames[0]] * 90 + frames + [frames[-1]] * 60, source, copy_of_dataset(tmp_path, DATASET_1), source.stem
    )
    padded = bandai_joints(take)
    moving = np.flatnonzero(np.linalg.norm(np.diff(padded, axis=0), axis=-1).max(axis=1) * T2M.fps > 0.15)
    assert moving[0] >= 60 and len(padded) - 1 - moving[-1] >= 40  # the padding is still: 3 s and 2 s at 20 fps
    span = moving_span(padded, T2M.fps)
    assert (span.start, span.stop) == (moving[0] - STILL_KEPT, moving[-1] + 1 + STILL_KEPT)
    np.testing.assert_array_equal(read_take(rows_by_id(tmp_path)[source.stem], T2M), padded[span])


def test_pieces_are_consecutive_equal_and_within_the_bounds():
    assert pieces(200) == [(0, 200)]
    assert pieces(201) == [(0, 100), (100, 201)]
    cut = pieces(1100)
    assert len(cut) == 6 and cut[0][0] == 0 and cut[-1][1] == 1100
    assert all(a[1] == b[0] for a, b in zip(cut, cut[1:]))
    assert max(last - first for first, last in cut) - min(last - first for first, last in cut) <= 1
    assert all(BOUNDS.minimum <= last - first - 1 < BOUNDS.maximum for first, last in cut)


def test_a_long_take_becomes_consecutive_pieces_with_its_captions_and_split(tmp_path):
    """The run repeated into a 14-s take (as Bandai's long takes repeat a cycle): it is cut into
    pieces within the bounds that, end to end, are the whole take, each captioned as the take and
    in its split."""
    source = DATASET_2 / "data" / "dataset-2_run_normal_001.bvh"
    take = take_of(frames_of(source) * 6, source, copy_of_dataset(tmp_path, DATASET_2), "dataset-2_run_normal_777")
    rows = list_bandai_namco(tmp_path)
    assert [row["id"] for row in rows] == [f"dataset-2_run_normal_777_part{k}of2" for k in (1, 2)]
    whole = bandai_joints(take)
    whole = whole[moving_span(whole, T2M.fps)]
    motions = [read_take(row, T2M) for row in rows]
    np.testing.assert_array_equal(np.concatenate(motions), whole)
    assert all(BOUNDS.minimum <= len(motion) - 1 < BOUNDS.maximum for motion in motions)
    assert {row["split"] for row in rows} == {stable_split("dataset-2_run_normal_777")}
    assert rows[0]["captions"] == rows[1]["captions"] == captions_for("run", "normal", "dataset-2_run_normal_777")


def test_a_take_too_short_is_quarantined_by_the_frame_bounds(tmp_path):
    source = DATASET_2 / "data" / "dataset-2_run_normal_001.bvh"
    take_of(frames_of(source)[:30], source, copy_of_dataset(tmp_path, DATASET_2), "dataset-2_run_normal_778")  # 1 s
    record = quarantined(rows_by_id(tmp_path)["dataset-2_run_normal_778"])
    assert record["stage"] == "validate" and record["reason"] == "too few frames: 19 < 24"


# ------------------------------------------------------------------------------ captions


def test_every_take_gets_three_captions_chosen_by_its_name_the_same_every_time():
    first = captions_for("walk", "happy", "dataset-1_walk_happy_001")
    assert first == captions_for("walk", "happy", "dataset-1_walk_happy_001") and len(set(first)) == 3
    assert all(caption.startswith(("a person walks", "someone walks")) for caption in first)
    by_take = {tuple(captions_for("walk", "happy", f"dataset-1_walk_happy_{n:03d}")) for n in range(12)}
    assert len(by_take) == 3  # the style's three wordings turn with the take's name
    assert captions_for("walk", "normal", "x") == [
        "a person walks forward",
        "someone walks straight ahead",
        "a person walks in a straight line",
    ]
    row = rows_by_id()["dataset-2_raise-up-left-hand_normal_035"]
    assert [c["text"] for c in read_take_captions(row)] == row["captions"]
    assert all(c["tokens"] is None and c["start"] == c["end"] == 0.0 for c in read_take_captions(row))


@pytest.fixture(scope="module")
def tagger(tmp_path_factory: pytest.TempPathFactory) -> Tagger:
    """The tagger `m2d2m data` trains for a corpus whose captions come untagged (tagged_captions)."""
    return train_tagger(tagged_captions(600, seed=0), tmp_path_factory.mktemp("nlp"), seed=0)


def labels(folder: Path, kind: str) -> list[str]:
    lines = (folder / "cfg" / f"{kind}_label.txt").read_text(encoding="utf-8").split()
    return [line.split("_", 1)[1] for line in lines]


def test_every_caption_of_every_label_pair_keeps_its_verb_when_split(tagger):
    """Every content of each dataset in every wording, with every wording of every style of that
    dataset: tagged as the pipeline tags it and split at its verbs, it keeps the content's verb,
    and only the two-verb wordings ("walks forward and turns left", "raises ... and lowers it
    again") become two actions."""
    second_verbs = (" and turns", ", then turns", " and waves", " and lowers", ", then puts")
    for folder in (DATASET_1, DATASET_2):
        for content in labels(folder, "content"):
            phrasings, verbs = CONTENTS[content]
            for style in labels(folder, "style"):
                for caption in {phrasing.format(style=wording) for phrasing in phrasings for wording in STYLES[style]}:
                    split = decompose(caption, parse_tagged_tokens(" ".join(tagger.corpus_tokens(caption))))
                    assert set(split.verbs) & verbs, (caption, split.verbs)
                    expected = 1 + sum(marker in caption for marker in second_verbs)
                    assert len(split.actions) == expected, (caption, split.actions)


def test_every_label_of_the_fixture_has_captions_and_every_style_three_wordings():
    for folder in (DATASET_1, DATASET_2):
        assert set(labels(folder, "content")) <= set(CONTENTS) and set(labels(folder, "style")) <= set(STYLES)
    assert all(len(set(wordings)) == 3 for style, wordings in STYLES.items() if style != "normal")


# ------------------------------------------------------------------------------ m2d2m data


def test_the_corpus_says_its_licence_and_attribution():
    about = corpus("bandai-namco").layout.about
    assert about is ABOUT and "CC BY-NC 4.0" in about["licence"] and "non-commercial" in about["licence"]
    assert "Bandai Namco Research Inc." in about["attribution"] and "arXiv:2306.08861" in about["attribution"]
    assert corpus("bandai-namco").frame_bounds == (24, 200) and corpus("bandai-namco").skeleton is T2M


@pytest.mark.slow
def test_data_builds_the_fixture_into_shards_and_quarantines_the_missing_take(tmp_path, ray_local, capsys):
    out = tmp_path / "data" / "bandai-namco"
    status = main(["data", "--dataset", "bandai-namco", "--raw", str(BANDAI), "--out", str(out)])
    assert status == 0
    printed = capsys.readouterr().out
    assert "licence: CC BY-NC 4.0" in printed and "attribution: Bandai Namco Research Motion Dataset" in printed
    manifest = json.loads((out / "manifest.json").read_text(encoding="utf-8"))
    assert {split: manifest["splits"][split]["originals"] for split in ("train", "val", "test")} == {
        "train": 2,
        "val": 1,
        "test": 2,
    }
    assert manifest["splits"]["train"]["mirrors"] == 2 and manifest["splits"]["train"]["inputs_seen"] == 3
    assert manifest["quarantine_reasons"] == {"read: no BVH file": 1}
    assert manifest["corpus"] == ABOUT
    [line] = (out / "quarantine.jsonl").read_text(encoding="utf-8").splitlines()
    assert json.loads(line)["id"] == "dataset-1_dance-long_normal_001"
    samples = shard_samples(out)
    walk = samples["dataset-1_walk_normal_001"]
    np.testing.assert_allclose(
        walk["motion.npy"],
        joints_to_features(bandai_joints(DATASET_1 / "data" / "dataset-1_walk_normal_001.bvh")),
        atol=1e-5,
    )
    captions = walk["meta.json"]["captions"]
    assert [c["text"] for c in captions] == captions_for("walk", "normal", "dataset-1_walk_normal_001")
    assert captions[0]["tokens"][:3] == ["a/DET", "person/NOUN", "walk/VERB"] and captions[0]["verbs"] == ["walk"]
    mirrored = samples["Mdataset-2_raise-up-left-hand_normal_035"]["meta.json"]["captions"]
    assert mirrored[0]["text"] == "a person raises the right hand"
