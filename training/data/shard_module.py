"""What every DataModule over manifest-listed shards shares (:class:`ShardDataModule`), and the
feature shards with their normalisation (:class:`FeatureShardDataModule`). The shards,
``stats.npz`` and the manifest are all this shares with the pipelines that wrote them (through
``m2d2m.layout``)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import lightning.pytorch as pl
import torch
import webdataset as wds
from lightning.pytorch.utilities import rank_zero_info

from m2d2m.layout import STATS, read_manifest, shard_urls
from m2d2m.motion.representation.normalization import Normalizer
from training.data.feed import LoaderFeed, loader_feed, rank_and_world_size, require_workers, usable_cpus
from training.data.passes import LengthBuckets, require_positive, resampled_batches, split_pass
from training.data.samples import Sample
from training.data.shards import require_training_splits


class ShardDataModule(pl.LightningDataModule):
    """What the DataModules over a directory of manifest-listed shards share: a resampled training
    stream cut to ``steps_per_epoch`` batches on every rank, bucketed by length when ``bucket`` and
    the samples vary in length (``length_field``), and one pass over each clip for validation and
    test, shared among the ranks, in shard order. ``num_workers`` (a count, or ``auto``) and pinned
    memory follow the device the attached trainer trains on (:func:`loader_feed`). Subclasses read
    the manifest (``self.manifest``), find each split's shards, checked against it (``self._urls``),
    and say how a clip becomes a training sample (:meth:`_train_sample`) and an evaluation sample
    (:meth:`_eval_sample`)."""

    manifest: dict[str, Any]
    _urls: dict[str, list[str]]
    length_field: str | None = None  # the training sample's sequence that pads a batch; None: fixed length

    def __init__(
        self,
        batch_size: int,
        num_workers: int | str,
        steps_per_epoch: int | None,
        val_batch_size: int,
        shuffle_buffer: int,
        seed: int,
        bucket: bool,
    ) -> None:
        super().__init__()
        require_positive(
            batch_size=batch_size,
            val_batch_size=val_batch_size,
            steps_per_epoch=1 if steps_per_epoch is None else steps_per_epoch,
        )
        require_workers(num_workers)
        self.batch_size, self.num_workers, self.val_batch_size = batch_size, num_workers, val_batch_size
        self.shuffle_buffer, self.seed, self.bucket = shuffle_buffer, seed, bucket
        self._steps_per_epoch = steps_per_epoch

    def urls(self, split: str) -> list[str]:
        """Absolute paths of a split's shards, checked against the manifest (sizes, and sha256
        once per file: ``m2d2m.integrity``) when the DataModule was made."""
        return self._urls[split]

    def _sizes(self, split: str) -> list[int]:
        """Clips per shard of a split, from the manifest."""
        return [shard["samples"] for shard in self.manifest["shards"][split]]

    @property
    def train_clips(self) -> int:
        """Train clips that can give a training sample."""
        raise NotImplementedError

    def _train_sample(self, rank: int) -> tuple[Callable[[Sample], Sample | None], Callable[[list[Sample]], Any]]:
        """(decoded clip → training sample or None to skip, collate) for the process of ``rank``."""
        raise NotImplementedError

    def _eval_sample(self) -> tuple[Callable[[Sample], Sample | None], Callable[[list[Sample]], Any]]:
        """(decoded clip → validation/test sample, collate)."""
        raise NotImplementedError

    @property
    def steps_per_epoch(self) -> int:
        """Batches per epoch on every rank: as given, else one pass over the usable train clips
        shared among the ranks (at least one)."""
        usable = self.train_clips  # counted, and checked, even when the steps are given
        if self._steps_per_epoch is not None:
            return self._steps_per_epoch
        return max(1, usable // (self.batch_size * rank_and_world_size(self.trainer)[1]))

    def feed(self) -> LoaderFeed:
        """Workers and pinned memory for the device the attached trainer trains on (a CPU without
        one), its processes on this machine sharing the cores."""
        if self.trainer is None:
            return loader_feed(self.num_workers, torch.device("cpu"), usable_cpus(), 1)
        return loader_feed(self.num_workers, self.trainer.strategy.root_device, usable_cpus(), self.trainer.num_devices)

    def train_dataloader(self) -> wds.WebLoader:
        rank = rank_and_world_size(self.trainer)[0]
        prepare, collate = self._train_sample(rank)
        feed, bucketed = self.feed(), self.bucket and self.length_field is not None
        rank_zero_info(
            f"training batches: {feed.num_workers} loader workers"
            + (", pinned memory" if feed.pin_memory else "")
            + (", bucketed by length" if bucketed else "")
        )
        batching = (
            LengthBuckets(self.batch_size, collate, self.length_field, self.seed, rank)
            if bucketed
            else wds.batched(self.batch_size, collation_fn=collate, partial=False)
        )
        return resampled_batches(
            self.urls("train"), prepare, batching, self.steps_per_epoch, self.shuffle_buffer, feed, self.seed
        )

    def val_dataloader(self) -> wds.WebLoader:
        return self._one_pass("val")

    def test_dataloader(self) -> wds.WebLoader:
        return self._one_pass("test")

    def _one_pass(self, split: str) -> wds.WebLoader:
        prepare, collate = self._eval_sample()
        return split_pass(
            self.urls(split), self._sizes(split), self.trainer, prepare, collate, self.val_batch_size, self.feed()
        )


class FeatureShardDataModule(ShardDataModule):
    """A processed dataset's feature shards (docs/data.md) with their manifest and normalisation,
    for the DataModules of motion windows and of caption/motion pairs."""

    def __init__(
        self,
        data_dir: str | Path,
        batch_size: int,
        num_workers: int | str,
        steps_per_epoch: int | None,
        val_batch_size: int,
        shuffle_buffer: int,
        seed: int,
        bucket: bool,
    ) -> None:
        super().__init__(batch_size, num_workers, steps_per_epoch, val_batch_size, shuffle_buffer, seed, bucket)
        self.data_dir = Path(data_dir).resolve()
        self.manifest = read_manifest(self.data_dir)
        stats = self.data_dir / STATS
        if not stats.exists():
            raise FileNotFoundError(f"{stats}: missing; the dataset is incomplete (rebuild it with `m2d2m data`)")
        self.normalizer = Normalizer.load(stats)
        # Checked here, where the stages turn a refusal into one line, not once the trainer runs.
        self._urls = require_training_splits(
            {split: shard_urls(self.data_dir, split) for split in self.manifest["shards"]}, self.data_dir
        )

    @property
    def feature_dim(self) -> int:
        return int(self.manifest["feature_dim"])

    @property
    def fps(self) -> float:
        return float(self.manifest["fps"])

    @property
    def skeleton(self) -> str:
        return str(self.manifest["skeleton"])
