"""The VQ-VAE's DataModule, and the bucketing of MotionDiffuse's caption/motion pairs, on a tiny
dataset built by the real pipeline (Ray, local, 2 CPUs)."""

import json
import logging
import shutil

import numpy as np
import pytest
import torch
import webdataset as wds
from numpy.lib.stride_tricks import sliding_window_view

from m2d2m.layout import MANIFEST, shard_urls
from m2d2m.motion.representation.skeleton import T2M
from pipelines.features import DataConfig, build_dataset
from tests.helpers import write_corpus
from training.data.motion_windows import MotionWindowDataModule
from training.data.samples import WindowCropper, valid_frames
from training.evaluator_module import CaptionMotionDataModule


@pytest.fixture(scope="module")
def dataset(tmp_path_factory, ray_local):
    """data/<name>/ with 16 train clips of 60–109 frames in 4 shards, 10 val clips in 3 shards and
    4 test clips; returns its path and the un-normalised clips of each split, read back."""
    root = tmp_path_factory.mktemp("training-data")
    write_corpus(root / "raw", {"train": 8, "val": 5, "test": 2}, T2M)
    build_dataset(
        DataConfig(dataset="synthetic", raw=str(root / "raw"), out=str(root / "out"), samples_per_shard=4, workers=2)
    )
    clips = {
        split: {
            s["__key__"]: s["motion.npy"]
            for s in wds.WebDataset(shard_urls(root / "out", split), shardshuffle=False).decode()
        }
        for split in ("train", "val", "test")
    }
    return root / "out", clips


def locate(window: np.ndarray, clips: dict[str, np.ndarray]) -> tuple[str, int] | None:
    """(key, start) of the clip slice equal to ``window`` within float tolerance, if any."""
    for key, clip in clips.items():
        if len(clip) < len(window):
            continue
        slices = sliding_window_view(clip, window.shape, axis=(0, 1))[:, 0]
        close = np.all(np.abs(slices - window) <= 1e-4 + 1e-4 * np.abs(window), axis=(1, 2))
        if close.any():
            return key, int(np.argmax(close))
    return None


def check_windows(module: MotionWindowDataModule, batches: list[dict], clips: dict) -> set[str]:
    """Every window is a normalised slice of one train clip and of no val/test clip; returns the
    clips the windows came from."""
    sources = set()
    for batch in batches:
        assert set(batch) == {"motion"}
        motion = batch["motion"]
        assert motion.dtype == torch.float32 and motion.shape == (module.batch_size, module.window, module.feature_dim)
        for window in motion.numpy():
            found = locate(module.normalizer.denormalize(window), clips["train"])
            assert found is not None, "a window that is no slice of a train clip"
            key, start = found
            raw = clips["train"][key][start : start + module.window]
            np.testing.assert_allclose(window, module.normalizer.normalize(raw), rtol=1e-6, atol=1e-6)
            assert locate(module.normalizer.denormalize(window), clips["val"] | clips["test"]) is None
            sources.add(key)
    return sources


def test_training_windows_are_normalised_slices_of_train_clips(dataset):
    out, clips = dataset
    module = MotionWindowDataModule(out, window=64, batch_size=4, num_workers=2)
    assert (module.feature_dim, module.fps, module.skeleton) == (263, 20.0, "t2m")
    assert module.too_short == 2 and module.train_clips == 14  # the two 60-frame clips (and mirror)
    assert module.steps_per_epoch == 14 // 4
    loader = module.train_dataloader()
    assert len(loader) == module.steps_per_epoch
    for _ in range(2):  # persistent workers: the second epoch has the same length
        batches = list(loader)
        assert len(batches) == module.steps_per_epoch
        check_windows(module, batches, clips)


def test_clips_shorter_than_the_window_are_skipped_and_counted_once(dataset, caplog):
    out, clips = dataset
    module = MotionWindowDataModule(out, window=90, batch_size=2, num_workers=2, steps_per_epoch=6)
    with caplog.at_level(logging.INFO):
        short = sum(len(clip) < 90 for clip in clips["train"].values())
        assert module.too_short == short == 10 and module.train_clips == 6
        batches = list(module.train_dataloader())
    assert len(batches) == 6
    assert check_windows(module, batches, clips) <= {k for k, clip in clips["train"].items() if len(clip) >= 90}
    assert sum("10 of 16 train clips are shorter" in record.message for record in caplog.records) == 1


@pytest.mark.parametrize("workers", [0, 2])
def test_the_training_stream_is_a_function_of_the_seed(dataset, workers):
    """Two loaders of one config give the same batches, epoch after epoch (so training a config twice
    trains the same model); another seed gives others. WebDataset's resampled mode and an unseeded
    shuffle would seed from the clock."""

    def batches(seed: int) -> list[np.ndarray]:
        module = MotionWindowDataModule(dataset[0], window=64, batch_size=4, num_workers=workers, seed=seed)
        loader = module.train_dataloader()
        return [batch["motion"].numpy() for _ in range(2) for batch in loader]

    first, again, other = batches(7), batches(7), batches(8)
    assert len(first) == len(again) > 2
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    assert not all(np.array_equal(a, b) for a, b in zip(first, other))


def test_caption_motion_pairs_are_bucketed_by_length_when_asked(dataset):
    """MotionDiffuse asks for bucketing and pads less over the same 40 batches of full size; the
    evaluator's default keeps random batches (its negatives of any length)."""
    out, clips = dataset

    def batches(**bucket: bool) -> list[dict]:
        module = CaptionMotionDataModule(out, batch_size=3, num_workers=0, steps_per_epoch=40, **bucket)
        loaded = list(module.train_dataloader())
        assert len(loaded) == 40 and all(len(batch["keys"]) == 3 for batch in loaded)
        assert {key for batch in loaded for key in batch["keys"]} <= clips["train"].keys()
        return loaded

    def padding(loaded: list[dict]) -> float:
        return 1 - sum(int(b["lengths"].sum()) for b in loaded) / sum(b["motion"].shape[:2].numel() for b in loaded)

    plain, default = padding(batches(bucket=False)), padding(batches())
    assert default == plain > 0.1 and padding(batches(bucket=True)) < plain / 2


def test_a_window_no_clip_fills_is_refused(dataset):
    module = MotionWindowDataModule(dataset[0], window=500)
    with pytest.raises(ValueError, match="shorter window"):
        module.train_dataloader()


def test_validation_reads_every_clip_once_in_a_fixed_order_padded_and_normalised(dataset):
    out, clips = dataset
    module = MotionWindowDataModule(out, val_batch_size=3, num_workers=2)
    passes = [list(module.val_dataloader()) for _ in range(2)]
    keys = [key for batch in passes[0] for key in batch["keys"]]
    assert sorted(keys) == sorted(clips["val"]) and len(keys) == len(set(keys)) == 10
    assert keys == [key for batch in passes[1] for key in batch["keys"]]
    for batch in passes[0]:
        motion, lengths = batch["motion"], batch["lengths"]
        assert motion.dtype == torch.float32 and lengths.dtype == torch.long
        assert motion.shape == (len(batch["keys"]), int(lengths.max()), 263)
        mask = valid_frames(lengths)
        for row, length, key, valid in zip(motion.numpy(), lengths.tolist(), batch["keys"], mask):
            assert length == len(clips["val"][key]) and int(valid.sum()) == length
            np.testing.assert_allclose(
                row[:length], module.normalizer.normalize(clips["val"][key]), rtol=1e-6, atol=1e-6
            )
            assert not row[length:].any()
    test_keys = [key for batch in module.test_dataloader() for key in batch["keys"]]
    assert sorted(test_keys) == sorted(clips["test"])


def test_every_rank_runs_the_same_number_of_batches(dataset, monkeypatch):
    out, clips = dataset
    counts = []
    for rank in (0, 1):
        monkeypatch.setenv("RANK", str(rank))
        monkeypatch.setenv("WORLD_SIZE", "2")
        module = MotionWindowDataModule(out, window=64, batch_size=2, num_workers=2)
        batches = list(module.train_dataloader())
        check_windows(module, batches, clips)
        counts.append((module.steps_per_epoch, len(batches)))
    assert counts == [(14 // (2 * 2), 14 // (2 * 2))] * 2


def test_ranks_share_validation_clip_by_clip(dataset, monkeypatch):
    """Three val shards, two ranks of three workers each: no rank is left without clips."""
    out, clips = dataset
    shares = []
    for rank in (0, 1):
        monkeypatch.setenv("RANK", str(rank))
        monkeypatch.setenv("WORLD_SIZE", "2")
        module = MotionWindowDataModule(out, val_batch_size=2, num_workers=3)
        shares.append([key for batch in module.val_dataloader() for key in batch["keys"]])
    assert len(shares[0]) == len(shares[1]) == 5
    assert sorted(shares[0] + shares[1]) == sorted(clips["val"])


def test_window_starts_depend_on_seed_rank_and_worker_only():
    normalizer = type("Identity", (), {"normalize": staticmethod(lambda x: x)})()
    samples = [{"motion.npy": np.arange(200.0)[:, None] + i} for i in range(20)]

    def starts(seed, rank):
        crop = WindowCropper(16, normalizer, seed, rank)
        return [int(crop(s)["motion"][0, 0]) - i for i, s in enumerate(samples)]

    np.random.seed(1)
    first = starts(0, 0)
    np.random.seed(2)
    assert starts(0, 0) == first and starts(0, 1) != first and starts(1, 0) != first
    assert all(0 <= start <= 200 - 16 for start in first)
    assert WindowCropper(300, normalizer, 0, 0)(samples[0]) is None


def test_an_unbuilt_or_incomplete_dataset_says_what_to_run(dataset, tmp_path):
    with pytest.raises(FileNotFoundError, match="m2d2m data"):
        MotionWindowDataModule(tmp_path)
    shutil.copy(dataset[0] / MANIFEST, tmp_path / MANIFEST)
    with pytest.raises(FileNotFoundError, match="stats.npz.*m2d2m data"):
        MotionWindowDataModule(tmp_path)
    with pytest.raises(ValueError, match="window must be a positive"):
        MotionWindowDataModule(dataset[0], window=0)


def test_a_dataset_without_val_motions_is_refused_in_one_line_before_training(dataset, tmp_path):
    """A small BVH corpus split by hash can leave val empty: that was a traceback at the first validation."""
    out = tmp_path / "no-val"
    shutil.copytree(dataset[0], out)
    manifest = json.loads((out / MANIFEST).read_text(encoding="utf-8"))
    manifest["shards"]["val"] = []
    (out / MANIFEST).write_text(json.dumps(manifest), encoding="utf-8")
    with pytest.raises(ValueError, match=r"no-val: no val motions, and training needs both; rebuild the dataset"):
        MotionWindowDataModule(out)
