"""MMM's LightningModule (training/mmm_module.py): masked-token cross-entropy that learns."""

from __future__ import annotations

import torch

from m2d2m.text import LearnedTextEncoder
from training.mmm_module import MMMModule

CAPTIONS = ["a person walks forward", "a person jumps"]
TRANSFORMER = {"width": 32, "heads": 4, "layers": 2, "cross_layers": 1, "ffn": 64, "dropout": 0.0, "max_tokens": 8}
TEXT = {"kind": "learned", "dim": 16, "layers": 1, "heads": 2, "dropout": 0.0}
OPTIM = {"lr": 3e-3}


def module() -> MMMModule:
    torch.manual_seed(0)
    return MMMModule(
        TRANSFORMER,
        TEXT,
        {"alpha": 0.5},
        OPTIM,
        codebook=torch.randn(12, 4),
        vocabulary=LearnedTextEncoder.build_vocabulary(CAPTIONS),
    )


def batch() -> dict:
    # walking is codes 1 2 3 4 5 6, jumping 7 8 9 10 (then padding)
    tokens = torch.tensor([[1, 2, 3, 4, 5, 6], [7, 8, 9, 10, 0, 0]])
    return {"tokens": tokens, "padding_mask": tokens > 0, "text": CAPTIONS}


def test_targets_are_a_share_of_each_captions_real_tokens():
    model = module()
    for seed in range(20):
        codes, masked, logits = model._predict(batch(), torch.Generator().manual_seed(seed))
        assert logits.shape == (2, 6, 12) and not masked[1, 4:].any()  # padding is never a target
        assert 3 <= masked[0].sum() <= 6 and 2 <= masked[1].sum() <= 4  # round(r·L), r in [0.5, 1]


def test_training_learns_the_captions_tokens_and_leaves_the_codebook_alone():
    model = module()
    codebook = model.transformer.codebook.clone()
    optimiser = model.configure_optimizers()["optimizer"]
    generator = torch.Generator().manual_seed(0)
    losses = []
    for _ in range(150):
        codes, masked, logits = model._predict(batch(), generator)
        loss = torch.nn.functional.cross_entropy(logits[masked], codes[masked])
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses.append(loss.item())
    assert sum(losses[-10:]) / 10 < 0.2 * sum(losses[:10]) / 10
    assert torch.equal(model.transformer.codebook, codebook)
