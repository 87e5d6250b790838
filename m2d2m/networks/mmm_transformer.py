"""MMM's text-conditioned masked motion transformer (Pinyoanuntapong et al., CVPR 2024, §3.2 and
supplement §D; the public code is exitudio/MMM, whose licence forbids reuse: nothing here is taken
from it).

It estimates p(y_i | Y_M̄, W) for every motion token: codes 0..K−1 go in, [END] = K, [PAD] = K+1
and [MASK] = K+2 beside them, and logits over the K codes come out. The input sequence is

    [sentence] y_1 … y_L [END] [PAD] …

- Real codes are embedded by the tokenizer's **frozen** codebook vectors (a buffer, never
  trained), the three special tokens by a learned table of the same width, and both are
  projected to the transformer's width: the transformer sees the codes' geometry from the start.
- The sentence embedding (CLIP's pooled feature, or the learned encoder's) is projected and
  prepended as a token, so every motion token attends to it (§3.2).
- The first ``cross_layers`` blocks attend from the sequence to the word features instead of to
  itself (supplement §D replaces self- by cross-attention in the starting layers, keeping the
  total); the rest are bidirectional self-attention blocks with a key padding mask over [PAD].
- Positions are learned absolute embeddings over ``max_tokens`` + 2 slots: MMM generates each
  piece of a long sequence at most as long as a training motion, so nothing needs extrapolating.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from m2d2m.networks.config import ConfigError, NetworkConfig

SPECIAL_TOKENS = 3  # [END], [PAD], [MASK], after the K codes


@dataclass(frozen=True)
class MaskedTransformerConfig(NetworkConfig):
    """Architecture of the masked transformer; defaults are the paper's HumanML3D model (18 blocks
    of width 1024 with 16 heads, the first 2 cross-attending to the words; 8192 codes of dimension 32;
    49 tokens = 196 frames)."""

    codebook_size: int = 8192
    code_dim: int = 32
    width: int = 1024
    heads: int = 16
    layers: int = 18
    cross_layers: int = 2
    ffn: int = 4096
    dropout: float = 0.1
    text_dim: int = 512
    max_tokens: int = 49

    def __post_init__(self) -> None:
        self.require_positive("codebook_size", "code_dim", "width", "heads", "layers", "ffn", "text_dim", "max_tokens")
        self.require_divisible("width", "heads")
        if not isinstance(self.cross_layers, int) or not 0 <= self.cross_layers <= self.layers:
            raise ConfigError(
                f"MaskedTransformerConfig.cross_layers must lie in 0..layers ({self.layers}), got {self.cross_layers!r}"
            )
        self.require_fraction("dropout")

    @property
    def end_id(self) -> int:
        return self.codebook_size

    @property
    def pad_id(self) -> int:
        return self.codebook_size + 1

    @property
    def mask_id(self) -> int:
        return self.codebook_size + 2

    @property
    def token_width(self) -> int:
        """The width of a token's vector before the projection to the transformer's width."""
        return self.code_dim


def framed(tokens: torch.Tensor, lengths: torch.Tensor, end_id: int, pad_id: int) -> torch.Tensor:
    """(B, W + 1): ``tokens`` (B, W) with ``end_id`` right after each sequence's first
    ``lengths[b]`` tokens and ``pad_id`` after that."""
    batch, width = tokens.shape
    position = torch.arange(width + 1, device=tokens.device)[None, :]
    padded = torch.cat([tokens, torch.full((batch, 1), pad_id, dtype=tokens.dtype, device=tokens.device)], 1)
    padded = torch.where(position < lengths[:, None], padded, torch.full_like(padded, pad_id))
    return torch.where(position == lengths[:, None], torch.full_like(padded, end_id), padded)


def canvas(tokens: torch.Tensor, lengths: torch.Tensor, config: MaskedTransformerConfig) -> torch.Tensor:
    """The network's input (B, W + 1) for ``tokens`` (B, W) of which the first ``lengths[b]`` are
    sequence b's (codes or [MASK]): [END] right after each sequence's last token, [PAD] after that."""
    return framed(tokens, lengths, config.end_id, config.pad_id)


def code_vectors(tokens: torch.Tensor, codebook: torch.Tensor, special: torch.Tensor) -> torch.Tensor:
    """(..., code_dim): ``codebook`` rows for codes 0..K−1, ``special`` rows for [END], [PAD], [MASK]
    (K, K + 1, K + 2). A token outside them is a RuntimeError, asserted without reading the tokens
    on the host (``torch._assert_async``: on a GPU it fails at a later kernel launch, as the
    embedding's own index check would, rather than make every forward pass wait)."""
    last = codebook.shape[0] + SPECIAL_TOKENS - 1
    torch._assert_async(
        ((tokens >= 0) & (tokens <= last)).all(), f"tokens must lie in 0..{last} (codes, then END, PAD, MASK)"
    )
    return F.embedding(tokens, torch.cat([codebook, special]))


class MaskedBlock(nn.Module):
    """Pre-norm attention (to the sequence itself, or to the words) and a GELU feed-forward."""

    def __init__(self, config: MaskedTransformerConfig, cross: bool) -> None:
        super().__init__()
        self.cross = cross
        self.norm = nn.LayerNorm(config.width)
        self.context_norm = nn.LayerNorm(config.width) if cross else None
        self.attention = nn.MultiheadAttention(config.width, config.heads, dropout=config.dropout, batch_first=True)
        self.ffn_norm = nn.LayerNorm(config.width)
        self.ffn = nn.Sequential(
            nn.Linear(config.width, config.ffn),
            nn.GELU(),
            nn.Linear(config.ffn, config.width),
            nn.Dropout(config.dropout),
        )
        self.dropout = nn.Dropout(config.dropout)

    def forward(
        self, x: torch.Tensor, padding: torch.Tensor, words: torch.Tensor, word_padding: torch.Tensor
    ) -> torch.Tensor:
        h = self.norm(x)
        if self.cross:
            context = self.context_norm(words)
            attended, _ = self.attention(h, context, context, key_padding_mask=word_padding, need_weights=False)
        else:
            attended, _ = self.attention(h, h, h, key_padding_mask=padding, need_weights=False)
        x = x + self.dropout(attended)
        return x + self.ffn(self.ffn_norm(x))


class MaskedMotionTransformer(nn.Module):
    """p(y | Y_M̄, W): logits (B, L, K) over the codes for every motion position."""

    def __init__(self, config: MaskedTransformerConfig, codebook: torch.Tensor) -> None:
        super().__init__()
        if tuple(codebook.shape) != (config.codebook_size, config.code_dim):
            raise ConfigError(
                f"the codebook is {tuple(codebook.shape)}, the config asks for "
                f"({config.codebook_size}, {config.code_dim})"
            )
        self.config = config
        self.register_buffer("codebook", codebook.detach().clone().float())
        self.special = nn.Parameter(torch.randn(SPECIAL_TOKENS, config.code_dim) * 0.02)
        self.token_projection = nn.Linear(config.token_width, config.width)
        self.sentence_projection = nn.Linear(config.text_dim, config.width)
        self.word_projection = nn.Linear(config.text_dim, config.width)
        self.positions = nn.Parameter(torch.randn(config.max_tokens + 2, config.width) * 0.02)
        self.blocks = nn.ModuleList(MaskedBlock(config, cross=i < config.cross_layers) for i in range(config.layers))
        self.head_norm = nn.LayerNorm(config.width)
        self.head = nn.Linear(config.width, config.codebook_size)

    def embed_tokens(self, tokens: torch.Tensor) -> torch.Tensor:
        """(B, L, width): frozen code vectors for codes, learned vectors for [END], [PAD], [MASK]."""
        return self.token_projection(code_vectors(tokens, self.codebook, self.special))

    def padding(self, tokens: torch.Tensor) -> torch.Tensor:
        """(B, L) bool: the [PAD] positions, never attended to."""
        return tokens == self.config.pad_id

    def forward(
        self, tokens: torch.Tensor, sentence: torch.Tensor, words: torch.Tensor, word_mask: torch.Tensor
    ) -> torch.Tensor:
        """Logits (B, L, K) for the positions of ``tokens`` (B, L): codes, [MASK] where to predict,
        [END] after a sequence's last token and [PAD] after that (never attended to).
        ``sentence`` (B, text_dim); ``words`` (B, S, text_dim) with ``word_mask`` (B, S), True = real.
        """
        batch, length = tokens.shape[:2]
        if length + 1 > self.positions.shape[0]:
            raise ValueError(f"{length} tokens exceed the {self.config.max_tokens} + [END] this model was built for")
        sequence = torch.cat([self.sentence_projection(sentence)[:, None], self.embed_tokens(tokens)], dim=1)
        sequence = sequence + self.positions[: length + 1]
        padding = torch.cat(
            [torch.zeros(batch, 1, dtype=torch.bool, device=tokens.device), self.padding(tokens)], dim=1
        )
        word_features = self.word_projection(words)
        for block in self.blocks:
            sequence = block(sequence, padding, word_features, ~word_mask)
        return self.head(self.head_norm(sequence[:, 1:]))
