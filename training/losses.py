"""What every training step does with its loss besides minimising it: stop before the optimiser
step when it is not finite, and log it per quarter of the noise steps (the small-t quarter, where
detail is decided, learns differently from the rest: docs/training.md)."""

from __future__ import annotations

import lightning.pytorch as pl
import torch

QUARTERS = 4


class NonFiniteLossError(FloatingPointError):
    """The loss became NaN or infinite; raised before the optimiser step, so the weights and the
    last checkpoint on disk are still the last good ones."""


def check_finite(loss: torch.Tensor, step: int) -> None:
    """Raise :class:`NonFiniteLossError` for a NaN or infinite ``loss`` at training step ``step``."""
    if not torch.isfinite(loss):
        raise NonFiniteLossError(f"the training loss is {loss.item()} at step {step}")


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
    ``<name>_t<first>-<last>``: for T = 1000 from 0, ``train/loss_t0-249`` … ``train/loss_t750-999``."""
    index = (t.long() - first) * QUARTERS // steps
    for quarter in range(QUARTERS):
        chosen = index == quarter
        if chosen.any():
            low, end = -(-quarter * steps // QUARTERS), -(-(quarter + 1) * steps // QUARTERS)
            module.log(
                f"{name}_t{first + low}-{first + end - 1}",
                losses[chosen].mean(),
                batch_size=int(chosen.sum()),
                **options,
            )
