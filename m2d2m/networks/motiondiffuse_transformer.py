"""MotionDiffuse's cross-modality linear transformer, the noise estimator ε_θ(x_t, t, text) of
Zhang et al., "MotionDiffuse: Text-Driven Human Motion Generation with Diffusion Model" (2022), §3.4
(public code: mingyuan-zhang/MotionDiffuse, ``text2motion/models/transformer.py``; written anew here).

- **Text.** The project's text encoder (frozen CLIP token features at paper size, the learned
  encoder on the embedded default) feeds a linear projection and ``text_layers`` transformer
  layers of MotionDiffuse's own, trained with the denoiser; the sentence vector is their feature
  at the last real token (CLIP's end-of-text token, as the public code takes it).
- **Condition vector** e = sinusoidal timestep embedding through two linear layers + the projected
  sentence vector (§3.4, "Stylization Block").
- **Motion decoder.** Features (F, D) are projected to ``width`` and given learned positions; each
  of ``layers`` layers has linear self-attention, linear cross-attention to the text and an FFN,
  each sub-layer's output passed through a stylization block (eq. 9: LN(Y)·(1 + W) + B from e,
  then SiLU, dropout and a zero-initialised projection) and added residually; the output
  projection is zero-initialised too, so training starts from ε_θ = 0.
- **Attention** is Efficient Attention (Shen et al. 2021; eq. 8): per head, F_g = softmax(K)ᵀ V
  with the softmax over positions, Y = softmax(Q) F_g with the softmax over features: O(n·d²)
  instead of O(n²·d). ``attention: softmax`` switches to standard scaled dot-product attention (the
  paper's Table 3 ablation). Padded frames are masked out of keys and values, so they never
  influence a valid frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from m2d2m.networks.config import ConfigError, NetworkConfig

ATTENTIONS = ("linear", "softmax")


@dataclass(frozen=True)
class MotionDiffuseConfig(NetworkConfig):
    """Architecture; the defaults are the paper's HumanML3D model (8 layers of width 512, 8 heads,
    FFN 1024; a 4-layer text transformer of width 256 over CLIP's 512-d token features; 196 frames)."""

    feature_dim: int = 263
    width: int = 512
    layers: int = 8
    heads: int = 8
    ffn: int = 1024
    dropout: float = 0.0
    text_dim: int = 512  # the text encoder's token features
    text_width: int = 256
    text_layers: int = 4
    text_heads: int = 4
    text_ffn: int = 2048
    max_frames: int = 196  # learned positions: the longest motion one pass generates
    attention: str = "linear"

    def __post_init__(self) -> None:
        self.require_positive(
            "feature_dim",
            "width",
            "layers",
            "heads",
            "ffn",
            "text_dim",
            "text_width",
            "text_heads",
            "text_ffn",
            "max_frames",
        )
        if not isinstance(self.text_layers, int) or self.text_layers < 0:
            raise ConfigError(f"MotionDiffuseConfig.text_layers must be a whole number >= 0, got {self.text_layers!r}")
        self.require_divisible("width", "heads")
        self.require_divisible("text_width", "text_heads")
        self.require_choice("attention", ATTENTIONS)
        self.require_fraction("dropout")

    @property
    def condition_dim(self) -> int:
        """The width of e (the public code's ``time_embed_dim``: 4 × width)."""
        return 4 * self.width


def _heads(x: torch.Tensor, heads: int) -> torch.Tensor:
    """(B, N, C) → (B, heads, N, C / heads)."""
    batch, length, channels = x.shape
    return x.view(batch, length, heads, channels // heads).transpose(1, 2)


def _merge_heads(x: torch.Tensor) -> torch.Tensor:
    batch, heads, length, channels = x.shape
    return x.transpose(1, 2).reshape(batch, length, heads * channels)


def efficient_attention(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, key_mask: torch.Tensor) -> torch.Tensor:
    """Eq. 8 per head: softmax(Q) over each query's features, softmax(K) over the valid key
    positions, F_g = softmax(K)ᵀ V (d × d), Y = softmax(Q) F_g. q (B, H, N, d); k, v (B, H, M, d);
    key_mask (B, M) True on valid keys, which alone reach the output."""
    valid = key_mask[:, None, :, None]
    k = k.masked_fill(~valid, float("-inf")).softmax(dim=2)
    global_map = k.transpose(-1, -2) @ v.masked_fill(~valid, 0.0)
    return q.softmax(dim=-1) @ global_map


def softmax_attention(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, key_mask: torch.Tensor) -> torch.Tensor:
    """Eq. 7 per head, invalid keys masked out: the paper's Table 3 alternative, O(N·M·d)."""
    return F.scaled_dot_product_attention(q, k, v, attn_mask=key_mask[:, None, None, :])


class Stylization(nn.Module):
    """Eq. 9: a sub-layer's output Y becomes LN(Y)·(1 + W) + B, W and B projected from the
    condition e, then SiLU, dropout and a zero-initialised projection (added residually by the
    caller)."""

    def __init__(self, width: int, condition_dim: int, dropout: float) -> None:
        super().__init__()
        self.modulation = nn.Sequential(nn.SiLU(), nn.Linear(condition_dim, 2 * width))
        self.norm = nn.LayerNorm(width)
        self.out = nn.Sequential(nn.SiLU(), nn.Dropout(dropout), nn.Linear(width, width))
        nn.init.zeros_(self.out[-1].weight)
        nn.init.zeros_(self.out[-1].bias)

    def forward(self, y: torch.Tensor, condition: torch.Tensor) -> torch.Tensor:
        scale, shift = self.modulation(condition)[:, None, :].chunk(2, dim=-1)
        return self.out(self.norm(y) * (1 + scale) + shift)


class Attention(nn.Module):
    """Self-attention over the frames (``context`` None) or cross-attention to the text tokens."""

    def __init__(self, config: MotionDiffuseConfig, context_width: int | None = None) -> None:
        super().__init__()
        width = config.width
        self.heads = config.heads
        self.attend = efficient_attention if config.attention == "linear" else softmax_attention
        self.norm = nn.LayerNorm(width)
        self.context_norm = nn.LayerNorm(context_width) if context_width else None
        self.query = nn.Linear(width, width)
        self.key = nn.Linear(context_width or width, width)
        self.value = nn.Linear(context_width or width, width)
        self.stylize = Stylization(width, config.condition_dim, config.dropout)

    def forward(
        self,
        x: torch.Tensor,
        mask: torch.Tensor,
        condition: torch.Tensor,
        context: torch.Tensor | None = None,
        context_mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        normed = self.norm(x)
        source, source_mask = (normed, mask) if context is None else (self.context_norm(context), context_mask)
        y = self.attend(
            _heads(self.query(normed), self.heads),
            _heads(self.key(source), self.heads),
            _heads(self.value(source), self.heads),
            source_mask,
        )
        return x + self.stylize(_merge_heads(y), condition)


class FeedForward(nn.Module):
    def __init__(self, config: MotionDiffuseConfig) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(config.width, config.ffn),
            nn.GELU(),
            nn.Dropout(config.dropout),
            nn.Linear(config.ffn, config.width),
        )
        nn.init.zeros_(self.net[-1].weight)
        nn.init.zeros_(self.net[-1].bias)
        self.stylize = Stylization(config.width, config.condition_dim, config.dropout)

    def forward(self, x: torch.Tensor, condition: torch.Tensor) -> torch.Tensor:
        return x + self.stylize(self.net(x), condition)


class DecoderLayer(nn.Module):
    def __init__(self, config: MotionDiffuseConfig) -> None:
        super().__init__()
        self.self_attention = Attention(config)
        self.cross_attention = Attention(config, context_width=config.text_width)
        self.feed_forward = FeedForward(config)

    def forward(self, x: torch.Tensor, mask: torch.Tensor, condition: torch.Tensor, text: EncodedText) -> torch.Tensor:
        x = self.self_attention(x, mask, condition)
        x = self.cross_attention(x, mask, condition, text.tokens, text.mask)
        return self.feed_forward(x, condition)


def timestep_embedding(t: torch.Tensor, dim: int) -> torch.Tensor:
    """(B, dim) sinusoidal embedding of the diffusion step (Vaswani et al. 2017's positions)."""
    half = dim // 2
    frequencies = torch.exp(-math.log(10000.0) * torch.arange(half, device=t.device, dtype=torch.float32) / half)
    angles = t.float()[:, None] * frequencies[None]
    embedding = torch.cat([torch.cos(angles), torch.sin(angles)], dim=-1)
    return F.pad(embedding, (0, dim % 2))


@dataclass
class EncodedText:
    """A batch of sentences as the decoder reads them, computed once per sampling run rather than
    once per diffusion step: token features (B, S, text_width), their mask, and the sentence
    vector projected to the condition width (B, condition_dim)."""

    tokens: torch.Tensor
    mask: torch.Tensor
    sentence: torch.Tensor

    def take(self, rows: torch.Tensor) -> EncodedText:
        """The encodings of ``rows`` (indices), e.g. one per term of a controlled sampling run."""
        return EncodedText(self.tokens[rows], self.mask[rows], self.sentence[rows])


class MotionDiffuseTransformer(nn.Module):
    """ε_θ(x_t, t, text): normalised features (B, F, D) of noisy motions → their noise (B, F, D)."""

    def __init__(self, config: MotionDiffuseConfig) -> None:
        super().__init__()
        self.config = config
        width = config.width
        self.text_projection = nn.Linear(config.text_dim, config.text_width)
        layer = nn.TransformerEncoderLayer(
            config.text_width, config.text_heads, config.text_ffn, config.dropout, activation="gelu", batch_first=True
        )
        self.text_transformer = (
            nn.TransformerEncoder(layer, config.text_layers, enable_nested_tensor=False)
            if config.text_layers
            else nn.Identity()
        )
        self.text_norm = nn.LayerNorm(config.text_width)
        self.sentence_projection = nn.Linear(config.text_width, config.condition_dim)
        self.time_embedding = nn.Sequential(
            nn.Linear(width, config.condition_dim), nn.SiLU(), nn.Linear(config.condition_dim, config.condition_dim)
        )
        self.motion_projection = nn.Linear(config.feature_dim, width)
        self.positions = nn.Parameter(torch.randn(config.max_frames, width) * 0.02)
        self.decoder = nn.ModuleList(DecoderLayer(config) for _ in range(config.layers))
        self.output = nn.Linear(width, config.feature_dim)
        nn.init.zeros_(self.output.weight)
        nn.init.zeros_(self.output.bias)

    def encode_text(self, words: torch.Tensor, word_mask: torch.Tensor) -> EncodedText:
        """The text encoder's token features (B, S, text_dim) and mask → :class:`EncodedText`."""
        x = self.text_projection(words)
        if self.config.text_layers:
            x = self.text_transformer(x, src_key_padding_mask=~word_mask)
        x = self.text_norm(x)
        last = word_mask.long().cumsum(dim=1).argmax(dim=1)  # the last real token of each sentence
        return EncodedText(x, word_mask, self.sentence_projection(x[torch.arange(len(x)), last]))

    def forward(self, x: torch.Tensor, t: torch.Tensor, lengths: torch.Tensor, text: EncodedText) -> torch.Tensor:
        """ε for noisy motions ``x`` (B, F, D) at steps ``t`` (B,) (the indices the network was
        trained on), each ``lengths[b]`` frames long (the rest is padding, which no valid frame
        sees), under ``text``."""
        frames = x.shape[1]
        if frames > self.config.max_frames:
            raise ValueError(
                f"MotionDiffuse generates at most {self.config.max_frames} frames in one pass; {frames} were asked for"
            )
        mask = torch.arange(frames, device=x.device)[None, :] < lengths[:, None]
        condition = self.time_embedding(timestep_embedding(t, self.config.width)) + text.sentence
        h = self.motion_projection(x) + self.positions[:frames]
        for layer in self.decoder:
            h = layer(h, mask, condition, text)
        return self.output(h)
