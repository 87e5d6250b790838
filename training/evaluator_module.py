"""The text–motion evaluator as a LightningModule, and the DataModule of caption/motion pairs it
trains on (Guo et al.'s ``Text2MotionDatasetV2`` and matching trainer: EricGuo5513/text-to-motion, ``data/dataset.py`` and ``networks/trainers.py``).

Pairs follow Guo's loader: a clip's caption is drawn afresh each time the clip is seen; a caption
with a start/end segment pairs with that segment of the clip; only pairs of at least ``min_frames``
are kept (Guo: 40); the motion is cut at a random place to a multiple of 4 frames, one unit shorter
with probability 1/3. Motions stay un-normalised: the evaluator normalises them with the statistics
it carries, so training and every later use see the same input. One deliberate difference: a pair
longer than ``max_frames`` (Guo: 196) is cropped to it at random instead of dropped.

The module trains all three encoders together with Guo's contrastive loss. Guo first pre-trains
the movement encoder as an autoencoder and then freezes it, a stage left out here.
"""

from __future__ import annotations

from functools import cached_property, partial
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lightning.pytorch.utilities import rank_zero_info

from m2d2m.evaluation.evaluator import UNIT_LENGTH, EvaluatorConfig, TextMotionEvaluator, contrastive_loss
from m2d2m.motion.representation.normalization import Normalizer
from training.data.samples import Sample, pad_clips, random_window, worker_generator
from training.data.shard_module import FeatureShardDataModule
from training.data.shards import clip_metas
from training.data.tokens import caption_span
from training.optim import configure_adamw
from training.step import TrainingModule

SHORTER_UNIT_CHANCE = 1 / 3  # Guo's "double" coin: one 4-frame unit less


def usable_spans(meta: dict[str, Any], frames: int, min_frames: int) -> list[tuple[dict[str, Any], tuple[int, int]]]:
    """Every caption of a ``frames``-frame clip with the frames [first, last) it describes — the
    whole clip, or its start/end segment cut at ``int(second · fps)`` — when that is at least
    ``min_frames`` long."""
    spans = [(caption, caption_span(caption, frames, meta["fps"], 1)) for caption in meta["captions"]]
    return [(caption, span) for caption, span in spans if span is not None and span[1] - span[0] >= min_frames]


def caption_clips(motion: np.ndarray, meta: dict[str, Any], min_frames: int) -> list[tuple[dict[str, Any], np.ndarray]]:
    """The (caption, motion frames) pairs of a clip, for its usable spans."""
    return [(caption, motion[first:last]) for caption, (first, last) in usable_spans(meta, len(motion), min_frames)]


def pair_sample(caption: dict[str, Any], motion: np.ndarray) -> Sample:
    return {"motion": motion, "tokens": list(caption["tokens"]), "text": caption["text"]}


class PairSampler:
    """Turns a decoded train sample into a random caption/motion pair, or None (dropped) when no
    caption describes ``min_frames`` frames. Its Generator comes from ``worker_generator`` on first
    use inside each DataLoader worker."""

    def __init__(self, min_frames: int, max_frames: int, seed: int, rank: int) -> None:
        self.min_frames, self.max_frames, self.seed, self.rank = min_frames, max_frames, seed, rank
        self.rng: np.random.Generator | None = None

    def __call__(self, sample: Sample) -> Sample | None:
        if self.rng is None:
            self.rng = worker_generator(self.seed, self.rank)
        pairs = caption_clips(sample["motion.npy"], sample["meta.json"], self.min_frames)
        if not pairs:
            return None
        caption, motion = pairs[int(self.rng.integers(len(pairs)))]
        units = min(len(motion), self.max_frames) // UNIT_LENGTH
        if units > 1 and self.rng.random() < SHORTER_UNIT_CHANCE:
            units -= 1
        return pair_sample(caption, random_window(motion, units * UNIT_LENGTH, self.rng))


def first_pair(sample: Sample, min_frames: int, max_frames: int) -> Sample | None:
    """The deterministic pair for validation and test: the first caption long enough, its first
    frames up to ``max_frames``, cut to a multiple of 4."""
    pairs = caption_clips(sample["motion.npy"], sample["meta.json"], min_frames)
    if not pairs:
        return None
    caption, motion = pairs[0]
    return pair_sample(caption, motion[: min(len(motion), max_frames) // UNIT_LENGTH * UNIT_LENGTH])


def collate_pairs(samples: list[Sample]) -> dict[str, Any]:
    """{"motion": (B, T_max, D) un-normalised, zero-padded, "lengths": (B,) long, "tokens": per
    sample its ``word/POS`` tokens, "text", "keys"}."""
    motion, lengths = pad_clips([sample["motion"] for sample in samples])
    return {
        "motion": motion,
        "lengths": lengths,
        "tokens": [sample["tokens"] for sample in samples],
        "text": [sample["text"] for sample in samples],
        "keys": [sample["__key__"] for sample in samples],
    }


class CaptionMotionDataModule(FeatureShardDataModule):
    """Caption/motion pairs of a processed dataset for the evaluator and MotionDiffuse: a random
    pair per clip and epoch in training (bucketed by the motion's length when ``bucket``), each
    clip's first pair once in validation and test. ``bucket`` is off unless asked for, as the
    evaluator needs it: it pads every motion to its ``max_motion_length`` itself, so bucketing
    saves it nothing, while it would make every contrastive negative as long as its positive.
    MotionDiffuse, which computes on every padded frame, asks for it."""

    length_field = "motion"

    def __init__(
        self,
        data_dir: str | Path,
        batch_size: int = 32,
        num_workers: int | str = 2,
        steps_per_epoch: int | None = None,
        val_batch_size: int = 32,
        shuffle_buffer: int = 1000,
        min_frames: int = 40,
        max_frames: int = 196,
        seed: int = 0,
        bucket: bool = False,
    ) -> None:
        if not UNIT_LENGTH <= min_frames <= max_frames:
            raise ValueError(f"need {UNIT_LENGTH} <= min_frames <= max_frames, got {min_frames} and {max_frames}")
        super().__init__(
            data_dir, batch_size, num_workers, steps_per_epoch, val_batch_size, shuffle_buffer, seed, bucket
        )
        self.min_frames, self.max_frames = min_frames, max_frames

    @cached_property
    def _train_survey(self) -> tuple[list[list[str]], int]:
        """(the tokens of every train caption, train clips with a caption of ``min_frames``), read
        once from the clips' ``meta.json``; refuses a split where no clip has one (the resampled
        stream would never yield a batch)."""
        captions, usable, clips = [], 0, 0
        for meta in clip_metas(self.urls("train")):
            clips += 1
            captions += [list(caption["tokens"]) for caption in meta["captions"]]
            usable += bool(usable_spans(meta, meta["frames"], self.min_frames))
        if not usable:
            raise ValueError(
                f"{self.data_dir}: none of the {clips} train clips has a caption describing "
                f"{self.min_frames} frames; lower min_frames"
            )
        rank_zero_info(
            f"{self.data_dir.name}: {clips - usable} of {clips} train clips have no caption describing "
            f"{self.min_frames} frames and are skipped"
        )
        return captions, usable

    def train_captions(self) -> list[list[str]]:
        """The ``word/POS`` tokens of every train caption: what a learned word table's vocabulary
        is built from (``m2d2m.evaluator.learned_vocabulary``)."""
        return self._train_survey[0]

    @property
    def train_clips(self) -> int:
        """Train clips with at least one usable pair."""
        return self._train_survey[1]

    def _train_sample(self, rank: int):
        return PairSampler(self.min_frames, self.max_frames, self.seed, rank), collate_pairs

    def _eval_sample(self):
        return partial(first_pair, min_frames=self.min_frames, max_frames=self.max_frames), collate_pairs


class EvaluatorModule(TrainingModule):
    """Guo's text–motion matching: contrastive loss (margin ``loss["margin"]``, Guo 10) between
    each caption and its motion and, as negatives, the motions of a random shift of the batch;
    Adam(W) over the trainable weights (Guo: Adam 1e-4, gradient norm clipped to 0.5, which the
    trainer applies). Validation scores a fixed shift of half the batch and reports the batch's top-1
    retrieval accuracy and mean matched distance (the matching score), for the best checkpoint.

    ``model`` holds :class:`EvaluatorConfig` fields but ``feature_dim``; ``vocabulary`` and
    ``word_vectors`` are as :class:`TextMotionEvaluator` takes them."""

    def __init__(
        self,
        model: dict[str, Any],
        optim: dict[str, Any],
        loss: dict[str, Any],
        feature_dim: int,
        vocabulary: list[str],
        word_vectors: torch.Tensor | None = None,
    ) -> None:
        super().__init__()
        self.save_hyperparameters(ignore=["word_vectors"])
        config = EvaluatorConfig.from_dict({**model, "feature_dim": feature_dim})
        self.model = TextMotionEvaluator(config, vocabulary, word_vectors)

    def model_parts(self) -> dict[str, Any]:
        """The network this module gives its model file (``EVALUATOR_FORMAT``, m2d2m/evaluation/evaluator.py)."""
        return {"model": self.model}

    def set_normalizer(self, normalizer: Normalizer) -> None:
        """The dataset's normalisation becomes the evaluator's own, carried in its weights."""
        self.model.set_statistics(normalizer.mean, normalizer.scale)

    def transfer_batch_to_device(self, batch: dict[str, Any], device: torch.device, dataloader_idx: int) -> dict:
        """The batch on ``device`` but for the motions' lengths, which stay on the host: the
        evaluator checks them and packs its GRUs' sequences by them there
        (TextMotionEvaluator.embed_motion), and reading them back from the device would make the
        host wait."""
        rest = {key: value for key, value in batch.items() if key != "lengths"}
        return {**super().transfer_batch_to_device(rest, device, dataloader_idx), "lengths": batch["lengths"]}

    def _embed(self, batch: dict[str, Any]) -> tuple[torch.Tensor, torch.Tensor]:
        return self.model.embed_text(batch["tokens"]), self.model.embed_motion(batch["motion"], batch["lengths"])

    def training_step(self, batch: dict[str, Any], batch_idx: int) -> torch.Tensor:
        """The negatives are the motions a random shift of the batch away, the shift drawn on the
        device and never read on the host."""
        text, motion = self._embed(batch)
        batch_size = len(text)
        shift = torch.randint(1, batch_size, (), device=motion.device)
        terms = contrastive_loss(text, motion, shift, self.hparams.loss["margin"])
        self.guard_finite(terms.total)
        self.log("train/loss", terms.total, batch_size=batch_size)
        self.log("train/positive", terms.positive, batch_size=batch_size)
        self.log("train/negative", terms.negative, batch_size=batch_size)
        return terms.total

    def validation_step(self, batch: dict[str, Any], batch_idx: int) -> None:
        batch_size = len(batch["tokens"])
        if batch_size < 2:  # a lone pair has no negative
            return
        text, motion = self._embed(batch)
        # half a batch away, not 1: the shards store each clip next to its mirror, a near-duplicate
        terms = contrastive_loss(text, motion, batch_size // 2, self.hparams.loss["margin"])
        distances = torch.cdist(text.float(), motion.float())
        top1 = (distances.argmin(dim=1) == torch.arange(batch_size, device=distances.device)).float().mean()
        self.log("val/loss", terms.total, batch_size=batch_size, sync_dist=True, prog_bar=True)
        self.log("val/positive", terms.positive, batch_size=batch_size, sync_dist=True)
        self.log("val/negative", terms.negative, batch_size=batch_size, sync_dist=True)
        self.log("val/top1", top1, batch_size=batch_size, sync_dist=True, prog_bar=True)
        self.log("val/matching_score", distances.diagonal().mean(), batch_size=batch_size, sync_dist=True)

    def configure_optimizers(self) -> dict[str, Any]:
        # Guo trains at a constant rate: no schedule
        return configure_adamw(self.parameters(), self.hparams.optim, scheduled=False, fused=self.fuses_optimizer())
