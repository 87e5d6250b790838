"""MMM's masked motion transformer (m2d2m/networks/mmm_transformer.py)."""

from __future__ import annotations

import pytest
import torch

from m2d2m.networks.config import ConfigError
from m2d2m.networks.mmm_transformer import MaskedMotionTransformer, MaskedTransformerConfig

CONFIG = MaskedTransformerConfig(
    codebook_size=16,
    code_dim=4,
    width=32,
    heads=4,
    layers=3,
    cross_layers=1,
    ffn=64,
    dropout=0.0,
    text_dim=8,
    max_tokens=10,
)


@pytest.fixture
def model() -> MaskedMotionTransformer:
    torch.manual_seed(0)
    return MaskedMotionTransformer(CONFIG, torch.randn(16, 4)).eval()


def text(batch: int, words: int = 5) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(1)
    return (
        torch.randn(batch, 8, generator=generator),
        torch.randn(batch, words, 8, generator=generator),
        torch.ones(batch, words, dtype=torch.bool),
    )


def test_logits_cover_the_codes_at_every_position(model):
    tokens = torch.tensor([[3, CONFIG.mask_id, 7, CONFIG.end_id, CONFIG.pad_id]])
    assert model(tokens, *text(1)).shape == (1, 5, 16)


def test_padding_and_padded_words_change_nothing(model):
    tokens = torch.tensor([[3, CONFIG.mask_id, 7, CONFIG.end_id]])
    sentence, words, word_mask = text(1)
    alone = model(tokens, sentence, words, word_mask)
    padded_tokens = torch.cat([tokens, torch.full((1, 3), CONFIG.pad_id)], dim=1)
    padded_words = torch.cat([words, 100 * torch.randn(1, 4, 8)], dim=1)
    padded_mask = torch.cat([word_mask, torch.zeros(1, 4, dtype=torch.bool)], dim=1)
    padded = model(padded_tokens, sentence, padded_words, padded_mask)
    torch.testing.assert_close(padded[:, :4], alone, rtol=1e-5, atol=1e-5)


def test_attention_is_bidirectional(model):
    before = model(torch.tensor([[3, CONFIG.mask_id, 7, CONFIG.end_id]]), *text(1))
    after = model(torch.tensor([[3, CONFIG.mask_id, 9, CONFIG.end_id]]), *text(1))
    assert not torch.allclose(before[:, 1], after[:, 1])  # a later token changes an earlier prediction


def test_codes_are_embedded_by_the_frozen_codebook(model):
    assert "codebook" not in dict(model.named_parameters())
    codes = torch.tensor([[2, 5]])
    torch.testing.assert_close(model.embed_tokens(codes)[0], model.token_projection(model.codebook[[2, 5]]))
    tokens = torch.tensor([[2, 5, CONFIG.end_id]])
    model.train()
    model(tokens, *text(1)).sum().backward()
    assert model.special.grad is not None and model.codebook.grad is None


def test_bad_settings_and_inputs_are_refused():
    with pytest.raises(ConfigError, match="cross_layers"):
        MaskedTransformerConfig(layers=2, cross_layers=3)
    with pytest.raises(ConfigError, match="codebook"):
        MaskedMotionTransformer(CONFIG, torch.randn(8, 4))
    model = MaskedMotionTransformer(CONFIG, torch.randn(16, 4))
    with pytest.raises(RuntimeError, match="tokens must lie"):  # asserted on the device: no host read
        model(torch.tensor([[CONFIG.mask_id + 1]]), *text(1))
    with pytest.raises(ValueError, match="exceed"):
        model(torch.zeros(1, 12, dtype=torch.long), *text(1))  # 10 tokens + [END] fit, 12 positions do not


def test_canvas_ends_each_sequence_and_pads_the_rest():
    from m2d2m.networks.mmm_transformer import canvas

    tokens = torch.tensor([[1, 2, 3], [4, CONFIG.mask_id, 9]])
    E, P = CONFIG.end_id, CONFIG.pad_id
    assert canvas(tokens, torch.tensor([3, 1]), CONFIG).tolist() == [[1, 2, 3, E], [4, E, P, P]]
