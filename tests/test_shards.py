"""Shard writing: WebDataset-readable, atomic, byte-reproducible, and verifiable."""

import numpy as np
import pytest
import webdataset as wds

from pipelines.shards import ShardWriter, iter_tar_samples, json_bytes, npy_bytes, verify_shards


def samples(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    for i in range(n):
        motion = rng.normal(size=(10 + i, 5)).astype(np.float32)
        yield (
            f"{i:06d}",
            {"motion.npy": npy_bytes(motion), "meta.json": json_bytes({"id": f"{i:06d}", "frames": 10 + i})},
        )


def write(directory, n=7, per_shard=3):
    with ShardWriter(directory, "train", per_shard) as writer:
        for key, members in samples(n):
            writer.write(key, members)
    return writer.shards


def test_shards_split_by_count_and_read_back_with_webdataset(tmp_path):
    shards = write(tmp_path)
    assert [s.samples for s in shards] == [3, 3, 1]
    assert [s.name for s in shards] == ["train-000000.tar", "train-000001.tar", "train-000002.tar"]
    urls = [str(tmp_path / s.name) for s in shards]
    read = list(wds.WebDataset(urls, shardshuffle=False, empty_check=False).decode())
    assert [r["__key__"] for r in read] == [f"{i:06d}" for i in range(7)]
    assert read[4]["motion.npy"].dtype == np.float32 and read[4]["motion.npy"].shape == (14, 5)
    assert read[4]["meta.json"] == {"id": "000004", "frames": 14}


def test_same_samples_give_byte_identical_shards(tmp_path):
    first = write(tmp_path / "a")
    second = write(tmp_path / "b")
    assert [s.sha256 for s in first] == [s.sha256 for s in second]
    assert (tmp_path / "a" / "train-000001.tar").read_bytes() == (tmp_path / "b" / "train-000001.tar").read_bytes()


def test_an_interrupted_write_leaves_no_partial_shard(tmp_path):
    with pytest.raises(RuntimeError):
        with ShardWriter(tmp_path, "train", 3) as writer:
            for i, (key, members) in enumerate(samples(7)):
                if i == 4:
                    raise RuntimeError("killed mid-shard")
                writer.write(key, members)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["train-000000.tar"]


def test_keys_with_dots_are_refused(tmp_path):
    with pytest.raises(ValueError, match="no dots"):
        ShardWriter(tmp_path, "train", 3).write("a.b", {"meta.json": b"{}"})


def test_verification_reports_tampering(tmp_path):
    records = [s.__dict__ for s in write(tmp_path)]
    assert verify_shards(tmp_path, records, lambda key, members: []) == []
    (tmp_path / "train-000002.tar").write_bytes(b"not a tar")
    (tmp_path / "stray.tar").write_bytes(b"")
    records[1] = {**records[1], "samples": 4}
    problems = verify_shards(tmp_path, records, lambda key, members: ["bad"] if key == "000000" else [])
    text = "\n".join(problems)
    assert "train-000000.tar: 000000: bad" in text
    assert "train-000001.tar: 3 samples, manifest says 4" in text
    assert "train-000002.tar: sha256 differs" in text
    assert "stray.tar: not in the manifest" in text


def test_iter_tar_samples_groups_members_by_key(tmp_path):
    write(tmp_path, n=2, per_shard=2)
    grouped = list(iter_tar_samples(tmp_path / "train-000000.tar"))
    assert [k for k, _ in grouped] == ["000000", "000001"]
    assert set(grouped[0][1]) == {"motion.npy", "meta.json"}
