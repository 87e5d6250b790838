"""What every training step does with its loss besides minimising it: watch that it stays finite,
and log it per quarter of the noise steps (the small-t quarter, where detail is decided, learns
differently from the rest: docs/training.md). Both stay on the device: on a GPU, reading a tensor
on the host makes the host wait for every kernel queued before it, so the host reads only at the
steps Lightning writes its logs, where it reads every logged metric anyway (:func:`is_logging_step`)."""

from __future__ import annotations

import lightning.pytorch as pl
import torch

QUARTERS = 4


class NonFiniteLossError(FloatingPointError):
    """The loss became NaN or infinite. Raised at the first host read after it happened, before any
    checkpoint, validation or model file is written, so the last checkpoint on disk is still the
    last good one (:class:`FiniteLossGuard`)."""


def is_logging_step(trainer: pl.Trainer) -> bool:
    """Whether the step that just ended is one Lightning logs at: every ``log_every_n_steps``
    optimiser steps (its ``_LoggerConnector.should_update_logs``, in ``on_train_batch_end``, where
    ``global_step`` already counts this step). Lightning reads every logged metric to the host
    then, so one more read there makes the device wait no longer."""
    every = trainer.log_every_n_steps
    return bool(every) and trainer.global_step % every == 0


class FiniteLossGuard(pl.LightningModule):
    """A LightningModule that stops training on a NaN or infinite loss without reading the loss on
    the host every step. Its ``training_step`` hands the loss to :meth:`guard_finite`, which notes
    on the device the first step whose loss was not finite; :meth:`raise_if_not_finite` reads that
    note, at every step Lightning logs, before each validation, before any checkpoint is written
    (snapshots and Ray's included, through ``on_save_checkpoint``) and at the end of training,
    before the model file.

    The optimiser steps after a non-finite loss until the next of those reads (at most
    ``log_every_n_steps`` steps), so the weights in memory may be spoilt by then; none of them is
    ever written, and the last checkpoint on disk is still the last good one (docs/reliability.md,
    "A non-finite loss"). Skipping the update on the device instead would need an optimiser that
    takes a found-inf flag (torch's fused AdamW) and would still leave buffers updated in the
    forward pass (the VQ-VAE's codebook) spoilt."""

    _not_finite_step: torch.Tensor | None = None  # the first such step, -1 while there is none
    _not_finite_loss: torch.Tensor | None = None  # its loss

    def guard_finite(self, loss: torch.Tensor) -> None:
        """Note ``loss`` of this training step (``self.global_step``) if it is the first that is not finite."""
        value = loss.detach().float()
        if self._not_finite_step is None:
            self._not_finite_step = torch.full((), -1, dtype=torch.long, device=value.device)
            self._not_finite_loss = torch.zeros((), device=value.device)
        first = ~torch.isfinite(value) & (self._not_finite_step < 0)
        self._not_finite_step = torch.where(first, self.global_step, self._not_finite_step)
        self._not_finite_loss = torch.where(first, value, self._not_finite_loss)

    def raise_if_not_finite(self) -> None:
        """Raise :class:`NonFiniteLossError` if a noted loss was not finite: one host read."""
        if self._not_finite_step is not None and (step := int(self._not_finite_step)) >= 0:
            raise NonFiniteLossError(f"the training loss is {float(self._not_finite_loss)} at step {step}")

    def on_train_start(self) -> None:
        self._not_finite_step = self._not_finite_loss = None

    def on_train_batch_end(self, outputs: object, batch: object, batch_idx: int) -> None:
        if is_logging_step(self.trainer):
            self.raise_if_not_finite()

    def on_validation_start(self) -> None:
        self.raise_if_not_finite()

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        self.raise_if_not_finite()

    def on_train_end(self) -> None:
        self.raise_if_not_finite()


def log_by_quarter(
    module: pl.LightningModule,
    name: str,
    losses: torch.Tensor,
    t: torch.Tensor,
    first: int,
    steps: int,
    **options: object,
) -> None:
    """Log ``losses`` (one per sample) averaged over each quarter of the process's ``steps`` noise
    steps, numbered from ``first`` (0 for a Gaussian DDPM's t, 1 for a discrete diffusion's), as
    ``<name>_t<first>-<last>``: for T = 1000 from 0, ``train/loss_t0-249`` … ``train/loss_t750-999``.

    Each quarter's mean is accumulated over the epoch (the stretch between validations) weighted
    by its number of samples, a tensor, and read once at the epoch's end: a step's batch holds a
    handful of samples per quarter, some none, and the host never has to look. A quarter without a
    sample in a step weighs nothing; one without a sample in the whole epoch is logged as NaN."""
    index = (t.long() - first) * QUARTERS // steps
    # (B, 4): a comparison, not F.one_hot, which checks its input's range on the host
    chosen = (index[:, None] == torch.arange(QUARTERS, device=index.device)).to(losses.dtype)
    counts = chosen.sum(dim=0)
    means = (losses[:, None] * chosen).sum(dim=0) / counts.clamp(min=1)
    for quarter in range(QUARTERS):
        low, end = -(-quarter * steps // QUARTERS), -(-(quarter + 1) * steps // QUARTERS)
        module.log(
            f"{name}_t{first + low}-{first + end - 1}",
            means[quarter],
            batch_size=counts[quarter],
            **{"on_step": False, "on_epoch": True, **options},
        )
