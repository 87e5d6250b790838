"""MMM's masking process (m2d2m/processes/masking.py) against hand-computed values."""

from __future__ import annotations

import math

import pytest
import torch

from m2d2m.processes.masking import (
    decay,
    dynamic_iterations,
    least_confident,
    masked_counts,
    training_mask,
    unmask,
)


def test_decay_functions_of_the_supplement():
    assert decay("cosine", 0.0) == 1.0 and decay("cosine", 1.0) == 0.0
    assert decay("cosine", 0.5) == pytest.approx(math.sqrt(0.5))
    assert decay("linear", 0.25) == 0.75 and decay("square", 0.5) == 0.75
    with pytest.raises(ValueError, match="unknown mask schedule"):
        decay("sqrt", 0.5)


def test_dynamic_iterations_grow_with_the_length():
    assert dynamic_iterations(49, 49, 10) == 10  # the longest motion gets all T
    assert dynamic_iterations(10, 49, 10) == 3  # ⌈10 · 10 / 49⌉ = ⌈2.04⌉
    assert dynamic_iterations(1, 49, 10) == 1
    assert dynamic_iterations(60, 49, 10) == 10  # longer than M (a long sequence's piece): capped at T


@pytest.mark.parametrize(
    "schedule, expected",
    [
        # L = 10, T = 4: ⌈γ(t/4) · 10⌉ for t = 1..4
        ("cosine", [9, 8, 4, 0]),  # ⌈9.24⌉ = 10 → 9 (one token decided per iteration at least), ⌈7.07⌉, ⌈3.83⌉, 0
        ("linear", [8, 5, 3, 0]),  # ⌈7.5⌉, 5, ⌈2.5⌉, 0
        ("square", [9, 8, 5, 0]),  # ⌈9.375⌉ = 10 → 9, ⌈7.5⌉, ⌈4.375⌉, 0
    ],
)
def test_masked_counts_by_hand(schedule, expected):
    assert masked_counts(10, 4, schedule) == expected


def test_every_iteration_decides_a_token_and_the_canvas_ends_full():
    counts = masked_counts(49, 10, "cosine")
    assert counts[0] == 48 and counts[-1] == 0  # ⌈cos(π/20) · 49⌉ = ⌈48.4⌉ = 49 would decide nothing
    assert all(b < a for a, b in zip([49] + counts, counts) if a > 0)
    assert masked_counts(3, 10, "linear") == [2, 1, 0] + [0] * 7


def test_training_mask_hides_a_share_between_alpha_and_one_of_the_real_tokens():
    lengths = torch.tensor([10, 4, 7] * 400)
    mask = training_mask(lengths, 12, alpha=0.5, generator=torch.Generator().manual_seed(0))
    real = torch.arange(12)[None, :] < lengths[:, None]
    assert not mask[~real].any()  # padding is never masked
    counts = mask.sum(dim=1)
    assert (counts >= torch.floor(0.5 * lengths)).all() and (counts <= lengths).all()
    # r ~ U(0.5, 1), round(r·L) tokens: E = 7.5 of 10, 3 of 4 and 37/7 of 7, so 15.79 of every 21
    assert counts.sum().item() / lengths.sum().item() == pytest.approx((7.5 + 3 + 37 / 7) / 21, abs=0.01)
    everything = training_mask(lengths, 12, alpha=1.0, generator=torch.Generator().manual_seed(1))
    assert torch.equal(everything, real)


def test_least_confident_positions_among_the_candidates():
    confidence = torch.tensor([[0.9, 0.1, 0.5, 0.2, 0.3], [0.4, 0.4, 0.1, 0.8, 0.2]])
    candidates = torch.tensor([[True, True, True, False, True], [True, True, False, True, True]])
    chosen = least_confident(confidence, candidates, torch.tensor([2, 2]))
    # row 0: 0.2 is kept (not a candidate), so 0.1 and 0.3; row 1: 0.1 is not a candidate, so 0.2 and the first 0.4
    assert chosen.tolist() == [[False, True, False, False, True], [True, False, False, False, True]]
    # a row asking for more than its candidates gets all of them (decoding asks for at most as many)
    assert torch.equal(
        least_confident(confidence, candidates, torch.tensor([5, 0])), candidates & torch.tensor([[True], [False]])
    )


def test_an_unmasking_step_decides_all_but_the_least_sure_and_keeps_decided_tokens():
    """Row 0 keeps one of its three masked positions masked, the one whose draw the model gave the
    least probability; row 1 decides both; decided tokens (3; 2, 1) never change."""
    mask = 9
    tokens = torch.tensor([[mask, 3, mask, mask], [mask, mask, 2, 1]])
    drawn = torch.tensor([[0, 5, 1, 2], [4, 4, 0, 0]])
    sureness = torch.tensor([[3.0, 9.0, 1.0, 2.0], [1.0, 2.0, 0.0, 0.0]])
    logits = torch.zeros(2, 4, 6).scatter(-1, drawn[..., None], sureness[..., None])
    stepped = unmask(tokens, drawn, logits, torch.tensor([1, 0]), mask)
    assert stepped.tolist() == [[0, 3, mask, 2], [4, 4, 2, 1]]
