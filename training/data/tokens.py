"""The token models' data: captioned VQ token sequences, one random caption per clip and epoch in
training, bucketed by length (:class:`TokenDataModule`); upper/lower-body token pairs for MMM's
upper-body editor (:class:`BodyTokenDataModule`); and the length prior a model file keeps."""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable
from functools import cached_property, partial
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lightning.pytorch.utilities import rank_zero_info

from m2d2m.layout import VQ_FILE, token_shard_urls
from m2d2m.model_files import LengthPrior
from training.data.passes import require_positive
from training.data.samples import Sample, pad_clips, random_window, valid_frames, worker_generator
from training.data.shard_module import ShardDataModule
from training.data.shards import clip_metas, read_token_manifest, require_training_splits, token_arrays


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
