"""MMM's parallel decoding (m2d2m/generators/mmm/decoding.py) with hand-set predictors."""

from __future__ import annotations

import math

import pytest
import torch

from m2d2m.generators.mmm.decoding import decode, filtered_probabilities, schedule_table
from m2d2m.generators.mmm.options import DecodingOptions
from m2d2m.generators.token_model import FREE

K, MASK = 6, 8  # 6 codes; [END] 6, [PAD] 7, [MASK] 8


def peaked(targets: torch.Tensor, sharpness: torch.Tensor | float = 50.0):
    """A predictor whose distribution at each position puts almost all mass on ``targets``."""

    def predict(tokens: torch.Tensor) -> torch.Tensor:
        logits = torch.zeros(*tokens.shape, K)
        logits.scatter_(
            -1, targets.expand_as(tokens)[..., None], torch.as_tensor(sharpness).expand_as(tokens)[..., None].float()
        )
        return logits

    return predict


def test_filtering_by_hand():
    logits = torch.log(torch.tensor([0.5, 0.3, 0.15, 0.05]))
    assert filtered_probabilities(logits, DecodingOptions(top_p=0.7)).tolist() == pytest.approx([0.625, 0.375, 0, 0])
    assert filtered_probabilities(logits, DecodingOptions(top_k=1)).tolist() == pytest.approx([1, 0, 0, 0])
    squared = torch.tensor([0.25, 0.09, 0.0225, 0.0025])
    assert filtered_probabilities(logits, DecodingOptions(temperature=0.5)).tolist() == pytest.approx(
        (squared / squared.sum()).tolist()
    )


def test_decoding_fills_exactly_the_free_positions_and_keeps_the_rest():
    targets = torch.tensor([[0, 1, 2, 3, 4, 5, 0, 1]])
    given = torch.tensor([[5, FREE, FREE, 4, FREE, FREE, 3, FREE]])
    valid = torch.ones_like(given, dtype=torch.bool)
    tokens = decode(peaked(targets), given, valid, MASK, longest=8, options=DecodingOptions(), seeds=[0])
    kept = given != FREE
    assert torch.equal(tokens[kept], given[kept])  # kept tokens bit-exact
    assert torch.equal(tokens[~kept], targets[~kept])  # every free position decided by the predictor


def test_the_least_confident_stay_masked():
    # 4 free tokens, 2 iterations, linear: 2 stay masked after the first; positions 1 and 3 are unsure
    seen = []
    sharp = torch.tensor([[50.0, 0.5, 50.0, 1.0]])
    predict = peaked(torch.tensor([[1, 2, 3, 4]]), sharp)

    def recording(tokens):
        seen.append(tokens.clone())
        return predict(tokens)

    given = torch.full((1, 4), FREE)
    decode(
        recording,
        given,
        torch.ones(1, 4, dtype=torch.bool),
        MASK,
        longest=4,
        options=DecodingOptions(iterations=2, schedule="linear", top_k=1),
        seeds=[0],
    )
    assert len(seen) == 2
    assert seen[1].tolist() == [[1, MASK, 3, MASK]]


def test_iterations_scale_with_the_length():
    calls = []

    def counting(tokens):
        calls.append(1)
        return peaked(torch.zeros(1, 1, dtype=torch.long))(tokens)

    given = torch.full((1, 5), FREE)
    decode(
        counting,
        given,
        torch.ones(1, 5, dtype=torch.bool),
        MASK,
        longest=10,
        options=DecodingOptions(iterations=10),
        seeds=[0],
    )
    assert len(calls) == 5  # T_dyn = 10 · 5 / 10
    table = schedule_table([5, 10, 0], longest=10, options=DecodingOptions(iterations=10))
    assert table.shape == (3, 10) and table[0, 4] == 0 and table[1, -1] == 0 and table[2].sum() == 0


def test_a_sequence_does_not_depend_on_its_batch():
    torch.manual_seed(0)
    weights = torch.randn(K + 3, K)

    def random_model(tokens):  # logits from a fixed table: a stochastic, position-agnostic predictor
        return weights[tokens] + weights[tokens].roll(1, dims=1)

    given = torch.full((2, 6), FREE)
    valid = torch.tensor([[True] * 6, [True] * 4 + [False] * 2])
    both = decode(random_model, given, valid, MASK, longest=6, options=DecodingOptions(), seeds=[3, 4])
    first = decode(random_model, given[:1], valid[:1], MASK, longest=6, options=DecodingOptions(), seeds=[3])
    assert torch.equal(both[:1], first)
    assert (both[1, 4:] == FREE).all()  # positions outside a sequence come back as given


def test_bad_options_are_refused():
    for options, message in (
        (DecodingOptions(iterations=0), "iterations"),
        (DecodingOptions(schedule="cubic"), "schedule"),
        (DecodingOptions(temperature=0.0), "temperature"),
        (DecodingOptions(top_p=1.5), "top_p"),
    ):
        with pytest.raises(ValueError, match=message):
            options.check()
    assert math.isfinite(DecodingOptions().temperature)
