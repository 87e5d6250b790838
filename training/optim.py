"""The optimiser every LightningModule here trains with: AdamW from a config's ``optim`` section,
optionally with a linear warm-up and step decay per step (T2M-GPT's schedule: Mael-zys/T2M-GPT,
``train_vq.py``; the values per stage are in docs/training.md)."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from typing import Any

import torch

# The defaults of the ``optim`` keys a config may leave out; ``lr`` has none.
DEFAULT_BETAS = (0.9, 0.999)  # torch's AdamW default
DEFAULT_WEIGHT_DECAY = 0.0
DEFAULT_WARMUP_STEPS = 0
DEFAULT_GAMMA = 1.0  # with no milestones either: a constant rate after warm-up


def warmup_step_decay(warmup_steps: int, milestones: list[int], gamma: float) -> Callable[[int], float]:
    """Learning-rate factor of step s: linear warm-up to 1, then × gamma at each milestone."""

    def factor(step: int) -> float:
        if step < warmup_steps:
            return (step + 1) / (warmup_steps + 1)
        return gamma ** sum(step >= m for m in milestones)

    return factor


def configure_adamw(
    parameters: Iterable[torch.nn.Parameter],
    optim: Mapping[str, Any],
    *,
    decay_matrices_only: bool = False,
    scheduled: bool = True,
    fused: bool = False,
) -> dict[str, Any]:
    """Lightning's ``configure_optimizers`` answer for AdamW over the trainable ``parameters``.

    ``optim`` gives ``lr`` and, defaulting to the constants above, ``betas``, ``weight_decay``,
    ``warmup_steps``, ``milestones`` and ``gamma``. With ``decay_matrices_only`` the weight decay
    spares biases, norms' gains and other parameters of fewer than 2 dimensions, as nanoGPT does
    (karpathy/nanoGPT, ``model.py``, ``configure_optimizers``); otherwise every parameter is in one
    group. With ``scheduled`` the rate follows :func:`warmup_step_decay`, stepped every batch.
    ``fused``: torch's fused AdamW, one kernel over every parameter (the same update to rounding;
    :meth:`training.step.TrainingModule.fuses_optimizer` says where it may run); otherwise torch's
    default implementation for the device.
    """
    params = [p for p in parameters if p.requires_grad]
    weight_decay = optim.get("weight_decay", DEFAULT_WEIGHT_DECAY)
    if decay_matrices_only:
        groups = [
            {"params": [p for p in params if p.ndim >= 2], "weight_decay": weight_decay},
            {"params": [p for p in params if p.ndim < 2], "weight_decay": 0.0},
        ]
    else:
        groups = [{"params": params, "weight_decay": weight_decay}]
    optimizer = torch.optim.AdamW(
        groups,
        lr=optim["lr"],
        betas=tuple(optim.get("betas", DEFAULT_BETAS)),
        weight_decay=weight_decay,
        fused=fused or None,
    )
    if not scheduled:
        return {"optimizer": optimizer}
    factor = warmup_step_decay(
        optim.get("warmup_steps", DEFAULT_WARMUP_STEPS),
        list(optim.get("milestones", [])),
        optim.get("gamma", DEFAULT_GAMMA),
    )
    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, factor)
    return {"optimizer": optimizer, "lr_scheduler": {"scheduler": schedule, "interval": "step"}}
