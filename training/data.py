"""WebDataset DataModules that feed the models from a processed dataset (DESIGN.md, data contract).

Training streams resampled shards split by rank and worker and cuts every epoch to the same number
of batches, so no DDP rank waits on another (``reference/ecosystem.md`` §3); validation and test
read each clip once, in shard order, the ranks sharing them clip by clip. The shards, ``stats.npz``
and the manifest are all this shares with the pipelines that wrote them (through ``m2d2m.layout``).
"""

from __future__ import annotations

import json
import tarfile
from functools import cached_property, partial
from pathlib import Path
from typing import Any, Iterator

import lightning.pytorch as pl
import numpy as np
import torch
import webdataset as wds
from lightning.pytorch.utilities import rank_zero_info

from m2d2m.layout import STATS, read_manifest, shard_urls
from m2d2m.normalization import Normalizer

Sample = dict[str, Any]


def clip_lengths(urls: list[str]) -> list[int]:
    """The frame count of every clip in local shards, from the small ``meta.json`` members alone:
    the tar headers let the motion arrays be skipped instead of read."""
    lengths = []
    for url in urls:
        with tarfile.open(url) as archive:
            for member in archive:
                if member.name.endswith(".meta.json"):
                    lengths.append(json.loads(archive.extractfile(member).read())["frames"])
    return lengths


def random_window(motion: np.ndarray, window: int, rng: np.random.Generator) -> np.ndarray | None:
    """``window`` frames starting uniformly in [0, T − window]; None for a shorter clip, which is
    skipped rather than padded, as T2M-GPT does."""
    spare = len(motion) - window
    if spare < 0:
        return None
    start = int(rng.integers(spare + 1))
    return motion[start:start + window]


def pad_clips(motions: list[np.ndarray]) -> tuple[torch.Tensor, torch.Tensor]:
    """Clips of different lengths as one zero-padded float32 (B, T_max, D) tensor and their
    lengths (B,) long, from which ``valid_frames`` rebuilds the mask."""
    lengths = torch.tensor([len(motion) for motion in motions], dtype=torch.long)
    batch = torch.zeros(len(motions), int(lengths.max()), motions[0].shape[1], dtype=torch.float32)
    for row, motion in zip(batch, motions):
        row[:len(motion)] = torch.from_numpy(motion)
    return batch, lengths


def valid_frames(lengths: torch.Tensor, max_length: int | None = None) -> torch.Tensor:
    """(B, T_max) bool, True on real frames and False on padding."""
    max_length = int(lengths.max()) if max_length is None else max_length
    return torch.arange(max_length, device=lengths.device) < lengths[:, None]


def stack_windows(samples: list[Sample]) -> dict[str, torch.Tensor]:
    """Equal-length windows as {"motion": (B, window, D)}."""
    return {"motion": torch.from_numpy(np.stack([sample["motion"] for sample in samples]))}


def collate_clips(samples: list[Sample]) -> dict[str, Any]:
    """Whole clips as {"motion": (B, T_max, D) zero-padded, "lengths": (B,), "keys": ids}."""
    motion, lengths = pad_clips([sample["motion"] for sample in samples])
    return {"motion": motion, "lengths": lengths, "keys": [sample["__key__"] for sample in samples]}


def normalized_clip(sample: Sample, normalizer: Normalizer) -> Sample:
    """A decoded sample's whole clip, normalised (the key travels along with it)."""
    return {"motion": normalizer.normalize(sample["motion.npy"])}


def rank_share(samples: Iterator[Sample], offsets: dict[str, int], rank: int, world_size: int) -> Iterator[Sample]:
    """The clips whose position in the split (``offsets``: each shard's first position) is
    ``rank`` modulo ``world_size``: every rank gets a share differing by at most one clip, so none
    is left without a batch (and without the metric its peers wait for) when the split has fewer
    shards than ranks."""
    seen: dict[str, int] = {}
    for sample in samples:
        url = sample["__url__"]
        position = offsets[url] + seen.get(url, 0)
        seen[url] = seen.get(url, 0) + 1
        if position % world_size == rank:
            yield sample


class WindowCropper:
    """Turns a decoded sample into {"motion": a normalised random window}, or None (dropped) when
    the clip is too short. Its Generator is made on first use inside each DataLoader worker, seeded
    from (seed, rank, worker id): the crops differ between workers and ranks, and never depend on
    global random state."""

    def __init__(self, window: int, normalizer: Normalizer, seed: int, rank: int) -> None:
        self.window, self.normalizer, self.seed, self.rank = window, normalizer, seed, rank
        self.rng: np.random.Generator | None = None

    def __call__(self, sample: Sample) -> Sample | None:
        if self.rng is None:
            worker = torch.utils.data.get_worker_info()
            self.rng = np.random.default_rng([self.seed, self.rank, 0 if worker is None else worker.id])
        crop = random_window(sample["motion.npy"], self.window, self.rng)
        return None if crop is None else {"motion": self.normalizer.normalize(crop)}


class MotionWindowDataModule(pl.LightningDataModule):
    """Random fixed-length windows of the train clips for the motion VQ-VAE; whole clips for
    validation and test. Every motion is normalised once, here, with the dataset's ``stats.npz``."""

    def __init__(
        self,
        data_dir: str | Path,
        window: int = 64,
        batch_size: int = 256,
        num_workers: int = 2,
        steps_per_epoch: int | None = None,
        val_batch_size: int = 32,
        shuffle_buffer: int = 1000,
        seed: int = 0,
    ) -> None:
        super().__init__()
        for name, value in (("window", window), ("batch_size", batch_size), ("val_batch_size", val_batch_size),
                            ("steps_per_epoch", 1 if steps_per_epoch is None else steps_per_epoch)):
            if value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value}")
        self.data_dir = Path(data_dir).resolve()
        self.manifest = read_manifest(self.data_dir)
        stats = self.data_dir / STATS
        if not stats.exists():
            raise FileNotFoundError(f"{stats}: missing; the dataset is incomplete (rebuild it with `m2d2m data`)")
        self.normalizer = Normalizer.load(stats)
        self.window, self.batch_size, self.num_workers = window, batch_size, num_workers
        self.val_batch_size, self.shuffle_buffer, self.seed = val_batch_size, shuffle_buffer, seed
        self._steps_per_epoch = steps_per_epoch

    @property
    def feature_dim(self) -> int:
        return int(self.manifest["feature_dim"])

    @property
    def fps(self) -> float:
        return float(self.manifest["fps"])

    @property
    def skeleton(self) -> str:
        return str(self.manifest["skeleton"])

    @cached_property
    def _train_counts(self) -> tuple[int, int]:
        """(usable, too short) train clips, counted once; reports the skipped ones, and refuses a
        window no clip fills (the resampled stream would then never yield a batch)."""
        lengths = clip_lengths(shard_urls(self.data_dir, "train"))
        too_short = sum(length < self.window for length in lengths)
        if too_short == len(lengths):
            raise ValueError(f"{self.data_dir}: none of the {len(lengths)} train clips has {self.window} frames; "
                             "use a shorter window")
        rank_zero_info(f"{self.data_dir.name}: {too_short} of {len(lengths)} train clips are shorter than "
                       f"the {self.window}-frame window and are skipped")
        return len(lengths) - too_short, too_short

    @property
    def too_short(self) -> int:
        """Train clips shorter than the window, which training never sees."""
        return self._train_counts[1]

    @property
    def train_clips(self) -> int:
        """Train clips long enough to give a window."""
        return self._train_counts[0]

    @property
    def steps_per_epoch(self) -> int:
        """Batches per epoch on every rank: as given, else one pass over the usable train clips
        shared among the ranks (at least one)."""
        usable = self.train_clips  # counted, and checked, even when the steps are given
        if self._steps_per_epoch is not None:
            return self._steps_per_epoch
        return max(1, usable // (self.batch_size * self._rank_and_world_size()[1]))

    def _rank_and_world_size(self) -> tuple[int, int]:
        """The trainer's when attached, else what webdataset's node splitter sees (env RANK and
        WORLD_SIZE, then torch.distributed)."""
        if self.trainer is not None:
            return self.trainer.global_rank, self.trainer.world_size
        rank, world_size, _, _ = wds.utils.pytorch_worker_info()
        return rank, world_size

    def train_dataloader(self) -> wds.WebLoader:
        steps = self.steps_per_epoch
        crop = WindowCropper(self.window, self.normalizer, self.seed, self._rank_and_world_size()[0])
        # seed= only spares WebDataset a draw from the global random module: resampled mode ignores it.
        dataset = (
            wds.WebDataset(shard_urls(self.data_dir, "train"), resampled=True, shardshuffle=False,
                           nodesplitter=wds.split_by_node, workersplitter=wds.split_by_worker,
                           empty_check=False, seed=self.seed)
            .shuffle(self.shuffle_buffer)
            .decode()
            .map(crop)
            .batched(self.batch_size, collation_fn=stack_windows, partial=False)
        )
        loader = wds.WebLoader(dataset, batch_size=None, num_workers=self.num_workers,
                               persistent_workers=self.num_workers > 0)
        return loader.with_epoch(steps).with_length(steps, silent=True)  # __len__ for progress bars and schedulers

    def val_dataloader(self) -> wds.WebLoader:
        return self._whole_clips("val")

    def test_dataloader(self) -> wds.WebLoader:
        return self._whole_clips("test")

    def _whole_clips(self, split: str) -> wds.WebLoader:
        """One deterministic pass over a split. Ranks share it clip by clip, not shard by shard
        (``rank_share``); the workers of a rank share its shards."""
        urls = shard_urls(self.data_dir, split)
        sizes = [shard["samples"] for shard in self.manifest["shards"][split]]
        offsets = dict(zip(urls, np.cumsum([0] + sizes[:-1]).tolist()))
        rank, world_size = self._rank_and_world_size()
        dataset = (
            wds.WebDataset(urls, shardshuffle=False, nodesplitter=None, empty_check=False)
            .compose(partial(rank_share, offsets=offsets, rank=rank, world_size=world_size))
            .decode()
            .map(partial(normalized_clip, normalizer=self.normalizer))
            .batched(self.val_batch_size, collation_fn=collate_clips, partial=True)
        )
        return wds.WebLoader(dataset, batch_size=None, num_workers=self.num_workers)
