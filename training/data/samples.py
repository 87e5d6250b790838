"""One decoded clip into a training or evaluation sample, and samples into a batch: random windows,
padding, masks, the normalised whole clip. Every random draw comes from a Generator per DataLoader
worker (``worker_generator``), never from global random state."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from m2d2m.motion.representation.normalization import Normalizer

Sample = dict[str, Any]


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
