"""The denoising transformer of M2D2M (paper §4.4; VQ-Diffusion's block: microsoft/VQ-Diffusion,
``image_synthesis/modeling/transformers/transformer_utils.py``).

It estimates p(z0 | z_t, y): motion tokens ``z_t`` (values 0..K-1, K = the mask) go in, logits over
the K codes (never the mask) come out. Each pre-norm block is

    x += SelfAttn(AdaLN(x, t))            relative position bias, motion padding masked
    x += CrossAttn(AdaLN(x, t), text)     text padding masked
    x += FFN(LN(x))                       GELU

Choices, each on purpose:

- No absolute positions anywhere: the only positional signal is a T5-style bucketed relative bias,
  so a model trained on single actions runs on the concatenated sequences of two-phase sampling.
  One bias table (``num_buckets`` x heads) is shared by all layers, as in T5, so the extrapolation
  behaviour is a property of one table rather than of twelve.
- AdaLN follows VQ-Diffusion: LayerNorm without affine parameters, scaled by ``1 + scale`` and
  shifted by ``shift``, both projected from a sinusoidal-then-MLP timestep embedding.
- Classifier-free guidance uses a learned null condition: a single learned text token with mask
  True, so the cross-attention always has something to attend to.
- Padding is masked with the most negative finite value of the attention dtype rather than -inf,
  so a row with no valid key (an all-padding sample) stays finite instead of turning into NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from m2d2m.networks.config import ConfigError, NetworkConfig


@dataclass(frozen=True)
class DenoiserConfig(NetworkConfig):
    """Architecture of the denoiser; the defaults are the paper's (12 x 16 heads x 512, FFN 2048)."""

    codebook_size: int = 512
    layers: int = 12
    heads: int = 16
    width: int = 512
    ffn: int = 2048
    dropout: float = 0.0
    text_dim: int = 512
    steps: int = 100
    max_distance: int = 128
    num_buckets: int = 32
    condition_drop: float = 0.1

    def __post_init__(self) -> None:
        self.require_positive("codebook_size", "layers", "heads", "width", "ffn", "text_dim", "steps", "max_distance")
        self.require_divisible("width", "heads")
        if not isinstance(self.num_buckets, int) or self.num_buckets < 4 or self.num_buckets % 2:
            raise ConfigError(f"DenoiserConfig.num_buckets must be an even integer >= 4, got {self.num_buckets!r}")
        if self.max_distance <= self.num_buckets // 4:
            raise ConfigError(f"DenoiserConfig.max_distance must exceed num_buckets // 4 "
                             f"({self.num_buckets // 4}), got {self.max_distance}")
        self.require_fraction("dropout", "condition_drop")


def relative_position_bucket(relative: torch.Tensor, num_buckets: int, max_distance: int) -> torch.Tensor:
    """T5's bidirectional bucketing of ``key - query`` offsets.

    Half of the buckets per direction hold exact small offsets, the rest are log-spaced up to
    ``max_distance``; every offset at or beyond ``max_distance`` falls in the last bucket of its
    direction, which is what lets the model run on sequences longer than any it was trained on.
    """
    half = num_buckets // 2
    exact = half // 2
    direction = (relative > 0).long() * half
    distance = relative.abs()
    log_ratio = torch.log(distance.float().clamp(min=1.0) / exact) / math.log(max_distance / exact)
    far = (exact + (log_ratio * (half - exact)).long()).clamp(max=half - 1)
    return direction + torch.where(distance < exact, distance, far)


def guided_logits(cond_logits: torch.Tensor, uncond_logits: torch.Tensor, scale: float) -> torch.Tensor:
    """Classifier-free guidance in log space, as VQ-Diffusion does it: log_softmax(u + s (c - u)).

    Inputs may be raw logits or log-probabilities: a per-position constant offset of either input
    cancels in the final log_softmax. Computed in float32 so bf16 logits do not lose the difference.
    """
    cond, uncond = cond_logits.float(), uncond_logits.float()
    return torch.log_softmax(uncond + scale * (cond - uncond), dim=-1)


def _key_mask(valid: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """Additive (B, 1, 1, S) mask: 0 for valid keys, the dtype's most negative value for padding."""
    blocked = torch.zeros(valid.shape, dtype=dtype, device=valid.device)
    blocked = blocked.masked_fill(~valid, torch.finfo(dtype).min)
    return blocked[:, None, None, :]


class TimestepEmbedding(nn.Module):
    """Sinusoidal features of t (stretched to [0, 4000] like VQ-Diffusion's ``adalayernorm_abs``) -> MLP."""

    def __init__(self, width: int, steps: int) -> None:
        super().__init__()
        self.width = width
        self.scale = 4000.0 / steps
        self.mlp = nn.Sequential(nn.Linear(width, width), nn.SiLU(), nn.Linear(width, width))

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        half = self.width // 2
        frequencies = torch.exp(-math.log(10000.0) * torch.arange(half, device=t.device) / half)
        angles = t.float()[:, None] * self.scale * frequencies[None, :]
        features = torch.cat([angles.sin(), angles.cos()], dim=-1)
        if self.width % 2:
            features = F.pad(features, (0, 1))
        return self.mlp(features)


class AdaLayerNorm(nn.Module):
    """LayerNorm whose scale and shift are predicted from the timestep embedding."""

    def __init__(self, width: int) -> None:
        super().__init__()
        self.norm = nn.LayerNorm(width, elementwise_affine=False)
        self.project = nn.Sequential(nn.SiLU(), nn.Linear(width, 2 * width))

    def forward(self, x: torch.Tensor, time: torch.Tensor) -> torch.Tensor:
        scale, shift = self.project(time)[:, None, :].chunk(2, dim=-1)
        return self.norm(x) * (1 + scale) + shift


class Attention(nn.Module):
    """Multi-head attention through ``scaled_dot_product_attention`` with an additive float mask."""

    def __init__(self, width: int, heads: int, context_dim: int, dropout: float) -> None:
        super().__init__()
        self.heads = heads
        self.dropout = dropout
        self.query = nn.Linear(width, width)
        self.key = nn.Linear(context_dim, width)
        self.value = nn.Linear(context_dim, width)
        self.out = nn.Linear(width, width)

    def _split(self, x: torch.Tensor) -> torch.Tensor:
        batch, length, _ = x.shape
        return x.view(batch, length, self.heads, -1).transpose(1, 2)

    def forward(self, x: torch.Tensor, context: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        q, k, v = self._split(self.query(x)), self._split(self.key(context)), self._split(self.value(context))
        attended = F.scaled_dot_product_attention(
            q, k, v, attn_mask=mask.to(q.dtype), dropout_p=self.dropout if self.training else 0.0)
        batch, _, length, _ = attended.shape
        return self.out(attended.transpose(1, 2).reshape(batch, length, -1))


class DenoiserBlock(nn.Module):
    """Pre-norm self-attention, cross-attention and feed-forward, the first two timestep-modulated."""

    def __init__(self, config: DenoiserConfig) -> None:
        super().__init__()
        width = config.width
        self.self_norm = AdaLayerNorm(width)
        self.self_attention = Attention(width, config.heads, width, config.dropout)
        self.cross_norm = AdaLayerNorm(width)
        self.cross_attention = Attention(width, config.heads, config.text_dim, config.dropout)
        self.ffn_norm = nn.LayerNorm(width)
        self.ffn = nn.Sequential(nn.Linear(width, config.ffn), nn.GELU(), nn.Linear(config.ffn, width),
                                 nn.Dropout(config.dropout))
        self.residual_dropout = nn.Dropout(config.dropout)

    def forward(self, x: torch.Tensor, time: torch.Tensor, self_mask: torch.Tensor,
                text: torch.Tensor, cross_mask: torch.Tensor) -> torch.Tensor:
        h = self.self_norm(x, time)
        x = x + self.residual_dropout(self.self_attention(h, h, self_mask))
        x = x + self.residual_dropout(self.cross_attention(self.cross_norm(x, time), text, cross_mask))
        return x + self.ffn(self.ffn_norm(x))


class MotionDenoiser(nn.Module):
    """p(z0 | z_t, t, text): logits (B, L, K) over the codes for every motion token."""

    def __init__(self, config: DenoiserConfig) -> None:
        super().__init__()
        self.config = config
        self.mask_id = config.codebook_size
        self.token_embedding = nn.Embedding(config.codebook_size + 1, config.width)
        self.time_embedding = TimestepEmbedding(config.width, config.steps)
        self.relative_bias = nn.Embedding(config.num_buckets, config.heads)
        self.null_text = nn.Parameter(torch.zeros(1, 1, config.text_dim))
        self.blocks = nn.ModuleList(DenoiserBlock(config) for _ in range(config.layers))
        self.head_norm = nn.LayerNorm(config.width)
        self.head = nn.Linear(config.width, config.codebook_size)
        self.apply(self._init_weights)
        nn.init.normal_(self.null_text, std=0.02)

    @staticmethod
    def _init_weights(module: nn.Module) -> None:
        """VQ-Diffusion's init: N(0, 0.02) weights, zero biases, unit LayerNorm."""
        if isinstance(module, (nn.Linear, nn.Embedding)):
            nn.init.normal_(module.weight, std=0.02)
            if isinstance(module, nn.Linear) and module.bias is not None:
                nn.init.zeros_(module.bias)
        elif isinstance(module, nn.LayerNorm) and module.elementwise_affine:
            nn.init.ones_(module.weight)
            nn.init.zeros_(module.bias)

    def null_condition(self, batch: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The learned unconditional text: one token per sample, always valid."""
        text = self.null_text.expand(batch, -1, -1)
        return text, torch.ones(batch, 1, dtype=torch.bool, device=text.device)

    def drop_condition(self, text: torch.Tensor, text_mask: torch.Tensor, p: float,
                       generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Replace each sample's condition by the null condition with probability ``p`` (CFG training).

        The null token takes the first position and the rest of that sample's tokens become
        padding, so dropped and kept samples share one (B, S, D) batch.
        """
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"drop probability must lie in [0, 1], got {p!r}")
        batch, length, _ = text.shape
        if length < 1:
            raise ValueError("text must have at least one token to be replaced by the null condition")
        draw_device = generator.device if generator is not None else text.device
        dropped = (torch.rand(batch, generator=generator, device=draw_device) < p).to(text.device)
        return self.nullify(text, text_mask, dropped)

    def nullify(self, text: torch.Tensor, text_mask: torch.Tensor,
                rows: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The condition with the samples where ``rows`` (B,) is True replaced by the null condition,
        which takes the first position, the rest of that sample's tokens becoming padding."""
        batch, length, _ = text.shape
        null_text = F.pad(self.null_text.to(text.dtype), (0, 0, 0, length - 1)).expand(batch, -1, -1)
        null_mask = torch.zeros_like(text_mask)
        null_mask[:, 0] = True
        rows = rows.to(text.device)
        return torch.where(rows[:, None, None], null_text, text), torch.where(rows[:, None], null_mask, text_mask)

    def relative_position_bias(self, length: int, device: torch.device) -> torch.Tensor:
        """(heads, L, L) learned bias indexed by the bucket of ``key - query``."""
        positions = torch.arange(length, device=device)
        buckets = relative_position_bucket(positions[None, :] - positions[:, None],
                                           self.config.num_buckets, self.config.max_distance)
        return self.relative_bias(buckets).permute(2, 0, 1)

    def forward(self, tokens: torch.Tensor, padding_mask: torch.Tensor | None, t: torch.Tensor,
                text: torch.Tensor | None = None, text_mask: torch.Tensor | None = None) -> torch.Tensor:
        """Logits (B, L, K) for z0.

        ``tokens`` (B, L) long in [0, K]; ``padding_mask`` (B, L) bool, True = real (None: all real);
        ``t`` (B,) long in [1, T]; ``text`` (B, S, text_dim) with ``text_mask`` (B, S) bool, or
        ``text=None`` for the unconditional (null) condition.
        """
        batch, length = tokens.shape
        if padding_mask is None:
            padding_mask = torch.ones_like(tokens, dtype=torch.bool)
        if text is None:
            text, text_mask = self.null_condition(batch)
        elif text_mask is None:
            text_mask = torch.ones(text.shape[:2], dtype=torch.bool, device=text.device)
        # Padded slots may hold anything; read them as the mask token so no index is out of range.
        tokens = tokens.masked_fill(~padding_mask, self.mask_id)
        x = self.token_embedding(tokens)
        time = self.time_embedding(t)
        self_mask = self.relative_position_bias(length, tokens.device)[None] + _key_mask(padding_mask, torch.float32)
        cross_mask = _key_mask(text_mask, torch.float32)
        for block in self.blocks:
            x = block(x, time, self_mask, text, cross_mask)
        return self.head(self.head_norm(x))
