"""Text encoders: the learned word-level encoder, action concatenation, and CLIP with a tiny local model."""

from __future__ import annotations

import socket
import string
from pathlib import Path

import pytest
import torch

from m2d2m.text import (
    CLIPTextEncoder,
    LearnedTextEncoder,
    TextEncoder,
    build_text_encoder,
    encode_actions,
    token_layout,
)

CORPUS = ["A person walks forward.", "a person runs in a circle", "someone waves, then walks"]


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def learned(seed: int = 0, **options) -> LearnedTextEncoder:
    torch.manual_seed(seed)
    vocabulary = LearnedTextEncoder.build_vocabulary(CORPUS)
    return LearnedTextEncoder(vocabulary, **{"dim": 16, "layers": 2, "heads": 4, "dropout": 0.0, **options}).eval()


def test_vocabulary_reserves_pad_and_unk_and_orders_by_count():
    vocabulary = LearnedTextEncoder.build_vocabulary(CORPUS)
    assert vocabulary[:2] == ["<pad>", "<unk>"]
    assert vocabulary[2:5] == ["a", "person", "walks"]
    assert "A" not in vocabulary and "forward" in vocabulary and "forward." not in vocabulary
    assert LearnedTextEncoder.build_vocabulary(CORPUS, min_count=2) == ["<pad>", "<unk>", "a", "person", "walks"]


def test_learned_encoder_shapes_masks_and_unknown_words():
    encoder = learned()
    features, mask = encoder.encode(["a person walks", "jumps", ""])
    assert features.shape == (3, 3, 16) and mask.tolist() == [[True] * 3, [True, False, False], [True, False, False]]
    tokens, _ = encoder.tokenize(["jumps walks"])
    assert tokens.tolist() == [[1, encoder.index["walks"]]]
    assert torch.isfinite(features).all()
    assert encoder.trainable and any(p.requires_grad for p in encoder.parameters())
    alone, _ = encoder.encode(["jumps"])
    torch.testing.assert_close(features[1, :1], alone[0], atol=1e-5, rtol=0)


def test_learned_state_dict_alone_rebuilds_the_encoder(tmp_path: Path):
    encoder = learned(dim=8, heads=2)
    torch.save({"text_encoder." + key: value for key, value in encoder.state_dict().items()}, tmp_path / "ckpt.pt")
    state = torch.load(tmp_path / "ckpt.pt", weights_only=False)
    restored = LearnedTextEncoder.from_state_dict(state, prefix="text_encoder.").eval()
    assert restored.vocabulary == encoder.vocabulary and restored.dim == 8
    sentences = ["a person walks forward", "someone waves"]
    torch.testing.assert_close(restored.encode(sentences)[0], encoder.encode(sentences)[0])
    other = LearnedTextEncoder(["<pad>", "<unk>", "hop"], dim=8, heads=2)
    with pytest.raises(ValueError, match="vocabulary or sizes differ"):
        other.load_state_dict(encoder.state_dict())


def test_encode_actions_concatenates_real_tokens_in_order():
    encoder = learned()
    captions = [["a person walks", "runs"], ["waves"], ["someone walks forward", "a circle", "runs"]]
    features, mask = encode_actions(encoder, captions)
    assert features.shape == (3, 3 + 2 + 1, 16)  # the longest concatenation: 3 + 2 + 1 words
    assert mask.sum(1).tolist() == [4, 1, 6]
    assert mask[0, :4].all() and not mask[0, 4:].any()
    parts = [encoder.encode([sentence])[0][0] for sentence in captions[2]]
    torch.testing.assert_close(features[2, :6], torch.cat(parts), atol=1e-5, rtol=0)
    torch.testing.assert_close(features[0, 3], encoder.encode(["runs"])[0][0, 0], atol=1e-5, rtol=0)
    assert (features[1, 1:] == 0).all()
    with pytest.raises(ValueError, match="at least one action"):
        encode_actions(encoder, [["walks"], []])


def test_the_token_layout_is_each_captions_tokens_in_order_as_a_loop_over_them_lays_them():
    """token_layout's whole-array operations against the loop over every token they replace, on
    random captions (sentences with no real token included)."""
    generator = torch.Generator().manual_seed(0)
    for _ in range(200):
        sentences = torch.randint(1, 4, (int(torch.randint(1, 6, (1,), generator=generator)),), generator=generator)
        counts = torch.randint(0, 5, (int(sentences.sum()),), generator=generator).tolist()
        width = max(counts) + 1
        expected, row = [], 0
        for n in sentences.tolist():
            expected.append([(row + i) * width + p for i in range(n) for p in range(counts[row + i])])
            row += n
        longest = max(len(positions) for positions in expected)
        padded = [positions + [-1] * (longest - len(positions)) for positions in expected]
        assert token_layout(counts, sentences.tolist(), width).tolist() == padded


def test_encode_actions_passes_gradients_to_a_trainable_encoder():
    encoder = learned()
    features, mask = encode_actions(encoder, [["a person walks", "runs"], ["waves"]])
    features[mask].sum().backward()
    assert encoder.embedding.weight.grad is not None and encoder.embedding.weight.grad.abs().sum() > 0


class LeftPadded(TextEncoder):
    """An encoder of another kind: one feature per word, its padding on the left, no host counts."""

    dim = 1
    trainable = False

    def encode(self, sentences: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        words = [[float(len(w)) for w in s.split()] for s in sentences]
        width = max(len(row) for row in words)
        features = torch.tensor([[0.0] * (width - len(row)) + row for row in words])[..., None]
        return features, torch.tensor([[False] * (width - len(row)) + [True] * len(row) for row in words])


def test_encode_actions_lays_out_any_encoders_tokens_through_the_counted_fallback():
    """An encoder that does not count its tokens on the host still gets its real tokens
    concatenated in order (the fallback reads its mask: one host read per call)."""
    features, mask = encode_actions(LeftPadded(), [["a person walks", "up"], ["someone jumps"]])
    assert mask.tolist() == [[True] * 4, [True, True, False, False]]
    assert features[..., 0].tolist() == [[1.0, 6.0, 5.0, 2.0], [7.0, 5.0, 0.0, 0.0]]


def test_factory_builds_and_rejects_unknown_kinds():
    encoder = build_text_encoder("learned", vocabulary=LearnedTextEncoder.build_vocabulary(CORPUS), dim=8, heads=2)
    assert isinstance(encoder, TextEncoder) and encoder.dim == 8
    with pytest.raises(ValueError, match="unknown text encoder 'bert': choose one of clip, learned"):
        build_text_encoder("bert")


# --------------------------------------------------------------------------------------------------
# CLIP, with a tiny randomly initialised text tower and BPE tokenizer written by the test


@pytest.fixture
def offline(monkeypatch: pytest.MonkeyPatch):
    """No network: the Hub is told it is offline and any socket connection fails the test."""
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("TRANSFORMERS_OFFLINE", "1")

    def refuse(*args, **kwargs):
        raise AssertionError("a network connection was attempted")

    monkeypatch.setattr(socket.socket, "connect", refuse)


@pytest.fixture
def tiny_clip(tmp_path: Path, offline) -> Path:
    transformers = pytest.importorskip("transformers")
    letters = list(string.ascii_lowercase)
    tokens = ["<|startoftext|>", "<|endoftext|>", *letters, *(c + "</w>" for c in letters), "th", "the</w>"]
    vocabulary = {token: i for i, token in enumerate(tokens)}
    tokenizer = transformers.CLIPTokenizer(vocab=vocabulary, merges=[("t", "h"), ("th", "e</w>")])
    config = transformers.CLIPTextConfig(
        vocab_size=len(vocabulary),
        hidden_size=32,
        intermediate_size=64,
        num_hidden_layers=2,
        num_attention_heads=2,
        max_position_embeddings=77,
        bos_token_id=0,
        eos_token_id=1,
        pad_token_id=1,
    )
    torch.manual_seed(0)
    directory = tmp_path / "tiny-clip"
    transformers.CLIPTextModel(config).save_pretrained(directory)
    tokenizer.save_pretrained(directory)
    return directory


def test_clip_encoder_gives_frozen_token_features_with_masks(tiny_clip: Path):
    encoder = build_text_encoder("clip", path=str(tiny_clip))
    assert isinstance(encoder, CLIPTextEncoder) and encoder.dim == 32 and not encoder.trainable
    assert not any(p.requires_grad for p in encoder.parameters())
    encoder.train()
    assert not encoder.model.training
    features, mask = encoder.encode(["the walk", "a person runs"])
    # <|startoftext|> + BPE pieces + <|endoftext|>: "the walk" is the, w, a, l, k</w>.
    assert mask.sum(1).tolist() == [7, 13] and features.shape == (2, 13, 32)
    assert not features.requires_grad and torch.isfinite(features).all()
    alone, _ = encoder.encode(["the walk"])
    torch.testing.assert_close(features[0, :7], alone[0], atol=1e-5, rtol=0)


def test_clip_actions_concatenate(tiny_clip: Path):
    encoder = CLIPTextEncoder(str(tiny_clip))
    features, mask = encode_actions(encoder, [["the walk", "the"], ["a person runs"]])
    assert mask.sum(1).tolist() == [7 + 3, 13]
    torch.testing.assert_close(features[0, 7:10], encoder.encode(["the"])[0][0], atol=1e-5, rtol=0)


def test_clip_missing_weights_give_one_clear_error(tmp_path: Path, offline):
    pytest.importorskip("transformers")
    missing = tmp_path / "no-clip-here"
    with pytest.raises(FileNotFoundError) as caught:
        CLIPTextEncoder(str(missing))
    message = str(caught.value)
    assert "\n" not in message and str(missing) in message and "save_pretrained" in message
    with pytest.raises(FileNotFoundError, match="nothing is downloaded"):
        CLIPTextEncoder("nobody/not-a-cached-model")


def test_clip_sentence_feature_is_the_end_of_text_token(tiny_clip: Path):
    encoder = CLIPTextEncoder(str(tiny_clip))
    features, mask, pooled = encoder.encode_pooled(["the walk", "a person runs"])
    ends = mask.sum(1) - 1  # <|endoftext|> is each sentence's last real token
    torch.testing.assert_close(pooled, features[torch.arange(2), ends])
    torch.testing.assert_close(encoder.encode(["the walk", "a person runs"])[0], features)


def test_learned_sentence_feature_is_the_mean_of_its_real_tokens():
    encoder = LearnedTextEncoder(
        LearnedTextEncoder.build_vocabulary(["a person walks", "a person jumps high"]),
        dim=16,
        layers=1,
        heads=2,
        dropout=0.0,
    ).eval()
    features, mask, pooled = encoder.encode_pooled(["a person walks", "a person jumps high"])
    assert mask.sum(1).tolist() == [3, 4]
    torch.testing.assert_close(pooled[0], features[0, :3].mean(0))  # the padded fourth slot is left out
    torch.testing.assert_close(pooled[1], features[1].mean(0))
