"""Text encoders for the denoiser's condition, behind one interface (docs/training.md, the text encoders).

``clip`` is the paper's: the frozen CLIP ViT-B/32 text tower, per-token features of the last
hidden state. It is read only from a local directory or the user's Hugging Face cache
(``local_files_only=True``): no code path here downloads anything. ``learned`` is a small
trainable word-level encoder for the embedded default, where no CLIP weights are assumed; its
vocabulary and sizes travel inside its ``state_dict`` so a checkpoint alone can encode.

A caption's condition is the concatenation of its action sentences' token features
(``encode_actions``), which is also how two-phase sampling builds the joint condition.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from collections.abc import Iterable
from typing import Any

import torch
from torch import nn
from torch.nn.utils.rnn import pad_sequence

CLIP_DEFAULT = "openai/clip-vit-base-patch32"
PAD, UNK = "<pad>", "<unk>"
_WORD = re.compile(r"[a-z]+")


class TextEncoder(nn.Module):
    """Sentences -> per-token features (N, S, dim) and a validity mask (N, S), True = real token."""

    dim: int
    trainable: bool

    def encode(self, sentences: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        raise NotImplementedError

    def encode_pooled(self, sentences: list[str]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """:meth:`encode`'s features and mask, and one (N, dim) vector per sentence, for models that
        condition on a sentence embedding as well as on words (MMM prepends it as a token): the
        mean of the sentence's real token features; CLIP gives its own pooled feature instead."""
        features, mask = self.encode(sentences)
        weights = mask.to(features.dtype)[..., None]
        return features, mask, (features * weights).sum(dim=1) / weights.sum(dim=1)

    @property
    def device(self) -> torch.device:
        return next(self.parameters()).device


class CLIPTextEncoder(TextEncoder):
    """The frozen CLIP text tower; ``path`` is a local directory or a model id already in the cache."""

    trainable = False

    def __init__(self, path: str = CLIP_DEFAULT, max_length: int = 77) -> None:
        super().__init__()
        from transformers import CLIPTextModel, CLIPTokenizer

        try:
            self.tokenizer = CLIPTokenizer.from_pretrained(path, local_files_only=True)
            model = CLIPTextModel.from_pretrained(path, local_files_only=True)
        except (OSError, ValueError) as error:
            raise FileNotFoundError(
                f"CLIP text weights not found in {path!r} (local directory or Hugging Face cache; nothing is "
                f"downloaded): fetch them once with `hf download {CLIP_DEFAULT}` or save CLIPTextModel and "
                f"CLIPTokenizer there with save_pretrained"
            ) from error
        self.model = model.eval().requires_grad_(False)
        self.dim = model.config.hidden_size
        self.max_length = min(max_length, model.config.max_position_embeddings)

    def train(self, mode: bool = True) -> CLIPTextEncoder:
        """Stays in eval mode: the tower is frozen, so a trainer's ``.train()`` must not wake dropout."""
        return super().train(False)

    def encode(self, sentences: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        features, mask, _ = self.encode_pooled(sentences)
        return features, mask

    @torch.no_grad()
    def encode_pooled(self, sentences: list[str]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Token features, mask and CLIP's pooled sentence feature (the end-of-text token's, after
        the final layer norm), all from one pass of the tower."""
        batch = self.tokenizer(
            list(sentences), padding=True, truncation=True, max_length=self.max_length, return_tensors="pt"
        ).to(self.device)
        output = self.model(input_ids=batch["input_ids"], attention_mask=batch["attention_mask"])
        return output.last_hidden_state, batch["attention_mask"].bool(), output.pooler_output


def _words(sentence: str) -> list[str]:
    """Lower-case words, split on anything that is not a letter."""
    return _WORD.findall(sentence.lower())


def _sinusoid(length: int, dim: int, device: torch.device) -> torch.Tensor:
    """(length, dim) fixed sinusoidal positions: no length limit learned into the encoder."""
    positions = torch.arange(length, device=device, dtype=torch.float32)[:, None]
    frequencies = torch.exp(-math.log(10000.0) * torch.arange(0, dim, 2, device=device) / dim)
    table = torch.zeros(length, dim, device=device)
    table[:, 0::2] = torch.sin(positions * frequencies)
    table[:, 1::2] = torch.cos(positions * frequencies[: dim // 2])
    return table


class LearnedTextEncoder(TextEncoder):
    """Word embedding + sinusoidal positions + a small Transformer encoder, trained with the denoiser."""

    trainable = True

    def __init__(
        self,
        vocabulary: list[str],
        dim: int = 256,
        layers: int = 2,
        heads: int = 4,
        dropout: float = 0.1,
        max_length: int = 77,
    ) -> None:
        super().__init__()
        if vocabulary[:2] != [PAD, UNK]:
            raise ValueError(
                f"vocabulary must start with {PAD!r}, {UNK!r}: build it with LearnedTextEncoder.build_vocabulary"
            )
        if dim % heads:
            raise ValueError(f"learned text encoder dim ({dim}) must be divisible by heads ({heads})")
        self.vocabulary = list(vocabulary)
        self.index = {word: i for i, word in enumerate(self.vocabulary)}
        self.options = {"dim": dim, "layers": layers, "heads": heads, "dropout": dropout, "max_length": max_length}
        self.dim = dim
        self.max_length = max_length
        self.embedding = nn.Embedding(len(self.vocabulary), dim, padding_idx=0)
        layer = nn.TransformerEncoderLayer(
            dim, heads, 4 * dim, dropout, activation="gelu", batch_first=True, norm_first=True
        )
        self.encoder = nn.TransformerEncoder(layer, layers, norm=nn.LayerNorm(dim), enable_nested_tensor=False)

    @staticmethod
    def build_vocabulary(sentences: Iterable[str], min_count: int = 1) -> list[str]:
        """<pad>, <unk>, then the corpus words seen at least ``min_count`` times, most frequent first."""
        counts = Counter(word for sentence in sentences for word in _words(sentence))
        kept = sorted(
            (word for word, count in counts.items() if count >= min_count), key=lambda word: (-counts[word], word)
        )
        return [PAD, UNK, *kept]

    def tokenize(self, sentences: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """Word ids (N, S) and mask; an empty sentence becomes one <unk> so no row is all padding."""
        ids = [[self.index.get(word, 1) for word in _words(s)][: self.max_length] or [1] for s in sentences]
        length = max(len(row) for row in ids)
        tokens = torch.zeros(len(ids), length, dtype=torch.long)
        for row, values in enumerate(ids):
            tokens[row, : len(values)] = torch.tensor(values)
        return tokens.to(self.device), tokens.to(self.device) != 0

    def encode(self, sentences: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        tokens, mask = self.tokenize(sentences)
        x = self.embedding(tokens) * math.sqrt(self.dim) + _sinusoid(tokens.shape[1], self.dim, tokens.device)
        return self.encoder(x, src_key_padding_mask=~mask), mask

    def get_extra_state(self) -> dict[str, Any]:
        return {"vocabulary": self.vocabulary, "options": self.options}

    def set_extra_state(self, state: dict[str, Any]) -> None:
        if state["vocabulary"] != self.vocabulary or state["options"] != self.options:
            raise ValueError(
                "checkpoint's text vocabulary or sizes differ from this encoder's: build it with "
                "LearnedTextEncoder.from_state_dict"
            )

    @classmethod
    def from_state_dict(cls, state_dict: dict[str, Any], prefix: str = "") -> LearnedTextEncoder:
        """Rebuild from a ``state_dict`` (optionally nested under ``prefix``) with no other file."""
        extra = state_dict[f"{prefix}_extra_state"]
        encoder = cls(extra["vocabulary"], **extra["options"])
        own = {key[len(prefix) :]: value for key, value in state_dict.items() if key.startswith(prefix)}
        encoder.load_state_dict(own)
        return encoder


def encode_actions(encoder: TextEncoder, actions_per_caption: list[list[str]]) -> tuple[torch.Tensor, torch.Tensor]:
    """Each caption's condition: its action sentences encoded separately, real tokens concatenated in order.

    Returns (B, S_max, dim) features and (B, S_max) mask, S_max the longest concatenation.
    """
    if any(len(actions) == 0 for actions in actions_per_caption):
        raise ValueError("every caption needs at least one action sentence")
    flat = [sentence for actions in actions_per_caption for sentence in actions]
    features, mask = encoder.encode(flat)
    pieces, start = [], 0
    for actions in actions_per_caption:
        pieces.append(torch.cat([features[row][mask[row]] for row in range(start, start + len(actions))]))
        start += len(actions)
    lengths = torch.tensor([piece.shape[0] for piece in pieces], device=features.device)
    joined_mask = torch.arange(int(lengths.max()), device=features.device)[None, :] < lengths[:, None]
    return pad_sequence(pieces, batch_first=True), joined_mask


_KINDS = {"clip": CLIPTextEncoder, "learned": LearnedTextEncoder}


def text_encoder_from_config(text: dict[str, Any], vocabulary: list[str] | None = None) -> TextEncoder:
    """A training run's text encoder from its ``text`` config section (``kind`` and options); a
    ``learned`` one takes the vocabulary of the run's training captions."""
    options = {k: v for k, v in text.items() if k != "kind"}
    kind = text.get("kind", "learned")
    if kind == "learned":
        if vocabulary is None:
            raise ValueError(
                "a 'learned' text encoder needs a vocabulary "
                "(LearnedTextEncoder.build_vocabulary over the training captions)"
            )
        options["vocabulary"] = list(vocabulary)
    return build_text_encoder(kind, **options)


def build_text_encoder(kind: str, **options: Any) -> TextEncoder:
    """``clip`` (options: path, max_length) or ``learned`` (options: vocabulary, dim, layers, heads, ...)."""
    if kind not in _KINDS:
        raise ValueError(f"unknown text encoder {kind!r}: choose one of {', '.join(sorted(_KINDS))}")
    return _KINDS[kind](**options)
