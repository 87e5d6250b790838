"""Training objective of the denoiser: L_vlb + λ·auxiliary cross-entropy (paper Eq. 3;
microsoft/VQ-Diffusion, ``diffusion_transformer.py`` ``_train_loss``).

The network predicts x0 logits over the K codes; its posterior p(z_{t−1} | z_t) is the mixture of
true posteriors weighted by softmax(logits) (paper Eq. 4), computed by
:meth:`TransitionSchedule.posterior_probs`. It is computed in the logits' precision but never below
float32 — float32 for a training step's float32 or bf16 logits, as VQ-Diffusion trains, so no float64
runs on a GPU; float64 for float64 logits — and returned in the logits' dtype. Float32 gives the
float64 loss and gradient to float32's rounding (``tests/test_training_precision.py``): every term is
a product, ratio or sum of positive probabilities, and no 1 − x is taken in float32.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from m2d2m.processes.discrete_diffusion import TransitionSchedule

# log-probabilities are floored here (≈ VQ-Diffusion's clamp at −70) so a zero never gives inf or NaN
_LOG_FLOOR = 1e-30


@dataclass(frozen=True)
class DiffusionLoss:
    """The loss to back-propagate and per-sample terms for logging (e.g. per t bucket)."""

    loss: Tensor  # scalar: importance-weighted per-token L_vlb + λ·aux over the batch
    vlb: Tensor  # (B,): each sample's mean L_vlb term over its valid positions (not weighted by 1/p(t))
    aux: Tensor  # (B,): each sample's mean auxiliary cross-entropy over its valid positions


def _per_sample(t: int | Tensor, like: Tensor) -> int | Tensor:
    """t as the posterior takes it: an int as it is, a (B,) per-sample t shaped (B, 1, …) to
    broadcast with ``like`` (B, ...), t per position as it is."""
    if isinstance(t, int):
        return t
    tt = torch.as_tensor(t, device=like.device).long()
    if tt.dim() == 1 and like.dim() > 1:
        tt = tt.reshape(-1, *([1] * (like.dim() - 1)))
    return tt


def diffusion_loss(
    schedule: TransitionSchedule,
    logits: Tensor,
    z0: Tensor,
    z_t: Tensor,
    t: int | Tensor,
    valid: Tensor | None = None,
    aux_weight: float = 5e-4,
    pt: Tensor | None = None,
    adaptive_aux: bool = False,
    validate: bool = True,
) -> DiffusionLoss:
    """L_vlb + λ·CE(x0) for logits (B, ..., K), codes z0 and z_t (B, ...), t (int, (B,) or per position).

    - L_vlb at a position is −log p(z0 | z_1) = −log softmax(logits)[z0] at t = 1 and
      KL(q(z_{t−1} | z_t, z0) ‖ p(z_{t−1} | z_t)) for t > 1.
    - The auxiliary term is −log softmax(logits)[z0] on every valid position, masked or not
      (VQ-Diffusion's ``mask_weight = [1, 1]``), optionally scaled by VQ-Diffusion's adaptive factor
      2 − (t − 1)/T (its code counts t from 0).
    - ``valid`` (B, ...) marks real (non-padding) positions. The loss is the mean over all valid
      tokens of the batch (VQ-Diffusion normalises per token too), each sample weighted by
      1/(T·pt): pt is the probability with which its t was drawn (None = uniform), so the weight is 1
      under uniform sampling and the estimate stays unbiased under importance sampling.

    The KL is computed at every position and kept where it is the term (t > 1, valid): choosing the
    positions first would make the host read the data (a device sync per step) for a saving of
    1/T and the padding. ``validate=False`` skips the schedule's range checks of the codes and t
    (each also a sync): for a training step, whose inputs are valid by construction.
    """
    num_codes = schedule.num_codes
    if z0.dim() < 1 or logits.shape[-1] != num_codes or logits.shape[:-1] != z0.shape or z0.shape != z_t.shape:
        raise ValueError(
            f"need logits (..., {num_codes}) and z0, z_t of shape logits.shape[:-1]; got "
            f"{tuple(logits.shape)}, {tuple(z0.shape)}, {tuple(z_t.shape)}"
        )
    device = logits.device
    z0 = z0.to(device).long()
    z_t = z_t.to(device).long()
    t_posterior = _per_sample(t, z0)
    tt = torch.broadcast_to(torch.as_tensor(t_posterior, device=device), z0.shape)
    mask = torch.ones_like(z0, dtype=torch.bool) if valid is None else valid.to(device).bool()
    if mask.shape != z0.shape:
        raise ValueError(f"valid must have shape {tuple(z0.shape)}, got {tuple(mask.shape)}")

    # padding may hold any value (e.g. a pad index >= K): read it as code 0, its weight is 0 anyway
    z0 = torch.where(mask, z0, 0)
    z_t = torch.where(mask, z_t, 0)
    dtype = torch.promote_types(logits.dtype, torch.float32)
    log_x0 = F.log_softmax(logits.to(dtype), dim=-1)
    nll = -log_x0.gather(-1, z0.unsqueeze(-1)).squeeze(-1)

    model = schedule.posterior_probs(z_t, log_x0.exp(), t_posterior, validate=validate, dtype=dtype)
    truth = schedule.true_posterior(z_t, z0, t_posterior, validate=validate, dtype=dtype)
    kl = (truth * (truth.clamp_min(_LOG_FLOOR).log() - model.clamp_min(_LOG_FLOOR).log())).sum(dim=-1)
    later = (tt > 1) & mask  # positions whose L_vlb term is a KL; the rest are the t = 1 decoder NLL
    vlb_pos = torch.where(later, kl.to(device), nll)

    aux_pos = nll
    if adaptive_aux:
        aux_pos = aux_pos * (2.0 - (tt - 1).to(dtype) / schedule.steps)

    batch = z0.shape[0]
    weight = mask.to(dtype).reshape(batch, -1)
    count = weight.sum(dim=1)
    vlb = (vlb_pos.reshape(batch, -1) * weight).sum(dim=1) / count.clamp_min(1.0)
    aux = (aux_pos.reshape(batch, -1) * weight).sum(dim=1) / count.clamp_min(1.0)
    importance = torch.ones_like(count) if pt is None else 1.0 / (schedule.steps * pt.to(device, dtype))
    per_sample = ((vlb_pos + aux_weight * aux_pos).reshape(batch, -1) * weight).sum(dim=1)
    loss = (importance * per_sample).sum() / count.sum().clamp_min(1.0)
    return DiffusionLoss(
        loss=loss.to(logits.dtype), vlb=vlb.to(logits.dtype).detach(), aux=aux.to(logits.dtype).detach()
    )


class TimestepSampler(nn.Module):
    """Draws t ∈ 1..T per sample, uniformly or by importance (VQ-Diffusion's ``sample_time``).

    Importance: keep an EMA (weight ``decay`` on the new value) of each t's squared L_vlb term; once
    every t has been seen more than ``warmup`` times, sample p(t) ∝ sqrt(EMA) + 1e-4, with t = 1 given
    the weight of t = 2 because its term is a decoder NLL on another scale. The history is a buffer,
    so it travels with checkpoints and devices. It is per process: under data parallelism each
    replica keeps its own.
    """

    def __init__(self, steps: int = 100, mode: str = "uniform", warmup: int = 10, decay: float = 0.1) -> None:
        super().__init__()
        if mode not in ("uniform", "importance"):
            raise ValueError(f"mode must be 'uniform' or 'importance', got {mode!r}")
        if steps < 1 or not 0.0 < decay <= 1.0:
            raise ValueError("need steps >= 1 and 0 < decay <= 1")
        self.steps = steps
        self.mode = mode
        self.warmup = warmup
        self.decay = decay
        # float32, like the loss it follows: nothing of a training step is float64 on a GPU
        self.register_buffer("history", torch.zeros(steps, dtype=torch.float32))
        self.register_buffer("count", torch.zeros(steps, dtype=torch.long))

    def probs(self) -> Tensor:
        """p(t) for t = 1..T (float32, index t − 1)."""
        uniform = torch.full_like(self.history, 1.0 / self.steps)
        if self.mode == "uniform":
            return uniform
        weights = self.history.sqrt() + 1e-4
        if self.steps > 1:
            weights[0] = weights[1]
        # chosen on the device: reading whether the warm-up is over would make the host wait every step
        return torch.where((self.count > self.warmup).all(), weights / weights.sum(), uniform)

    def sample(self, batch: int, generator: torch.Generator | None = None) -> tuple[Tensor, Tensor]:
        """(t, pt): t long (B,) in 1..T on the sampler's device and the probability each was drawn with."""
        probs = self.probs()
        index = torch.multinomial(probs, batch, replacement=True, generator=generator)
        return index + 1, probs[index]

    @torch.no_grad()
    def update(self, t: Tensor, vlb: Tensor) -> None:
        """Fold a batch's per-sample L_vlb terms into the history (duplicate t's are averaged first).
        A term that is not finite is left out, so that the steps a non-finite loss takes to be
        noticed (training.losses.FiniteLossGuard) do not spoil p(t) for the draws in between."""
        index = t.to(self.history.device).long().reshape(-1) - 1
        squares = vlb.detach().to(self.history).reshape(-1).square()
        finite = torch.isfinite(squares)
        sums = torch.zeros_like(self.history).index_add_(0, index, torch.where(finite, squares, 0.0))
        seen = torch.zeros_like(self.count).index_add_(0, index, finite.long())
        mean = sums / seen.clamp_min(1)
        self.history.copy_(torch.where(seen > 0, (1 - self.decay) * self.history + self.decay * mean, self.history))
        self.count.add_(seen)
