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

import inspect
import math
import re
from collections import Counter
from collections.abc import Iterable
from typing import Any

import numpy as np
import torch
from torch import nn

CLIP_DEFAULT = "openai/clip-vit-base-patch32"
PAD, UNK = "<pad>", "<unk>"
_WORD = re.compile(r"[a-z]+")


class TextEncoder(nn.Module):
    """Sentences -> per-token features (N, S, dim) and a validity mask (N, S), True = real token."""

    kind: str  # its name in a ``text`` config section and in model files
    options: dict[str, Any]  # the arguments it was constructed with, beside a vocabulary: what a model file records
    dim: int
    trainable: bool
    reads_any_word: bool = True  # False: only the words of its vocabulary (the others are <unk>)

    def encode(self, sentences: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        raise NotImplementedError

    def encode_counted(self, sentences: list[str]) -> tuple[torch.Tensor, torch.Tensor, list[int]]:
        """:meth:`encode`'s features and mask with each row's real tokens first, and each sentence's
        number of real tokens as host integers: what :func:`encode_actions` lays the tokens out
        with, so that it never reads the mask back from the device. The encoders here count as they
        tokenize, on the host; this fallback for others reads the mask (a device sync)."""
        features, mask = self.encode(sentences)
        order = torch.argsort((~mask).to(torch.uint8), dim=1, stable=True)
        features = features.gather(1, order[..., None].expand_as(features))
        return features, mask.gather(1, order), mask.sum(dim=1).tolist()

    def unknown_words(self, sentence: str) -> list[str]:
        """The words of ``sentence`` this encoder cannot read (none: an open-vocabulary encoder)."""
        return []

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

    kind = "clip"
    trainable = False

    def __init__(self, path: str = CLIP_DEFAULT, max_length: int = 77) -> None:
        super().__init__()
        self.options = {"path": path, "max_length": max_length}
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

    def encode_counted(self, sentences: list[str]) -> tuple[torch.Tensor, torch.Tensor, list[int]]:
        features, mask, _, counts = self._encode(sentences)
        return features, mask, counts

    def encode_pooled(self, sentences: list[str]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Token features, mask and CLIP's pooled sentence feature (the end-of-text token's, after
        the final layer norm), all from one pass of the tower."""
        features, mask, pooled, _ = self._encode(sentences)
        return features, mask, pooled

    @torch.no_grad()
    def _encode(self, sentences: list[str]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, list[int]]:
        """One pass of the tower, and each sentence's token count read from the tokenizer's lists
        (CLIP pads on the right); the ids go to the device without making it wait."""
        encoded = self.tokenizer(list(sentences), padding=True, truncation=True, max_length=self.max_length)
        ids = torch.tensor(encoded["input_ids"]).to(self.device, non_blocking=True)
        attention = torch.tensor(encoded["attention_mask"]).to(self.device, non_blocking=True)
        output = self.model(input_ids=ids, attention_mask=attention)
        counts = [sum(row) for row in encoded["attention_mask"]]
        return output.last_hidden_state, attention.bool(), output.pooler_output, counts


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

    kind = "learned"
    trainable = True
    reads_any_word = False

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

    def unknown_words(self, sentence: str) -> list[str]:
        """The words of ``sentence`` its training captions never had: each is read as <unk>."""
        return list(dict.fromkeys(word for word in _words(sentence) if word not in self.index))

    def _word_ids(self, sentences: list[str]) -> list[list[int]]:
        """Each sentence's word ids; an empty sentence becomes one <unk> so no row is all padding."""
        return [[self.index.get(word, 1) for word in _words(s)][: self.max_length] or [1] for s in sentences]

    def tokenize(self, sentences: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """Word ids (N, S) and mask, built on the host and sent to the device in one copy that does
        not make it wait."""
        return self._tokens(self._word_ids(sentences))

    def _tokens(self, ids: list[list[int]]) -> tuple[torch.Tensor, torch.Tensor]:
        """The sentences' word ids padded on the right with <pad>, on the device, and their mask."""
        length = max(len(row) for row in ids)
        tokens = torch.tensor([row + [0] * (length - len(row)) for row in ids])
        tokens = tokens.to(self.device, non_blocking=True)
        return tokens, tokens != 0

    def encode(self, sentences: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        features, mask, _ = self.encode_counted(sentences)
        return features, mask

    def encode_counted(self, sentences: list[str]) -> tuple[torch.Tensor, torch.Tensor, list[int]]:
        ids = self._word_ids(sentences)
        tokens, mask = self._tokens(ids)
        x = self.embedding(tokens) * math.sqrt(self.dim) + _sinusoid(tokens.shape[1], self.dim, tokens.device)
        return self.encoder(x, src_key_padding_mask=~mask), mask, [len(row) for row in ids]

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

    Returns (B, S_max, dim) features and (B, S_max) mask, S_max the longest concatenation, zeros
    past each caption's tokens. The layout is planned on the host from the sentences' token counts
    (:meth:`TextEncoder.encode_counted`) and applied as one gather on the device, so a training
    step that encodes its captions never makes the host wait for the device.
    """
    if any(len(actions) == 0 for actions in actions_per_caption):
        raise ValueError("every caption needs at least one action sentence")
    flat = [sentence for actions in actions_per_caption for sentence in actions]
    features, _, counts = encoder.encode_counted(flat)
    # one host-built tensor, sent without making the device wait
    plan = token_layout(counts, [len(actions) for actions in actions_per_caption], features.shape[1])
    plan = plan.to(features.device, non_blocking=True)
    joined_mask = plan >= 0
    joined = features.reshape(-1, features.shape[-1])[plan.clamp_min(0)]
    return torch.where(joined_mask[..., None], joined, 0.0), joined_mask


def token_layout(counts: list[int], sentences: list[int], width: int) -> torch.Tensor:
    """Where each caption's tokens come from: (captions, longest) flat positions (sentence row ×
    ``width`` + token) of its sentences' real tokens in order, −1 past them. ``counts`` are the
    sentences' real tokens, ``sentences`` each caption's number of sentences, in order. Whole-array
    NumPy on the host, no Python per token (a paper-size batch has thousands), and no torch
    operator whose size depends on the data (tests/test_host_syncs.py flags those)."""
    tokens = np.asarray(counts, dtype=np.int64)
    row_of_token = np.repeat(np.arange(len(counts)), tokens)
    caption_of_row = np.repeat(np.arange(len(sentences)), sentences)
    caption_of_token = caption_of_row[row_of_token]
    per_caption = np.bincount(caption_of_row, weights=tokens, minlength=len(sentences)).astype(np.int64)
    order = np.arange(len(row_of_token))
    within_row = order - (np.cumsum(tokens) - tokens)[row_of_token]
    within_caption = order - (np.cumsum(per_caption) - per_caption)[caption_of_token]
    plan = np.full((len(sentences), per_caption.max()), -1, dtype=np.int64)
    plan[caption_of_token, within_caption] = row_of_token * width + within_row
    return torch.from_numpy(plan)


_KINDS = {encoder.kind: encoder for encoder in (CLIPTextEncoder, LearnedTextEncoder)}


def option_names() -> frozenset[str]:
    """The options a ``text`` config section may give beside ``kind``: any encoder's, each with
    its own default (a CLIP section names ``path``, a learned one its sizes)."""
    return frozenset(
        name
        for encoder in _KINDS.values()
        for name in inspect.signature(encoder.__init__).parameters
        if name not in ("self", "vocabulary")
    )


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
