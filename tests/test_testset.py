"""The N-action test set (pipelines/testset.py): the single-verb pool, the no-overlap draw, the
files on disk, reuse, and verification — on small handmade datasets written with ShardWriter."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np
import pytest

from m2d2m.layout import MANIFEST, SHARDS
from pipelines.dataset import encode_sample
from pipelines.shards import ShardWriter, iter_tar_samples, shard_records
from pipelines.testset import (
    INSTANCES,
    MOTIONS,
    build_testset,
    check_testset,
    load_testset,
    single_verb_pool,
    verb_tags,
)

FPS = 20.0
DIM = 263


def caption(text, tokens, verbs, actions, start=0.0, end=0.0):
    return {"text": text, "tokens": tokens.split(), "verbs": verbs, "actions": actions, "start": start, "end": end}


def one_verb(verb: str):
    return caption(f"a person {verb}s", f"a/DET person/NOUN {verb}/VERB", [verb], [f"a person {verb}s"])


TWO = caption(
    "a person walks and then turns",
    "a/DET person/NOUN walk/VERB and/CCONJ then/ADV turn/VERB",
    ["walk", "turn"],
    ["a person walks", "a person turns"],
)
SEGMENT = caption("a man waves", "a/DET man/NOUN wave/VERB", ["wave"], ["a person waves"], 0.5, 3.0)  # frames 10..60
SHORT = caption("a man claps", "a/DET man/NOUN clap/VERB", ["clap"], ["a person claps"], 0.5, 1.5)  # 20 frames
# Two VERB tags, one action verb in the decomposition: dropped as a disagreement.
CATENATIVE = caption(
    "a person starts to run", "a/DET person/NOUN start/VERB to/PART run/VERB", ["run"], ["a person runs"]
)

VERBS = ["jump", "kick", "sit", "squat", "crawl", "bow", "spin", "hop", "dance", "skip"]
USABLE = [0, 1, 2, 3, 4, 5, 6, 9]  # the test clips with at least one usable single-verb caption


def clip_captions(index: int) -> list[dict]:
    if index <= 6:
        return [TWO, one_verb(VERBS[index]), SEGMENT]
    if index == 7:
        return [TWO, SHORT, CATENATIVE]
    if index == 8:
        return [TWO]
    return [one_verb(VERBS[index])]


def features(key: str, frames: int) -> np.ndarray:
    rng = np.random.default_rng(sum(map(ord, key)) * 1000 + len(key))
    return rng.normal(size=(frames, DIM)).astype(np.float32)


def write_dataset(root: Path, shipped_mirrors: bool = False) -> Path:
    """Ten test originals (each with its mirror, made by the pipeline or shipped as ``M<id>``)
    and one train clip with a single-verb caption, in shards of 4 samples."""
    samples = {"train": [], "test": []}
    for index in range(10):
        key, frames = f"{index:06d}", 60 + 7 * index
        for mirror in (False, True):
            name = f"M{key}" if mirror else key
            meta = {
                "id": name,
                "source": name if shipped_mirrors or not mirror else key,
                "fps": FPS,
                "frames": frames,
                "mirrored": mirror and not shipped_mirrors,
                "captions": clip_captions(index),
            }
            samples["test"].append((name, encode_sample(features(name, frames), meta)))
    meta = {
        "id": "000100",
        "source": "000100",
        "fps": FPS,
        "frames": 80,
        "mirrored": False,
        "captions": [one_verb("train")],
    }
    samples["train"].append(("000100", encode_sample(features("000100", 80), meta)))
    shards = {"val": []}
    for split, items in samples.items():
        with ShardWriter(root / SHARDS, split, 4) as writer:
            for key, members in items:
                writer.write(key, members)
        shards[split] = shard_records(writer.shards)
    manifest = {"dataset": "hand", "fps": FPS, "feature_dim": DIM, "config": {"min_frames": 40}, "shards": shards}
    (root / MANIFEST).write_text(json.dumps(manifest), encoding="utf-8")
    return root


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("hand"))


@pytest.fixture(scope="module")
def shipped(tmp_path_factory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("shipped"), shipped_mirrors=True)


def shard_features(data_dir: Path) -> dict[str, np.ndarray]:
    out = {}
    for shard in sorted((data_dir / SHARDS).glob("test-*.tar")):
        for key, members in iter_tar_samples(shard):
            out[key] = np.load(io.BytesIO(members["motion.npy"]))
    return out


def instances(path: Path) -> list[dict]:
    return [json.loads(line) for line in (path / INSTANCES).read_text(encoding="utf-8").splitlines()]


def test_pool_holds_only_single_verb_captions_with_usable_spans(data):
    pool = single_verb_pool(data)
    expected = {(f"{p}{i:06d}", c) for i in range(7) for p in ("", "M") for c in (1, 2)}
    expected |= {("000009", 0), ("M000009", 0)}
    assert {(e.key, e.caption_index) for e in pool} == expected
    assert all(len(verb_tags(clip_captions(int(e.key.lstrip("M")))[e.caption_index]["tokens"])) == 1 for e in pool)
    assert {e.verb for e in pool} == {VERBS[i] for i in USABLE} | {"wave"}
    assert "train" not in {e.verb for e in pool} and "clap" not in {e.verb for e in pool}
    assert all(e.action == f"a person {e.verb}s" for e in pool)
    assert {e.motion for e in pool} == {f"{i:06d}" for i in USABLE}  # a mirror counts as its original
    # A lower minimum lets the 20-frame segment in; the catenative caption stays out.
    assert {e.verb for e in single_verb_pool(data, min_frames=20)} >= {"clap"}
    assert "run" not in {e.verb for e in single_verb_pool(data, min_frames=1)}


def test_spans_honour_start_and_end(data):
    pool = {(e.key, e.caption_index): e for e in single_verb_pool(data)}
    segment, whole = pool[("000003", 2)], pool[("000003", 1)]
    assert (segment.first, segment.end, segment.length) == (10, 60, 50)  # 0.5 s .. 3.0 s at 20 fps
    assert (whole.first, whole.end) == (0, 60 + 7 * 3)


@pytest.mark.parametrize("n", [2, 3, 4])
@pytest.mark.parametrize("dataset", ["data", "shipped"])
def test_no_motion_or_mirror_twice_and_floor_count(dataset, n, request, tmp_path):
    data_dir = request.getfixturevalue(dataset)
    summary = build_testset(data_dir, n=n, seed=5, out=tmp_path)
    assert summary["pool"]["motions"] == len(USABLE) and summary["pool"]["keys"] == 2 * len(USABLE)
    assert summary["instances"] == len(USABLE) // n
    records = instances(Path(summary["path"]))
    assert len(records) == len(USABLE) // n and all(len(r["items"]) == n for r in records)
    originals = [item["key"].removeprefix("M") for r in records for item in r["items"]]
    assert len(originals) == len(set(originals)) == n * (len(USABLE) // n)
    assert [item["motion"] for r in records for item in r["items"]] == originals


def test_mirror_rules(data, tmp_path):
    same = build_testset(data, n=3, seed=0, out=tmp_path)
    distinct = build_testset(data, n=3, seed=0, out=tmp_path, mirrors="distinct")
    assert distinct["pool"]["motions"] == 16 and distinct["instances"] == 16 // 3
    # each rule has its own folder: drawing by another rule never meets the first one's test set
    assert [Path(same["path"]).name, Path(distinct["path"]).name] == ["n3-seed0", "n3-seed0-distinct"]
    keys = [item["key"] for r in instances(Path(distinct["path"])) for item in r["items"]]
    assert len(keys) == len(set(keys))
    exclude = build_testset(data, n=3, seed=0, out=tmp_path, mirrors="exclude")
    assert Path(exclude["path"]).name == "n3-seed0-exclude"
    assert exclude["pool"]["entries"] == 15 and exclude["instances"] == 8 // 3
    assert not any(item["key"].startswith("M") for r in instances(Path(exclude["path"])) for item in r["items"])
    with pytest.raises(ValueError, match="mirrors"):
        build_testset(data, out=tmp_path / "x", mirrors="sometimes")


def test_dropped_captions_are_counted(data, tmp_path):
    pool = build_testset(data, n=2, seed=0, out=tmp_path)["pool"]
    assert pool["clips"] == 20 and pool["captions"] == 2 * (7 * 3 + 3 + 1 + 1)
    assert pool["entries"] == 30 and pool["disagreements"] == 2 and pool["too_short"] == 2


def test_same_seed_gives_identical_files_and_another_seed_other_instances(data, tmp_path):
    a = Path(build_testset(data, n=2, seed=1, out=tmp_path / "a")["path"])
    b = Path(build_testset(data, n=2, seed=1, out=tmp_path / "b")["path"])
    c = Path(build_testset(data, n=2, seed=2, out=tmp_path / "c")["path"])
    for name in (INSTANCES, MOTIONS, MANIFEST):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    assert instances(a) != instances(c)
    assert a.name == "n2-seed1" and c.name == "n2-seed2"


def test_gt_features_are_the_shard_features_of_the_span(data, tmp_path):
    truth = shard_features(data)
    with load_testset(build_testset(data, n=4, seed=3, out=tmp_path)["path"]) as testset:
        assert testset.n == 4 and len(testset) == 2
        for instance in testset:
            assert len(instance.actions) == 4
            for position, item in enumerate(instance.items):
                gt = testset.features(instance.index, position)
                assert gt.dtype == np.float32 and gt.shape == (item.length, DIM)
                np.testing.assert_array_equal(gt, truth[item.key][item.first : item.end])
    segments = [item for instance in testset for item in instance.items if item.verb == "wave"]
    assert all((item.first, item.end) == (10, 60) for item in segments)


def test_reuse_without_force_and_rebuild_with_it(data, tmp_path):
    first = build_testset(data, n=2, seed=0, out=tmp_path)
    assert first["reused"] is False
    path = Path(first["path"])
    stamp = (path / MOTIONS).stat().st_mtime_ns
    again = build_testset(data, n=2, seed=0, out=tmp_path)
    assert again["reused"] is True and again["files"] == first["files"]
    assert (path / MOTIONS).stat().st_mtime_ns == stamp
    with pytest.raises(FileExistsError, match="other parameters"):
        build_testset(data, n=2, seed=0, out=tmp_path, min_frames=20)
    forced = build_testset(data, n=2, seed=0, out=tmp_path, min_frames=20, force=True)
    assert forced["reused"] is False and forced["min_frames"] == 20 and check_testset(path) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == [".n2-seed0.lock", "n2-seed0"]  # no partial or old ones


def test_check_finds_corruption(data, tmp_path):
    path = Path(build_testset(data, n=2, seed=0, out=tmp_path)["path"])
    assert check_testset(path) == []
    blob = bytearray((path / MOTIONS).read_bytes())
    blob[-100] ^= 0xFF
    (path / MOTIONS).write_bytes(bytes(blob))
    assert any("motions.npz: sha256" in p for p in check_testset(path))
    with pytest.raises(FileExistsError, match="damaged"):
        build_testset(data, n=2, seed=0, out=tmp_path)

    lines = (path / INSTANCES).read_text(encoding="utf-8").splitlines()
    (path / INSTANCES).write_text(
        "\n".join(lines[:-1] + [lines[0].replace('"index":0', f'"index":{len(lines) - 1}')]) + "\n"
    )
    problems = check_testset(path)
    assert any("instances.jsonl: sha256" in p for p in problems)
    assert any("more than once" in p for p in problems)
    (path / MANIFEST).unlink()
    assert check_testset(path) == [f"{path / MANIFEST}: missing (the test set is incomplete or was never built)"]


def test_too_few_motions_is_an_error(data, tmp_path):
    with pytest.raises(ValueError, match="fewer than n = 9"):
        build_testset(data, n=9, out=tmp_path)
    assert [p.name for p in tmp_path.iterdir()] == [".n9-seed0.lock"]  # no test set, whole or half


def test_on_the_pipelines_own_output(tiny_data, tmp_path):
    """The real data pipeline's samples (tests/helpers.CAPTIONS: one two-verb caption, one
    single-verb whole-clip caption, one single-verb 1.5 s segment) and its mirrors."""
    pool = single_verb_pool(tiny_data)
    assert sorted((e.key.removeprefix("M"), e.verb, e.first) for e in pool) == [("000008", "jump", 0)] * 2
    assert {e.motion for e in pool} == {"000008"} and {e.key for e in pool} == {"000008", "M000008"}
    assert {e.verb for e in single_verb_pool(tiny_data, min_frames=30)} == {"jump", "wave"}
    summary = build_testset(tiny_data, n=1, seed=0, out=tmp_path)
    assert summary["instances"] == 1 and check_testset(summary["path"]) == []
    with pytest.raises(ValueError, match="fewer than n = 2"):
        build_testset(tiny_data, n=2, out=tmp_path)


def test_another_split_draws_only_its_clips_into_a_directory_of_its_own(data, tmp_path):
    """Sampling settings are chosen on a set drawn from another split (``--split val``): it holds that
    split's clips alone and never lands where the test split's set of the same seed lives."""
    summary = build_testset(data, n=1, seed=0, out=tmp_path, split="train")
    assert Path(summary["path"]).name == "n1-seed0-train" and summary["split"] == "train"
    assert [item["key"] for instance in instances(Path(summary["path"])) for item in instance["items"]] == ["000100"]
    assert Path(build_testset(data, n=1, seed=0, out=tmp_path)["path"]).name == "n1-seed0"
    with pytest.raises(ValueError, match="no 'dev' split; the dataset has val, train, test"):
        build_testset(data, n=1, out=tmp_path, split="dev")
