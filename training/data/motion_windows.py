"""The motion VQ-VAE's data: random fixed-length windows of the train clips, whole clips for
validation and test."""

from __future__ import annotations

from functools import cached_property, partial
from pathlib import Path

from lightning.pytorch.utilities import rank_zero_info

from training.data.passes import require_positive
from training.data.samples import WindowCropper, collate_clips, normalized_clip, stack_windows
from training.data.shard_module import FeatureShardDataModule
from training.data.shards import clip_lengths


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
