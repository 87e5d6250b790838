"""MMM's masking process (Pinyoanuntapong et al., "MMM: Generative Masked Motion Model",
CVPR 2024, §3.2 and supplement §F–G): how training corrupts a token sequence and how parallel
decoding schedules what stays masked. No network and no parameters, like the other processes.

- Training masks r·L of a sequence's L tokens, rounded and at least one, r ~ U(α, 1) (§3.2;
  Table 4 ablates α, 0.5 by default), chosen uniformly among its real positions; the loss is
  the cross-entropy of the masked tokens (eq. 2).
- Decoding starts from an all-[MASK] canvas. After iteration t of T_dyn, n_M(t) = ⌈γ(t / T_dyn)·L⌉
  tokens are masked again (supplement eq. 4): those the model is least confident about. γ is a
  decaying function (§G): ``cosine`` cos(π/2·x), ``linear`` 1 − x, or the supplement's third,
  ``square`` 1 − x² (which it calls "square root").
- T_dyn = T·L / M (supplement §F): a sequence of L tokens gets a share of the T iterations that
  the longest motion M gets, so time grows with the length.

One departure, on purpose: each iteration decides at least one more token (n_M(t) ≤ n_M(t − 1) − 1
while tokens are masked), so T_dyn iterations always finish the canvas. The ceiling of eq. 4
alone would leave a 49-token sequence's first cosine iteration of 10 with nothing decided.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

SCHEDULES = ("cosine", "linear", "square")


def decay(schedule: str, x: float) -> float:
    """γ(x) for x = t / T_dyn in [0, 1]: 1 at the start, 0 at the end."""
    if not 0.0 <= x <= 1.0:
        raise ValueError(f"the schedule's argument must lie in [0, 1], got {x}")
    if schedule == "cosine":
        return 0.0 if x == 1.0 else math.cos(0.5 * math.pi * x)
    if schedule == "linear":
        return 1.0 - x
    if schedule == "square":
        return 1.0 - x * x
    raise ValueError(f"unknown mask schedule {schedule!r}: choose one of {', '.join(SCHEDULES)}")


def dynamic_iterations(length: int, longest: int, iterations: int) -> int:
    """T_dyn = ⌈T·L / M⌉ for L tokens when the longest motion, M tokens, gets T iterations;
    at least one, and T for anything as long as M or longer (a long-sequence method's pieces)."""
    if length < 1 or longest < 1 or iterations < 1:
        raise ValueError(f"length, longest and iterations must be >= 1, got {length}, {longest}, {iterations}")
    return max(1, math.ceil(iterations * min(length, longest) / longest))


def masked_counts(length: int, iterations: int, schedule: str = "cosine") -> list[int]:
    """n_M(t) for t = 1 … ``iterations``: how many of ``length`` tokens stay masked after each
    iteration; non-increasing, decreasing by at least one while any is masked, 0 at the end."""
    if length < 1 or iterations < 1:
        raise ValueError(f"length and iterations must be >= 1, got {length} and {iterations}")
    counts, masked = [], length
    for t in range(1, iterations + 1):
        # rounded before the ceiling so that float error (cos(π/2) = 6e-17) does not add a token
        scheduled = math.ceil(round(decay(schedule, t / iterations) * length, 9))
        masked = max(0, min(scheduled, masked - 1))
        counts.append(masked)
    return counts


def training_mask(lengths: Tensor, width: int, alpha: float, generator: torch.Generator | None = None) -> Tensor:
    """(B, width) bool, True where a token is replaced by [MASK]: for each sequence of
    ``lengths[b]`` real tokens, round(r·L) of them (at least one), r ~ U(α, 1), chosen uniformly."""
    if not 0.0 <= alpha <= 1.0:
        raise ValueError(f"alpha must lie in [0, 1], got {alpha}")
    ratio = alpha + (1.0 - alpha) * torch.rand(len(lengths), generator=generator, device=lengths.device)
    return random_positions(lengths, width, torch.round(ratio * lengths).clamp(min=1).long(), generator)


def corruption_mask(lengths: Tensor, width: int, most: float, generator: torch.Generator | None = None) -> Tensor:
    """(B, width) bool, True where a conditioning token is replaced by [MASK]: round(q·L) of
    each sequence's ``lengths[b]`` tokens (none at all for some), q ~ U(0, ``most``). MMM's light
    corruption of the lower-body tokens in upper-body editing (§3.3): without it the upper body
    follows the lower too closely and the text too little."""
    if not 0.0 <= most <= 1.0:
        raise ValueError(f"the largest corrupted fraction must lie in [0, 1], got {most}")
    ratio = most * torch.rand(len(lengths), generator=generator, device=lengths.device)
    return random_positions(lengths, width, torch.round(ratio * lengths).long(), generator)


def random_positions(lengths: Tensor, width: int, counts: Tensor, generator: torch.Generator | None = None) -> Tensor:
    """(B, width) bool: ``counts[b]`` of row b's first ``lengths[b]`` positions, chosen uniformly."""
    device = lengths.device
    real = torch.arange(width, device=device)[None, :] < lengths[:, None]
    # a random order of each row's real positions (padding sorts last); the first `count` are chosen
    noise = torch.rand(len(lengths), width, generator=generator, device=device).masked_fill(~real, 2.0)
    rank = noise.argsort(dim=1).argsort(dim=1)
    return (rank < counts[:, None]) & real


def least_confident(confidence: Tensor, candidates: Tensor, counts: Tensor) -> Tensor:
    """(B, L) bool: for each row, the ``counts[b]`` candidate positions with the lowest confidence
    (ties to the earlier position), or all of its candidates when it has fewer: what a decoding
    iteration masks again. Shapes only are checked, so that a decoding step never reads a tensor
    back on the host."""
    if confidence.shape != candidates.shape:
        raise ValueError(f"confidence {tuple(confidence.shape)} and candidates {tuple(candidates.shape)} differ")
    score = confidence.double().masked_fill(~candidates, math.inf)
    rank = score.argsort(dim=1, stable=True).argsort(dim=1)
    return (rank < counts[:, None]) & candidates


def unmask(tokens: Tensor, drawn: Tensor, logits: Tensor, still_masked: Tensor, mask_id: int) -> Tensor:
    """One iteration of parallel decoding (MMM §3.2, after MaskGIT): the masked positions of
    ``tokens`` (B, L) take their ``drawn`` tokens, but the ``still_masked[b]`` of row b the model
    was least sure of stay masked. The model's sureness is its own probability of the drawn token
    (``logits``, before the temperature and filtering the draw used, so that top-k = 1 still ranks
    positions). Decided tokens never change."""
    masked = tokens == mask_id
    confidence = torch.softmax(logits.double(), dim=-1).gather(-1, drawn[..., None])[..., 0]
    again = least_confident(confidence, masked, still_masked)
    return torch.where(masked & ~again, drawn, tokens)
