"""`m2d2m tokenize` end to end with real Ray (local, 2 CPUs): a tiny dataset, a tiny random VQ-VAE."""

import io
import json
import math
import shutil

import numpy as np
import pytest
import torch

from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.networks.vqvae import VQ_FORMAT, MotionVQVAE, VQConfig, load_vq
from pipelines.features import DataConfig, build_dataset
from pipelines.shards import ShardWriter, iter_tar_samples, npy_bytes
from pipelines.tokenize import check_tokens, tokenize_dataset
from tests.helpers import random_vq, write_corpus


def load_npy(data: bytes) -> np.ndarray:
    return np.load(io.BytesIO(data), allow_pickle=False)


@pytest.fixture(scope="module")
def tokenized(tmp_path_factory, ray_local):
    root = tmp_path_factory.mktemp("tokenize")
    write_corpus(root / "raw", {"train": 4, "val": 2, "test": 2}, T2M)
    data = root / "data"
    build_dataset(DataConfig(dataset="synthetic", raw=str(root / "raw"), out=str(data), samples_per_shard=4))
    model, normalizer = random_vq(root / "vq.pt", data, seed=0)
    manifest = tokenize_dataset(data, root / "vq.pt", root / "tokens", workers=2)
    return root, data, model, normalizer, manifest


def test_one_token_sequence_per_motion_equal_to_a_direct_encoding(tokenized):
    root, data, model, normalizer, manifest = tokenized
    dataset = json.loads((data / "manifest.json").read_text())
    for split in ("train", "val", "test"):
        assert [s["name"] for s in manifest["shards"][split]] == [s["name"] for s in dataset["shards"][split]]
        assert manifest["splits"][split]["samples"] == dataset["splits"][split]["samples_written"]
        tokens_in_split, codes_used = 0, set()
        for shard in dataset["shards"][split]:
            motions = list(iter_tar_samples(data / "shards" / shard["name"]))
            tokens = list(iter_tar_samples(root / "tokens" / shard["name"]))
            assert [k for k, _ in tokens] == [k for k, _ in motions]
            for (key, motion_members), (_, token_members) in zip(motions, tokens):
                assert set(token_members) == {"tokens.npy", "meta.json"}
                assert token_members["meta.json"] == motion_members["meta.json"]
                codes = load_npy(token_members["tokens.npy"])
                motion = load_npy(motion_members["motion.npy"])
                assert codes.dtype == np.int16 and codes.shape == (math.ceil(len(motion) / 4),)
                expected = model.encode(torch.from_numpy(normalizer.normalize(motion))[None])[0]
                np.testing.assert_array_equal(codes, expected.numpy())
                tokens_in_split += len(codes)
                codes_used |= set(codes.tolist())
        assert manifest["splits"][split]["tokens"] == tokens_in_split
        assert len(codes_used) > 3  # a meaningful comparison, not all tokens the same code
    assert manifest["codebook_size"] == 32 and manifest["frames_per_token"] == 4 and manifest["kind"] == "tokens"


def test_the_codebook_and_model_travel_with_the_tokens(tokenized):
    root, data, model, normalizer, manifest = tokenized
    np.testing.assert_array_equal(np.load(root / "tokens" / "codebook.npy"), model.codebook.numpy())
    loaded, loaded_normalizer, info = load_vq(root / "tokens" / "vq.pt")
    np.testing.assert_array_equal(loaded.codebook.numpy(), model.codebook.numpy())
    np.testing.assert_array_equal(loaded_normalizer.mean, normalizer.mean)
    assert info["skeleton"] == "t2m" and (root / "tokens" / "stats.npz").exists()
    assert len(np.unique(np.load(root / "tokens" / "codebook.npy"), axis=0)) > 1


def test_rerun_reuses_a_new_model_rebuilds_and_check_catches_tampering(tokenized, tmp_path):
    root, data, model, normalizer, manifest = tokenized
    out, vq = tmp_path / "tokens", tmp_path / "vq.pt"
    shutil.copytree(root / "tokens", out)
    shutil.copy(root / "vq.pt", vq)
    # Reuse: nothing is rewritten, even a file planted in the directory stays.
    (out / "train-000099.tar").write_bytes(b"stale")
    assert tokenize_dataset(data, vq, out) == manifest
    assert (out / "train-000099.tar").exists()
    assert any("train-000099.tar: not in the manifest" in p for p in check_tokens(out))
    # Another model at the same path: rebuilt, stale shards cleared, tokens from the new model.
    other, _ = random_vq(vq, data, seed=1)
    rebuilt = tokenize_dataset(data, vq, out)
    assert rebuilt["vq_sha256"] != manifest["vq_sha256"] and not (out / "train-000099.tar").exists()
    key, members = next(iter_tar_samples(out / "val-000000.tar"))
    _, motion = next(iter_tar_samples(data / "shards" / "val-000000.tar"))
    expected = other.encode(torch.from_numpy(normalizer.normalize(load_npy(motion["motion.npy"])))[None])
    np.testing.assert_array_equal(load_npy(members["tokens.npy"]), expected[0].numpy())
    assert check_tokens(out) == []
    # A shard rewritten with out-of-range codes and a wrong length is reported.
    samples = list(iter_tar_samples(out / "test-000000.tar"))
    with ShardWriter(out, "test", len(samples)) as writer:
        for key, members in samples:
            writer.write(key, {**members, "tokens.npy": npy_bytes(np.array([32, 0], dtype=np.int16))})
    problems = check_tokens(out)
    assert any("test-000000.tar: sha256 differs" in p for p in problems)
    assert any("tokens outside [0, 32)" in p for p in problems)
    assert any("2 tokens for" in p for p in problems)


def test_missing_inputs_and_a_mismatched_model_are_clear_errors(tokenized, tmp_path):
    root, data, *_ = tokenized
    with pytest.raises(FileNotFoundError, match="train-vq"):
        tokenize_dataset(data, tmp_path / "missing.pt", tmp_path / "tokens")
    with pytest.raises(FileNotFoundError, match="m2d2m data"):
        tokenize_dataset(tmp_path / "no-dataset", root / "vq.pt", tmp_path / "tokens")
    kit_like = MotionVQVAE(VQConfig(feature_dim=251, width=32, code_dim=16, codebook_size=32, depth=1))
    VQ_FORMAT.save(
        tmp_path / "kit.pt",
        model=kit_like,
        normalizer=Normalizer(np.zeros(251), np.ones(251)),
        skeleton="kit",
        extra={},
    )
    with pytest.raises(ValueError, match="251-d features but .* 263-d"):
        tokenize_dataset(data, tmp_path / "kit.pt", tmp_path / "tokens")
    assert not (tmp_path / "tokens" / "manifest.json").exists()


def test_samples_per_shard_cuts_a_split_into_smaller_shards_in_motion_order(tokenized, tmp_path):
    root, data, model, normalizer, manifest = tokenized
    out = tmp_path / "small"
    small = tokenize_dataset(data, root / "vq.pt", out, samples_per_shard=3)
    train = small["shards"]["train"]
    assert [(s["name"], s["samples"], s["source"]) for s in train] == [
        ("train-000000.tar", 3, "train-000000.tar"),
        ("train-000001.tar", 1, "train-000000.tar"),
        ("train-000002.tar", 3, "train-000001.tar"),
        ("train-000003.tar", 1, "train-000001.tar"),
    ]
    samples = [sample for s in train for sample in iter_tar_samples(out / s["name"])]
    assert samples == [
        sample for s in manifest["shards"]["train"] for sample in iter_tar_samples(root / "tokens" / s["name"])
    ]
    assert small["splits"] == manifest["splits"] and check_tokens(out) == []
