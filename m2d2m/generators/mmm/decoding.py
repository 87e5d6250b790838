"""MMM's confidence-based parallel decoding (Pinyoanuntapong et al., CVPR 2024, §3.2, supplement
§F–H), over any predictor of token logits.

Each sequence starts as a canvas of [MASK] wherever it is free (kept tokens — editing — are
given and never change). An iteration is the model's prediction, a draw for every position
(temperature, then top-k and top-p filtering: supplement §H) and the masking process's step
(:func:`m2d2m.processes.masking.unmask`): the masked positions take their draws but the n_M(t)
the model was least sure of, with n_M(t) from :func:`m2d2m.processes.masking.masked_counts` over
the sequence's own T_dyn iterations and its free positions. Tokens once decided stay decided, as
in MaskGIT.

Randomness is per sequence: each has its own generator and draws one uniform per position per
iteration, so a sequence's result does not depend on the rest of the batch.

An iteration reads nothing back on the host (tests/test_host_syncs_models.py): the schedule is
made on the host once per call, and every iteration of it is queued without looking at the tokens.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from m2d2m.generators.mmm.options import DecodingOptions
from m2d2m.generators.token_model import FREE
from m2d2m.processes.discrete_diffusion import categorical
from m2d2m.processes.masking import dynamic_iterations, masked_counts, unmask

Predictor = Callable[[Tensor], Tensor]  # (B, L) tokens with [MASK] → (B, L, K) logits


def filtered_probabilities(logits: Tensor, options: DecodingOptions) -> Tensor:
    """softmax(logits / temperature), keeping the ``top_k`` most probable codes and the fewest
    whose mass reaches ``top_p`` (the most probable always stays), renormalised; float64."""
    probs = torch.softmax(logits.double() / options.temperature, dim=-1)
    keep = torch.ones_like(probs, dtype=torch.bool)
    ordered, order = probs.sort(dim=-1, descending=True)
    positions = torch.arange(probs.shape[-1], device=probs.device).expand_as(order)
    rank = torch.empty_like(order).scatter_(-1, order, positions)  # each code's place in the order
    if options.top_k is not None:
        keep &= rank < options.top_k
    if options.top_p is not None:
        before = (ordered.cumsum(dim=-1) - ordered).gather(-1, rank)  # mass of the more probable codes
        keep &= before < options.top_p
    kept = probs * keep
    return kept / kept.sum(dim=-1, keepdim=True)


def schedule_table(free: list[int], longest: int, options: DecodingOptions) -> Tensor:
    """(B, I) long: how many of each sequence's free positions stay masked after iteration i, over
    its own T_dyn iterations until none is (then 0); I is the most iterations a row of the batch
    needs, so that no iteration is queued with nothing left to decide."""
    counts = [
        masked_counts(n, dynamic_iterations(n, longest, options.iterations), options.schedule) if n else [0]
        for n in free
    ]
    counts = [c[: c.index(0) + 1] for c in counts]  # each ends at its first 0: all decided
    width = max(len(c) for c in counts)
    return torch.tensor([c + [0] * (width - len(c)) for c in counts], dtype=torch.long)


def decode(
    predict: Predictor,
    given: Tensor,
    valid: Tensor,
    mask_id: int,
    longest: int,
    options: DecodingOptions,
    seeds: list[int],
) -> Tensor:
    """Tokens (B, L) for a batch: ``given`` (B, L) holds kept codes and :data:`FREE` where to
    generate, ``valid`` (B, L) marks each sequence's positions (the rest is returned as given);
    ``longest`` is M of T_dyn, the token length given all ``options.iterations``."""
    options.check()
    device = given.device
    free = (given == FREE) & valid
    tokens = torch.where(free, torch.full_like(given, mask_id), given)
    # The call's one host read, before any iteration is queued: how many iterations to queue
    # depends on each row's number of free positions (its T_dyn, supplement §F).
    free_counts = free.sum(dim=1).tolist()
    if not any(free_counts):
        return tokens
    counts = schedule_table(free_counts, longest, options).to(device, non_blocking=True)
    generators = [torch.Generator(device=device).manual_seed(int(seed)) for seed in seeds]
    for still_masked in counts.unbind(dim=1):  # n_M(t) of each row
        logits = predict(tokens)
        drawn = categorical(filtered_probabilities(logits, options), _uniforms(generators, given.shape[1], device))
        tokens = unmask(tokens, drawn, logits, still_masked, mask_id)
    return tokens


def _uniforms(generators: list[torch.Generator], width: int, device: torch.device) -> Tensor:
    """(B, width) uniforms, row b's from its own generator, so no row depends on the batch."""
    return torch.stack([torch.rand(width, generator=g, dtype=torch.float64, device=device) for g in generators])
