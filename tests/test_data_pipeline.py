"""`m2d2m data` end to end with real Ray (local, 2 CPUs) on tiny corpora."""

import json
import shutil

import numpy as np
import pytest
import webdataset as wds

from m2d2m.layout import shard_urls
from m2d2m.motion.representation.features import joints_to_features
from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.motion.representation.skeleton import T2M
from orchestration.cli import main
from pipelines.corpora import list_corpus
from pipelines.dataset import check_dataset, sample_problems
from pipelines.features import DataConfig, build_dataset, plan_shards
from tests.helpers import pose_clip, write_corpus


def plant_bad_inputs(raw, train_ids):
    """One input per failure the validator must catch; returns {id: expected reason fragment}."""
    joints = raw / "joints"
    bad = {}
    clip = pose_clip(T2M, 80, seed=99)
    nan = clip.copy()
    nan[5, 3, 1] = np.nan
    np.save(joints / "900001.npy", nan)
    bad["900001"] = "NaN or Inf"
    np.save(joints / "900002.npy", clip[:, :21])
    bad["900002"] = "wrong shape"
    np.save(joints / "900003.npy", clip)
    data = (joints / "900003.npy").read_bytes()
    (joints / "900003.npy").write_bytes(data[: len(data) // 2])
    bad["900003"] = "unreadable or truncated"
    np.save(joints / "900004.npy", clip)
    bad["900004"] = "empty text"
    np.save(joints / "900005.npy", clip)
    bad["900005"] = "not UTF-8"
    np.save(joints / "900006.npy", clip[:11])
    bad["900006"] = "too few frames"
    bad["900007"] = "no motion file"
    np.save(joints / "900008.npy", (clip * 100).astype(np.int32))
    bad["900008"] = "wrong dtype"
    texts = raw / "texts"
    for motion_id in ("900001", "900002", "900003", "900006", "900007", "900008"):
        shutil.copy(texts / f"{train_ids[0]}.txt", texts / f"{motion_id}.txt")
    (texts / "900004.txt").write_text("\n", encoding="utf-8")
    (texts / "900005.txt").write_bytes("a person walks#a/DET person/NOUN walk/VERB#0.0#0.0".encode("utf-16"))
    with (raw / "train.txt").open("a", encoding="utf-8") as split_file:
        split_file.write("".join(f"{i}\n" for i in bad))
    return bad


@pytest.fixture(scope="module")
def built(tmp_path_factory, ray_local):
    root = tmp_path_factory.mktemp("pipeline")
    raw = root / "raw"
    ids = write_corpus(raw, {"train": 8, "val": 2, "test": 3}, T2M)
    bad = plant_bad_inputs(raw, ids["train"])
    config = DataConfig(dataset="synthetic", raw=str(raw), out=str(root / "out"), samples_per_shard=5, workers=2)
    manifest = build_dataset(config)
    return root, raw, ids, bad, config, manifest


def read_split(out, split):
    return list(wds.WebDataset(shard_urls(out, split), shardshuffle=False, empty_check=False).decode())


def test_every_sample_reads_back_with_webdataset_and_fits_the_schema(built):
    root, raw, ids, bad, config, manifest = built
    out = root / "out"
    for split in ("train", "val", "test"):
        samples = read_split(out, split)
        expected = [k for i in ids[split] for k in (i, f"M{i}")]
        assert [s["__key__"] for s in samples] == expected
        for sample in samples:
            motion, meta = sample["motion.npy"], sample["meta.json"]
            assert motion.dtype == np.float32 and motion.shape[1] == 263
            assert meta["frames"] == len(motion) and meta["fps"] == 20.0
            assert meta["mirrored"] == sample["__key__"].startswith("M")
            assert len(meta["captions"]) == 3
            assert all(set(c) == {"text", "tokens", "start", "end", "actions", "verbs"} for c in meta["captions"])


def test_features_and_mirrors_are_computed_from_the_raw_joints(built):
    root, raw, ids, *_ = built
    samples = {s["__key__"]: s for s in read_split(root / "out", "val")}
    motion_id = ids["val"][0]
    joints = np.load(raw / "joints" / f"{motion_id}.npy")
    np.testing.assert_array_equal(samples[motion_id]["motion.npy"], joints_to_features(joints))
    mirrored = samples[f"M{motion_id}"]["meta.json"]["captions"]
    assert mirrored[0]["text"] == "a person walks forward and then turns right"
    assert "right/ADV" in mirrored[0]["tokens"] and mirrored[2]["text"] == "a man waves his left hand"
    assert mirrored[2]["start"] == 0.5 and mirrored[2]["end"] == 2.0


def test_captions_carry_their_verb_decomposition(built):
    root, *_ = built
    caption = read_split(root / "out", "test")[0]["meta.json"]["captions"][0]
    assert caption["verbs"] == ["walk", "turn"]
    assert caption["actions"] == ["a person walks forward", "a person turns left"]


def test_bad_inputs_are_quarantined_with_their_reasons_and_nothing_else_is(built):
    root, raw, ids, bad, config, manifest = built
    lines = [json.loads(line) for line in (root / "out" / "quarantine.jsonl").read_text().splitlines()]
    assert {q["id"] for q in lines} == set(bad)
    for q in lines:
        assert bad[q["id"]] in q["reason"], q
        assert q["split"] == "train" and q["stage"] in {"read", "validate"}
    train = manifest["splits"]["train"]
    assert train["inputs_seen"] == len(ids["train"]) + len(bad) == train["originals"] + train["quarantined"]
    assert train["originals"] == train["mirrors"] == len(ids["train"]) and train["quarantined"] == len(bad)


def test_a_tagger_for_free_text_prompts_is_trained_from_the_corpus(built):
    from pipelines.language import decompose, load_tagger

    root, raw, ids, bad, config, manifest = built
    assert manifest["tagger"] == f"trained on {3 * len(ids['train'])} train captions"
    tagger = load_tagger(root / "out" / "nlp")
    assert decompose("a man walks forward and then turns left", tagger=tagger).verbs == ("walk", "turn")


def test_stats_come_from_the_train_split(built):
    root, raw, ids, *_ = built
    stats = Normalizer.load(root / "out" / "stats.npz")
    samples = [s["motion.npy"] for s in read_split(root / "out", "train")]
    np.testing.assert_allclose(stats.mean, np.concatenate(samples).mean(0), rtol=1e-5, atol=1e-6)
    assert stats.feat_bias == 5.0


def test_rebuild_with_another_worker_count_gives_identical_bytes_and_check_passes(built, tmp_path):
    root, raw, ids, bad, config, manifest = built
    again = build_dataset(DataConfig(**{**config.__dict__, "out": str(tmp_path / "again"), "workers": 1}))
    assert again["shards"] == manifest["shards"]
    for shard in manifest["shards"]["train"]:
        name = shard["name"]
        assert (tmp_path / "again" / "shards" / name).read_bytes() == (root / "out" / "shards" / name).read_bytes()
    assert check_dataset(root / "out") == []


def test_check_reports_a_damaged_dataset(built, tmp_path):
    root, *_ = built
    copy = tmp_path / "copy"
    shutil.copytree(root / "out", copy)
    (copy / "shards" / "val-000000.tar").write_bytes(b"")
    problems = check_dataset(copy)
    assert any("val-000000.tar: sha256 differs" in p for p in problems)


def test_shard_plan_never_exceeds_the_shard_size(built):
    root, raw, ids, bad, config, manifest = built
    assert all(s["samples"] <= config.samples_per_shard for split in manifest["shards"].values() for s in split)
    plan = plan_shards(list_corpus(raw), samples_per_shard=5, make_mirror=True)
    assert [(t["split"], t["index"], len(t["rows"])) for t in plan][:3] == [
        ("train", 0, 2),
        ("train", 1, 2),
        ("train", 2, 2),
    ]
    assert sum(len(t["rows"]) for t in plan) == len(list_corpus(raw))


def test_sample_schema_rejects_wrong_members():
    assert sample_problems("x", {"motion.npy": b""}, 263) == [
        "members ['motion.npy'], expected ['meta.json', 'motion.npy']"
    ]


def test_processed_layout_reads_features_and_ships_its_own_stats(tmp_path, ray_local):
    raw = tmp_path / "raw"
    ids = write_corpus(raw, {"train": 3, "val": 1, "test": 1}, T2M, kind="features")
    for motion_id in [i for split in ids.values() for i in split]:  # the corpus ships its mirrors
        shutil.copy(raw / "new_joint_vecs" / f"{motion_id}.npy", raw / "new_joint_vecs" / f"M{motion_id}.npy")
        shutil.copy(raw / "texts" / f"{motion_id}.txt", raw / "texts" / f"M{motion_id}.txt")
    for split, split_ids in ids.items():
        (raw / f"{split}.txt").write_text("".join(f"{i}\nM{i}\n" for i in split_ids))
    np.save(raw / "Mean.npy", np.full(263, 0.5, np.float32))
    np.save(raw / "Std.npy", np.full(263, 2.0, np.float32))
    manifest = build_dataset(DataConfig(dataset="humanml3d", raw=str(raw), out=str(tmp_path / "out")))
    assert manifest["mirrors_made_by_pipeline"] is False and manifest["stats_source"] == "corpus Mean.npy/Std.npy"
    assert manifest["splits"]["train"]["originals"] == 6 and manifest["splits"]["train"]["mirrors"] == 0
    np.testing.assert_array_equal(Normalizer.load(tmp_path / "out" / "stats.npz").std, 2.0)
    first = read_split(tmp_path / "out", "train")[0]
    np.testing.assert_array_equal(first["motion.npy"], np.load(raw / "new_joint_vecs" / f"{ids['train'][0]}.npy"))


def test_cli_reuses_a_complete_dataset_and_checks_it(built, capsys, tmp_path):
    root, raw, *_ = built
    out = tmp_path / "cli"
    assert (
        main(["data", "--dataset", "synthetic", "--raw", str(raw), "--out", str(out), "--samples-per-shard", "5"]) == 0
    )
    first = capsys.readouterr().out
    assert "read 21 inputs (2 rejected) · validate 6 rejected · features 13 motions + 13 mirrors" in first
    assert "train  8        8" in first  # the summary table: motions and mirrors per split
    assert (
        main(["data", "--dataset", "synthetic", "--raw", str(raw), "--out", str(out), "--samples-per-shard", "5"]) == 0
    )
    assert "reusing it" in capsys.readouterr().out
    assert main(["data", "--check", str(out)]) == 0
    (out / "manifest.json").unlink()
    assert main(["data", "--check", str(out)]) == 2


def test_kit_layout_gives_251_dimensional_samples_at_12_5_fps(tmp_path, ray_local):
    from m2d2m.motion.representation.skeleton import KIT

    raw = tmp_path / "raw"
    write_corpus(raw, {"train": 2, "val": 1, "test": 1}, KIT)
    manifest = build_dataset(DataConfig(dataset="kit", raw=str(raw), out=str(tmp_path / "out")))
    assert manifest["feature_dim"] == 251 and manifest["fps"] == 12.5 and manifest["config"]["min_frames"] == 24
    sample = read_split(tmp_path / "out", "train")[0]
    assert sample["motion.npy"].shape[1] == 251 and sample["meta.json"]["fps"] == 12.5
    assert check_dataset(tmp_path / "out") == []


def test_a_corpus_layout_registered_from_outside_goes_through_data_into_shards(built, tmp_path, monkeypatch):
    """tests/fake_corpus.py reads the same clips from one .npz each: `m2d2m data --dataset npz-clips`
    (Ray tasks importing the plugin) writes the same samples as the HumanML3D-layout build."""
    from m2d2m.plugins import import_plugins

    root, raw, ids, bad, config, manifest = built
    monkeypatch.setenv("M2D2M_PLUGINS", "tests.fake_corpus")
    monkeypatch.setattr("m2d2m.plugins._imported", [])
    import_plugins()
    npz = tmp_path / "npz"
    for split in ("train", "val", "test"):
        (npz / split).mkdir(parents=True)
        for clip_id in ids[split]:
            captions = (raw / "texts" / f"{clip_id}.txt").read_text(encoding="utf-8").splitlines()
            np.savez(
                npz / split / f"{clip_id}.npz",
                joints=np.load(raw / "joints" / f"{clip_id}.npy"),
                captions=np.array(captions),
            )
    out = tmp_path / "out"
    assert (
        main(
            [
                "data",
                "--dataset",
                "npz-clips",
                "--raw",
                str(npz),
                "--out",
                str(out),
                "--samples-per-shard",
                "5",
                "--workers",
                "2",
            ]
        )
        == 0
    )
    assert check_dataset(out) == []
    for split in ("train", "val", "test"):
        built_here = {sample["__key__"]: sample for sample in read_split(out, split)}
        from_humanml3d_layout = {sample["__key__"]: sample for sample in read_split(root / "out", split)}
        assert sorted(built_here) == sorted(from_humanml3d_layout)
        for key, sample in built_here.items():
            np.testing.assert_array_equal(sample["motion.npy"], from_humanml3d_layout[key]["motion.npy"])
            assert sample["meta.json"]["captions"] == from_humanml3d_layout[key]["meta.json"]["captions"]
    assert main(["data", "--dataset", "nope", "--raw", str(npz)]) == 2
