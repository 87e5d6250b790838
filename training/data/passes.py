"""The two ways a split is read. Training: resampled shards split by rank and worker, cut every
epoch to the same number of batches so no DDP rank waits on another (webdataset's multi-node
recipe, webdataset.github.io/webdataset/multinode/), batched by length when the samples vary
(:class:`LengthBuckets`). Validation and test: each clip once, in shard order, the ranks sharing
them clip by clip."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from functools import partial
from typing import Any

import lightning.pytorch as pl
import numpy as np
import webdataset as wds

from training.data.feed import LoaderFeed, rank_and_world_size
from training.data.samples import Sample, worker_generator

Batching = Callable[[Iterable[Sample]], Iterator[Any]]  # a pipeline stage: samples in, collated batches out
BUCKET_POOL_BATCHES = 8
BUCKET_STREAM = 1  # ``worker_generator`` stream of the bucketed batch order (stream 0: the samples' own draws)


def require_positive(**values: int) -> None:
    """Refuse a zero or negative size, which would otherwise stall or empty a stream."""
    for name, value in values.items():
        if value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value}")


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


class LengthBuckets:
    """A pipeline stage that makes batches of ``batch_size`` samples of similar length, so a batch
    is padded to the longest of its neighbours in length rather than of a random draw. It keeps a
    pool of ``pool_batches`` batches' worth of arriving (already shuffled) samples, sorts it by
    ``len(sample[field])`` (stable, so ties keep their arrival order), cuts it into batches and lets
    them out in random order: torchtext's ``BucketIterator`` pool (pytorch/text,
    ``torchtext/data/iterator.py``, ``pool``), whose pool is 100 batches; a few batches already
    remove most of the padding (docs/training.md, "Data loading") and keep the first batch near.

    Every sample that enters leaves exactly once, in a batch of exactly ``batch_size``; a finite
    stream's samples after its last full batch are dropped, the ones ``wds.batched(partial=False)``
    drops. The batch order comes from ``worker_generator(seed, rank, BUCKET_STREAM)``, made on
    first use inside each DataLoader worker and kept across epochs."""

    def __init__(
        self,
        batch_size: int,
        collate: Callable[[list[Sample]], Any],
        field: str,
        seed: int,
        rank: int,
        pool_batches: int = BUCKET_POOL_BATCHES,
    ) -> None:
        require_positive(batch_size=batch_size, pool_batches=pool_batches)
        self.batch_size, self.collate, self.field, self.pool_batches = batch_size, collate, field, pool_batches
        self.seed, self.rank = seed, rank
        self.rng: np.random.Generator | None = None

    def __call__(self, samples: Iterable[Sample]) -> Iterator[Any]:
        if self.rng is None:
            self.rng = worker_generator(self.seed, self.rank, BUCKET_STREAM)
        pool: list[Sample] = []
        for sample in samples:
            pool.append(sample)
            if len(pool) == self.batch_size * self.pool_batches:
                yield from self._batches(pool, self.rng)
                pool = []
        yield from self._batches(pool[: len(pool) - len(pool) % self.batch_size], self.rng)

    def _batches(self, pool: list[Sample], rng: np.random.Generator) -> Iterator[Any]:
        by_length = np.argsort([len(sample[self.field]) for sample in pool], kind="stable")
        batches = by_length.reshape(-1, self.batch_size)
        for row in rng.permutation(len(batches)):
            yield self.collate([pool[index] for index in batches[row]])


def resampled_batches(
    urls: list[str],
    prepare: Callable[[Sample], Sample | None],
    batching: Batching,
    steps: int,
    shuffle_buffer: int,
    feed: LoaderFeed,
    seed: int,
) -> wds.WebLoader:
    """Endless resampled shards split by rank and worker, made into batches by ``batching`` (full
    ones only) and cut to ``steps`` batches an epoch, so every DDP rank runs the same number of
    steps whatever its shards hold. Every draw is a function of ``seed`` (the shards' of it, the
    epoch, the rank and the worker), so training the same config twice with as many workers sees
    the same batches: ``wds.WebDataset(resampled=True)`` and an unseeded ``.shuffle`` would seed
    from the clock and the process id."""
    dataset = wds.DataPipeline(
        wds.ResampledShards(urls, seed=seed, deterministic=True),
        wds.split_by_node,
        wds.split_by_worker,
        wds.tarfile_to_samples(),
        wds.shuffle(shuffle_buffer, seed=seed),
        wds.decode(),
        wds.map(prepare),
        batching,
    )
    loader = wds.WebLoader(
        dataset,
        batch_size=None,
        num_workers=feed.num_workers,
        pin_memory=feed.pin_memory,
        persistent_workers=feed.num_workers > 0,
    )
    return loader.with_epoch(steps).with_length(steps, silent=True)  # __len__ for progress bars and schedulers


def split_pass(
    urls: list[str],
    sizes: list[int],
    trainer: pl.Trainer | None,
    prepare: Callable[[Sample], Sample],
    collate: Callable[[list[Sample]], Any],
    batch_size: int,
    feed: LoaderFeed,
) -> wds.WebLoader:
    """One deterministic pass over a split whose shards hold ``sizes`` clips. Ranks share it clip
    by clip, not shard by shard (``rank_share``); the workers of a rank share its shards."""
    offsets = dict(zip(urls, np.cumsum([0] + sizes[:-1]).tolist()))
    rank, world_size = rank_and_world_size(trainer)
    dataset = (
        wds.WebDataset(urls, shardshuffle=False, nodesplitter=None, empty_check=False)
        .compose(partial(rank_share, offsets=offsets, rank=rank, world_size=world_size))
        .decode()
        .map(prepare)
        .batched(batch_size, collation_fn=collate, partial=True)
    )
    # workers kept between passes: a validation every few hundred steps would otherwise start them anew
    return wds.WebLoader(
        dataset,
        batch_size=None,
        num_workers=feed.num_workers,
        pin_memory=feed.pin_memory,
        persistent_workers=feed.num_workers > 0,
    )
