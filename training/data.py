"""WebDataset DataModules that feed the models from a processed dataset (docs/data.md, the processed dataset).

Training streams resampled shards split by rank and worker and cuts every epoch to the same number
of batches, so no DDP rank waits on another (webdataset's multi-node recipe,
webdataset.github.io/webdataset/multinode/); validation and test read each clip once, in shard
order, the ranks sharing them clip by clip. The shards, ``stats.npz``
and the manifest are all this shares with the pipelines that wrote them (through ``m2d2m.layout``).
Two feeds: motion windows for the VQ-VAE, and captioned token sequences for the token models
(upper/lower-body token pairs for MMM's upper-body editor). Training batches of sequences that vary
in length are bucketed by length (:class:`LengthBuckets`); on a GPU the loaders run in worker
processes and pin their batches (:func:`loader_feed`). docs/training.md, "Data loading".
"""

from __future__ import annotations

import io
import json
import math
import os
import tarfile
from collections import defaultdict
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from functools import cached_property, partial
from pathlib import Path
from typing import Any

import lightning.pytorch as pl
import numpy as np
import torch
import webdataset as wds
from lightning.pytorch.utilities import rank_zero_info

from m2d2m.layout import MANIFEST, STATS, TOKENS_KIND, VQ_FILE, read_manifest, shard_urls, token_shard_urls
from m2d2m.model_files import LengthPrior
from m2d2m.motion.representation.normalization import Normalizer

Sample = dict[str, Any]
Batching = Callable[[Iterable[Sample]], Iterator[Any]]  # a pipeline stage: samples in, collated batches out
AUTO_WORKERS = "auto"
MOST_AUTO_WORKERS = 8
BUCKET_POOL_BATCHES = 8
BUCKET_STREAM = 1  # ``worker_generator`` stream of the bucketed batch order (stream 0: the samples' own draws)


def clip_metas(urls: list[str]) -> Iterator[dict[str, Any]]:
    """The ``meta.json`` of every clip in local shards, in order, from those small members alone:
    the tar headers let the motion or token arrays be skipped instead of read."""
    for url in urls:
        with tarfile.open(url) as archive:
            for member in archive:
                if member.name.endswith(".meta.json"):
                    yield json.loads(archive.extractfile(member).read())


def clip_lengths(urls: list[str]) -> list[int]:
    """The frame count of every clip in local shards."""
    return [meta["frames"] for meta in clip_metas(urls)]


def require_positive(**values: int) -> None:
    """Refuse a zero or negative size, which would otherwise stall or empty a stream."""
    for name, value in values.items():
        if value < 1:
            raise ValueError(f"{name} must be a positive integer, got {value}")


def require_training_splits(urls: dict[str, list[str]], directory: Path) -> dict[str, list[str]]:
    """``urls`` when both the train and the val split have shards: training samples the one and
    validates (and keeps its checkpoints) on the other, so a dataset lacking either is refused in
    one line before anything runs, not with a traceback at the first validation."""
    empty = [split for split in ("train", "val") if not urls.get(split)]
    if empty:
        raise ValueError(
            f"{directory}: no {' and no '.join(empty)} motions, and training needs both; rebuild the dataset "
            "with motions in each split (the bvh corpus: name some in the split column of captions.csv)"
        )
    return urls


def worker_generator(seed: int, rank: int, *stream: int) -> np.random.Generator:
    """A Generator seeded from (seed, rank, DataLoader worker id): draws differ between workers and
    ranks, and never depend on global random state. Call it inside the worker, on first use.
    ``stream`` numbers a second, independent Generator of the same worker (one per purpose)."""
    worker = torch.utils.data.get_worker_info()
    return np.random.default_rng([seed, rank, 0 if worker is None else worker.id, *stream])


def random_window(motion: np.ndarray, window: int, rng: np.random.Generator) -> np.ndarray | None:
    """``window`` frames starting uniformly in [0, T − window]; None for a shorter clip, which is
    skipped rather than padded, as T2M-GPT does."""
    spare = len(motion) - window
    if spare < 0:
        return None
    start = int(rng.integers(spare + 1))
    return motion[start : start + window]


def pad_clips(clips: list[np.ndarray], dtype: torch.dtype = torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """Sequences of different lengths (T_i, ...) — motions (T, D) or tokens (L,) — as one
    zero-padded (B, T_max, ...) tensor of ``dtype`` and their lengths (B,) long, from which
    ``valid_frames`` rebuilds the mask."""
    lengths = torch.tensor([len(clip) for clip in clips], dtype=torch.long)
    batch = torch.zeros(len(clips), int(lengths.max()), *clips[0].shape[1:], dtype=dtype)
    for row, clip in zip(batch, clips):
        row[: len(clip)] = torch.from_numpy(clip)
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
            self.rng = worker_generator(self.seed, self.rank)
        crop = random_window(sample["motion.npy"], self.window, self.rng)
        return None if crop is None else {"motion": self.normalizer.normalize(crop)}


def rank_and_world_size(trainer: pl.Trainer | None) -> tuple[int, int]:
    """The trainer's rank and world size when attached, else what webdataset's node splitter sees
    (env RANK and WORLD_SIZE, then torch.distributed)."""
    if trainer is not None:
        return trainer.global_rank, trainer.world_size
    rank, world_size, _, _ = wds.utils.pytorch_worker_info()
    return rank, world_size


def require_workers(num_workers: int | str) -> None:
    """Refuse a worker count that is neither a count of processes (0: none) nor ``auto``."""
    if num_workers != AUTO_WORKERS and not (
        isinstance(num_workers, int) and not isinstance(num_workers, bool) and num_workers >= 0
    ):
        raise ValueError(f"num_workers must be 0 or more worker processes, or {AUTO_WORKERS!r}; got {num_workers!r}")


def usable_cpus() -> int:
    """Cores this process may run on (its affinity, which a cluster's scheduler narrows)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


@dataclass(frozen=True)
class LoaderFeed:
    """How a DataLoader hands its batches over: made by ``num_workers`` worker processes (0: by the
    training process between steps), in pinned (page-locked) memory when ``pin_memory``, from which
    Lightning's ``non_blocking`` copy to the GPU runs asynchronously."""

    num_workers: int
    pin_memory: bool


def loader_feed(num_workers: int | str, device: torch.device, cpus: int, processes: int) -> LoaderFeed:
    """The feed of a loader whose batches train on ``device``, one of ``processes`` training
    processes (DDP ranks) sharing ``cpus`` cores. ``auto`` on a GPU: the cores left after the
    training processes, shared among them, at least one and at most ``MOST_AUTO_WORKERS`` a
    process (the paper configs' count before ``auto``; one process alone already makes token
    batches faster than a paper-size step takes them, ``bench/loader.py``, docs/training.md); on a
    CPU: none, since the step's own threads keep every core busy and loading in the training
    process measured fastest on 2 cores (``bench/train_vq.py``). A count is taken as it is. Memory
    is pinned for a CUDA device only."""
    on_gpu = device.type == "cuda"
    if num_workers != AUTO_WORKERS:
        workers = int(num_workers)
    elif on_gpu:
        workers = max(1, min(MOST_AUTO_WORKERS, (cpus - processes) // processes))
    else:
        workers = 0
    return LoaderFeed(workers, pin_memory=on_gpu)


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


class MotionWindowDataModule(FeatureShardDataModule):
    """Random fixed-length windows of the train clips for the motion VQ-VAE; whole clips for
    validation and test. Every motion is normalised once, here, with the dataset's ``stats.npz``.
    Windows are all ``window`` frames long: nothing to bucket."""

    def __init__(
        self,
        data_dir: str | Path,
        window: int = 64,
        batch_size: int = 256,
        num_workers: int | str = 2,
        steps_per_epoch: int | None = None,
        val_batch_size: int = 32,
        shuffle_buffer: int = 1000,
        seed: int = 0,
    ) -> None:
        require_positive(window=window)
        super().__init__(
            data_dir, batch_size, num_workers, steps_per_epoch, val_batch_size, shuffle_buffer, seed, bucket=False
        )
        self.window = window

    @cached_property
    def _train_counts(self) -> tuple[int, int]:
        """(usable, too short) train clips, counted once; reports the skipped ones, and refuses a
        window no clip fills (the resampled stream would then never yield a batch)."""
        lengths = clip_lengths(self.urls("train"))
        too_short = sum(length < self.window for length in lengths)
        if too_short == len(lengths):
            raise ValueError(
                f"{self.data_dir}: none of the {len(lengths)} train clips has {self.window} frames; "
                "use a shorter window"
            )
        rank_zero_info(
            f"{self.data_dir.name}: {too_short} of {len(lengths)} train clips are shorter than "
            f"the {self.window}-frame window and are skipped"
        )
        return len(lengths) - too_short, too_short

    @property
    def too_short(self) -> int:
        """Train clips shorter than the window, which training never sees."""
        return self._train_counts[1]

    @property
    def train_clips(self) -> int:
        """Train clips long enough to give a window."""
        return self._train_counts[0]

    def _train_sample(self, rank: int):
        return WindowCropper(self.window, self.normalizer, self.seed, rank), stack_windows

    def _eval_sample(self):
        return partial(normalized_clip, normalizer=self.normalizer), collate_clips


def caption_span(caption: dict[str, Any], num_tokens: int, fps: float, frames_per_token: int) -> tuple[int, int] | None:
    """The tokens [first, last) a caption describes. ``start``/``end`` (seconds, both 0 = whole clip)
    are cut with T2M-GPT's rule ``int(second · fps / frames_per_token)``, widened to at least one
    token; None when nothing of the clip is left (a segment past its end, or end ≤ start)."""
    start, end = caption["start"], caption["end"]
    if start == 0 and end == 0:
        return 0, num_tokens
    if end <= start:
        return None
    first = int(start * fps / frames_per_token)
    last = min(max(int(end * fps / frames_per_token), first + 1), num_tokens)
    return (first, last) if first < last else None


def length_prior(urls: list[str], frames_per_token: int) -> LengthPrior:
    """Token lengths of the single-action captions (exactly one verb) of the clips in ``urls``: the
    median per verb and overall, and the longest clip — what generation falls back on when a
    prompt comes without a duration."""
    per_verb: dict[str, list[int]] = defaultdict(list)
    longest = 0
    for meta in clip_metas(urls):
        num_tokens = math.ceil(meta["frames"] / frames_per_token)
        longest = max(longest, num_tokens)
        for caption in meta["captions"]:
            span = caption_span(caption, num_tokens, meta["fps"], frames_per_token)
            if span is not None and len(caption.get("verbs", [])) == 1:
                per_verb[caption["verbs"][0]].append(span[1] - span[0])
    if not per_verb:
        raise ValueError("no single-action captions to estimate action lengths from")
    every = [n for lengths in per_verb.values() for n in lengths]
    return LengthPrior(
        {verb: int(np.median(lengths)) for verb, lengths in sorted(per_verb.items())}, int(np.median(every)), longest
    )


def captioned_tokens(
    tokens: np.ndarray, meta: dict[str, Any], caption: dict[str, Any], frames_per_token: int
) -> Sample:
    """{"tokens": the caption's segment (the whole clip when its segment is empty), "actions": its
    action sentences — the denoiser's condition concatenates their features — or, for a caption
    with none, the caption itself, "text"}."""
    span = caption_span(caption, len(tokens), meta["fps"], frames_per_token) or (0, len(tokens))
    return {
        "tokens": tokens[span[0] : span[1]],
        "actions": list(caption["actions"]) or [caption["text"]],
        "text": caption["text"],
    }


def first_caption_tokens(sample: Sample, frames_per_token: int) -> Sample:
    """A decoded token sample with its first caption: the deterministic choice for evaluation."""
    meta = sample["meta.json"]
    return captioned_tokens(sample["tokens.npy"], meta, meta["captions"][0], frames_per_token)


class CaptionSampler:
    """Turns a decoded token sample into one of its captions, drawn at random every time the clip
    is seen, with that caption's tokens, randomly cropped to ``max_tokens`` when longer (memory).
    Its Generator comes from ``worker_generator`` on first use inside each DataLoader worker."""

    def __init__(self, frames_per_token: int, max_tokens: int | None, seed: int, rank: int) -> None:
        self.frames_per_token, self.max_tokens, self.seed, self.rank = frames_per_token, max_tokens, seed, rank
        self.rng: np.random.Generator | None = None

    def __call__(self, sample: Sample) -> Sample:
        if self.rng is None:
            self.rng = worker_generator(self.seed, self.rank)
        meta = sample["meta.json"]
        caption = meta["captions"][int(self.rng.integers(len(meta["captions"])))]
        chosen = captioned_tokens(sample["tokens.npy"], meta, caption, self.frames_per_token)
        if self.max_tokens is not None and len(chosen["tokens"]) > self.max_tokens:
            chosen["tokens"] = random_window(chosen["tokens"], self.max_tokens, self.rng)
        return chosen


def collate_captioned_tokens(samples: list[Sample]) -> dict[str, Any]:
    """{"tokens": (B, L_max) long padded with 0, "padding_mask": (B, L_max) bool, True on real
    tokens, "lengths": (B,) long, "actions": per sample its action sentences, "text", "keys"}."""
    tokens, lengths = pad_clips([sample["tokens"] for sample in samples], dtype=torch.long)
    return {
        "tokens": tokens,
        "padding_mask": valid_frames(lengths),
        "lengths": lengths,
        "actions": [sample["actions"] for sample in samples],
        "text": [sample["text"] for sample in samples],
        "keys": [sample["__key__"] for sample in samples],
    }


def read_token_manifest(tokens_dir: Path) -> dict[str, Any]:
    """A token set's manifest, refusing a missing one or a directory that is not a token set (a
    processed dataset, say), with what to run instead."""
    path = tokens_dir / MANIFEST
    if not path.exists():
        raise FileNotFoundError(f"{path}: missing; no token set here (make one with `m2d2m tokenize` or `make tokens`)")
    manifest = read_manifest(tokens_dir)
    if manifest.get("kind") != TOKENS_KIND:
        raise ValueError(
            f"{path}: kind {manifest.get('kind')!r}, not a token set ({TOKENS_KIND!r}); pass the "
            "directory `m2d2m tokenize` wrote (data/<name>/tokens/<vq-run>/)"
        )
    return manifest


class TokenDataModule(ShardDataModule):
    """Captioned VQ token sequences (``data/<name>/tokens/<vq-run>/``) for the discrete-diffusion
    denoiser: in training, one random caption per clip and epoch with its segment of the tokens,
    bucketed by the segment's length; in validation and test, every clip once with its first
    caption."""

    length_field = "tokens"

    def __init__(
        self,
        tokens_dir: str | Path,
        batch_size: int = 64,
        num_workers: int | str = 2,
        steps_per_epoch: int | None = None,
        val_batch_size: int = 64,
        shuffle_buffer: int = 1000,
        max_tokens: int | None = None,
        seed: int = 0,
        bucket: bool = True,
    ) -> None:
        super().__init__(batch_size, num_workers, steps_per_epoch, val_batch_size, shuffle_buffer, seed, bucket)
        require_positive(max_tokens=1 if max_tokens is None else max_tokens)
        self.tokens_dir = Path(tokens_dir).resolve()
        self.manifest = read_token_manifest(self.tokens_dir)
        self.max_tokens = max_tokens
        # A split's token shards sit in the token directory itself (no ``shards/``).
        self._urls = require_training_splits(
            {split: token_shard_urls(self.tokens_dir, split) for split in self.manifest["shards"]}, self.tokens_dir
        )

    @property
    def codebook_size(self) -> int:
        return int(self.manifest["codebook_size"])

    @property
    def frames_per_token(self) -> int:
        return int(self.manifest["frames_per_token"])

    @property
    def vq_file(self) -> Path:
        """The VQ model that made the tokens: its codebook builds the transitions, its decoder
        turns samples back into motion."""
        return self.tokens_dir / VQ_FILE

    @cached_property
    def _train_captions(self) -> tuple[float, int, int]:
        """(fps, train captions, those whose segment is empty), read once from the train clips'
        ``meta.json``; refuses a token set without train clips (the resampled stream would never
        yield a batch)."""
        metas = list(clip_metas(self.urls("train")))
        if not metas:
            raise ValueError(f"{self.tokens_dir}: the token set holds no train clips")
        captions = empty = 0
        for meta in metas:
            num_tokens = math.ceil(meta["frames"] / self.frames_per_token)
            captions += len(meta["captions"])
            empty += sum(
                caption_span(c, num_tokens, meta["fps"], self.frames_per_token) is None for c in meta["captions"]
            )
        return float(metas[0]["fps"]), captions, empty

    @property
    def fps(self) -> float:
        return self._train_captions[0]

    @property
    def empty_segments(self) -> int:
        """Train captions whose segment cuts no token, which fall back to their whole clip."""
        return self._train_captions[2]

    @property
    def train_clips(self) -> int:
        """Every train clip: each has a caption to train on."""
        return sum(self._sizes("train"))

    def _train_sample(self, rank: int):
        """Also reports, each time a train loader is made, the captions whose segment is empty."""
        _, captions, empty = self._train_captions
        if empty:
            rank_zero_info(
                f"{self.tokens_dir}: {empty} of {captions} train captions have a start/end segment "
                "with no tokens of their clip; they train on the whole clip"
            )
        return CaptionSampler(self.frames_per_token, self.max_tokens, self.seed, rank), collate_captioned_tokens

    def _eval_sample(self):
        return partial(first_caption_tokens, frames_per_token=self.frames_per_token), collate_captioned_tokens


def token_arrays(urls: list[str]) -> dict[str, np.ndarray]:
    """Every clip's ``tokens.npy`` in local token shards, by key."""
    arrays = {}
    for url in urls:
        with tarfile.open(url) as archive:
            for member in archive:
                if member.name.endswith(".tokens.npy"):
                    key = member.name[: -len(".tokens.npy")]
                    arrays[key] = np.load(io.BytesIO(archive.extractfile(member).read()), allow_pickle=False)
    return arrays


def with_lower_body(sample: Sample, lower: dict[str, np.ndarray], then: Callable[[Sample], Sample]) -> Sample:
    """A decoded upper-body token sample whose ``tokens.npy`` becomes the (L, 2) pairs with the same
    clip's lower-body tokens, handed to ``then`` (a caption sampler)."""
    upper = sample["tokens.npy"]
    return then({**sample, "tokens.npy": np.stack([upper, lower[sample["__key__"]].astype(upper.dtype)], axis=-1)})


class BodyTokenDataModule(TokenDataModule):
    """Upper- and lower-body token sets of one dataset, made by MMM's two part tokenizers, as
    pairs: every clip's tokens are (L, 2), upper then lower, cut by the same caption segment and
    crop. The upper set is streamed; the lower one (int16, a few MB even for HumanML3D) is read
    into memory at the start and joined by clip key."""

    def __init__(
        self,
        tokens_dir: str | Path,
        lower_tokens_dir: str | Path,
        batch_size: int = 64,
        num_workers: int | str = 2,
        steps_per_epoch: int | None = None,
        val_batch_size: int = 64,
        shuffle_buffer: int = 1000,
        max_tokens: int | None = None,
        seed: int = 0,
        bucket: bool = True,
    ) -> None:
        super().__init__(
            tokens_dir,
            batch_size,
            num_workers,
            steps_per_epoch,
            val_batch_size,
            shuffle_buffer,
            max_tokens,
            seed,
            bucket,
        )
        self.lower_tokens_dir = Path(lower_tokens_dir).resolve()
        lower_manifest = read_token_manifest(self.lower_tokens_dir)
        if (
            lower_manifest.get("source_shards") != self.manifest.get("source_shards")
            or lower_manifest["frames_per_token"] != self.manifest["frames_per_token"]
        ):
            raise ValueError(
                f"{self.lower_tokens_dir} and {self.tokens_dir} are not token sets of the same dataset "
                "build at the same frame rate"
            )
        self.lower = token_arrays(
            [url for split in lower_manifest["shards"] for url in token_shard_urls(self.lower_tokens_dir, split)]
        )

    def _train_sample(self, rank: int):
        sampler, collate = super()._train_sample(rank)
        return partial(with_lower_body, lower=self.lower, then=sampler), collate

    def _eval_sample(self):
        first, collate = super()._eval_sample()
        return partial(with_lower_body, lower=self.lower, then=first), collate
