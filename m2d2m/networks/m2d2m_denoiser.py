"""The denoising transformer of M2D2M (paper §4.4; VQ-Diffusion's block: microsoft/VQ-Diffusion,
``image_synthesis/modeling/transformers/transformer_utils.py``).

It estimates p(z0 | z_t, y): motion tokens ``z_t`` (values 0..K-1, K = the mask) go in, logits over
the K codes (never the mask) come out. Each pre-norm block is

    x += SelfAttn(AdaLN(x, t))            relative position bias, motion padding masked
    x += CrossAttn(AdaLN(x, t), text)     text padding masked
    x += FFN(LN(x))                       GELU

Choices, each on purpose:

- No absolute positions in the sequence: its positional signal is a T5-style bucketed relative bias,
  so a model trained on single actions runs on the concatenated sequences of two-phase sampling.
  One bias table (``num_buckets`` x heads) is shared by all layers, as in T5, so the extrapolation
  behaviour is a property of one table rather than of twelve.
- ``positions: relative`` (the paper, §4.4) stops there. Then an all-[MASK] input gives every
  position the same logits: attention over identical values returns the same value whatever the
  bias, and padded keys are masked, so the model knows neither where it is nor how long the clip is.
  ``positions: action`` (ours, docs/training.md) adds to each token's embedding sinusoidal features
  of its offsets from its action's first and last token. They are bounded by an action's length,
  never by the sequence's, so the joint phase of Two-Phase Sampling (four actions in one row, each
  with its own offsets) stays within what training showed, and the relative bias still spans the
  boundaries.
- ``embedding: learned`` (VQ-Diffusion's) gives every code a trained vector; ``embedding: codebook``
  (ours, after MMM, Pinyoanuntapong et al. 2024, §3.2) embeds a code by a projection of its frozen
  VQ codebook vector, so codes that decode alike start alike, and the mask by a trained vector.
- AdaLN follows VQ-Diffusion: LayerNorm without affine parameters, scaled by ``1 + scale`` and
  shifted by ``shift``, both projected from a sinusoidal-then-MLP timestep embedding.
- Classifier-free guidance uses a learned null condition: a single learned text token with mask
  True, so the cross-attention always has something to attend to.
- Padding is masked with the most negative finite value of the attention dtype rather than -inf,
  so a row with no valid key (an all-padding sample) stays finite instead of turning into NaN.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from m2d2m.networks.config import ConfigError, NetworkConfig

POSITIONS = ("relative", "action")
EMBEDDINGS = ("learned", "codebook")
KeysValues = tuple[torch.Tensor, torch.Tensor]


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
    positions: str = "relative"  # the paper's; "action" adds offsets within the action (ours)
    embedding: str = "learned"  # the paper's (VQ-Diffusion's); "codebook" projects the frozen code vectors (ours)
    code_dim: int = 512  # the codebook vectors' width (read with embedding: codebook)

    def __post_init__(self) -> None:
        self.require_positive("codebook_size", "layers", "heads", "width", "ffn", "text_dim", "steps", "max_distance")
        self.require_divisible("width", "heads")
        if not isinstance(self.num_buckets, int) or self.num_buckets < 4 or self.num_buckets % 2:
            raise ConfigError(f"DenoiserConfig.num_buckets must be an even integer >= 4, got {self.num_buckets!r}")
        if self.max_distance <= self.num_buckets // 4:
            raise ConfigError(
                f"DenoiserConfig.max_distance must exceed num_buckets // 4 "
                f"({self.num_buckets // 4}), got {self.max_distance}"
            )
        self.require_fraction("dropout")
        self.require_choice("positions", POSITIONS)
        self.require_choice("embedding", EMBEDDINGS)
        self.require_positive("code_dim")


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
    """Classifier-free guidance in log space with the paper's scale (eq. 9):
    log_softmax((1 + s)·c − s·u), so s = 0 is the conditional model alone. (VQ-Diffusion's code
    writes u + s'(c − u): its s' is our 1 + s.)

    Inputs may be raw logits or log-probabilities: a per-position constant offset of either input
    cancels in the final log_softmax. Computed in float32 so bf16 logits do not lose the difference.
    """
    cond, uncond = cond_logits.float(), uncond_logits.float()
    return torch.log_softmax(cond + scale * (cond - uncond), dim=-1)


def sinusoid(values: torch.Tensor, width: int) -> torch.Tensor:
    """(..., width) sine and cosine features of ``values`` at geometric frequencies (Vaswani et al.
    2017, §3.5); an odd width gets a zero last feature."""
    half = width // 2
    frequencies = torch.exp(-math.log(10000.0) * torch.arange(half, device=values.device) / max(half, 1))
    angles = values.float()[..., None] * frequencies
    features = torch.cat([angles.sin(), angles.cos()], dim=-1)
    return F.pad(features, (0, width % 2))


def action_offsets(actions: Sequence[Sequence[int]], width: int, device: torch.device | str = "cpu") -> torch.Tensor:
    """(rows, width, 2) long: each position's distance from the first and to the last token of its
    action, for rows laid out as consecutive actions of the given lengths (``actions[row]``);
    positions past a row's actions (padding) get 0. Built on the host from the lengths and sent in
    one copy that does not make the device wait."""
    offsets = torch.zeros(len(actions), width, 2, dtype=torch.long)
    for row, lengths in enumerate(actions):
        start = 0
        for length in lengths:
            inside = torch.arange(length)
            offsets[row, start : start + length, 0] = inside
            offsets[row, start : start + length, 1] = length - 1 - inside
            start += length
    return offsets.to(device, non_blocking=True)


def row_offsets(padding_mask: torch.Tensor) -> torch.Tensor:
    """:func:`action_offsets` when each row is one action: its real positions (True) from the start."""
    lengths = padding_mask.sum(dim=1, keepdim=True)
    inside = torch.arange(padding_mask.shape[1], device=padding_mask.device)[None, :].expand_as(padding_mask)
    offsets = torch.stack([inside, (lengths - 1 - inside)], dim=-1)
    return torch.where(padding_mask[..., None], offsets, 0)


def _key_mask(valid: torch.Tensor, dtype: torch.dtype) -> torch.Tensor:
    """Additive (B, 1, 1, S) mask: 0 for valid keys, the dtype's most negative value for padding."""
    blocked = torch.zeros(valid.shape, dtype=dtype, device=valid.device)
    blocked = blocked.masked_fill(~valid, torch.finfo(dtype).min)
    return blocked[:, None, None, :]


def _attention_dtype(device: torch.device, weights: torch.dtype) -> torch.dtype:
    """The dtype ``scaled_dot_product_attention`` computes in: autocast's where it is on (its
    casts would otherwise convert a float32 mask in every block), else the weights'."""
    return torch.get_autocast_dtype(device.type) if torch.is_autocast_enabled(device.type) else weights


class TimestepEmbedding(nn.Module):
    """Sinusoidal features of t (stretched to [0, 4000] like VQ-Diffusion's ``adalayernorm_abs``) -> MLP."""

    def __init__(self, width: int, steps: int) -> None:
        super().__init__()
        self.width = width
        self.scale = 4000.0 / steps
        self.mlp = nn.Sequential(nn.Linear(width, width), nn.SiLU(), nn.Linear(width, width))

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        return self.mlp(sinusoid(t.float() * self.scale, self.width))


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
    """Multi-head attention through ``scaled_dot_product_attention`` with an additive float mask.

    The keys and values come from :meth:`context` apart from the queries, so a caller that attends
    to the same context many times (the text, over every reverse step) projects it once.
    """

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

    def context(self, context: torch.Tensor) -> KeysValues:
        """The context's keys and values, each (B, heads, S, head_dim)."""
        return self._split(self.key(context)), self._split(self.value(context))

    def forward(self, x: torch.Tensor, keys_values: KeysValues, mask: torch.Tensor) -> torch.Tensor:
        keys, values = keys_values
        queries = self._split(self.query(x))  # in the dtype the attention computes in (bf16 under autocast)
        attended = F.scaled_dot_product_attention(
            queries,
            keys,
            values,
            attn_mask=mask.to(queries.dtype),
            dropout_p=self.dropout if self.training else 0.0,
        )
        batch, _, length, _ = attended.shape
        return self.out(attended.transpose(1, 2).reshape(batch, length, -1))


@dataclass(frozen=True)
class Condition:
    """The text as every block's cross-attention sees it: its keys and values per block and the
    additive mask of its padding (B, 1, 1, S). A sampler builds it once per phase
    (:meth:`MotionDenoiser.condition`) and reuses it at every reverse step."""

    keys_values: tuple[KeysValues, ...]
    mask: torch.Tensor

    def rows(self, index: torch.Tensor) -> Condition:
        """The condition of the rows ``index`` (in that order)."""
        return Condition(tuple((keys[index], values[index]) for keys, values in self.keys_values), self.mask[index])


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
        self.ffn = nn.Sequential(
            nn.Linear(width, config.ffn), nn.GELU(), nn.Linear(config.ffn, width), nn.Dropout(config.dropout)
        )
        self.residual_dropout = nn.Dropout(config.dropout)

    def forward(
        self, x: torch.Tensor, time: torch.Tensor, self_mask: torch.Tensor, text: KeysValues, cross_mask: torch.Tensor
    ) -> torch.Tensor:
        h = self.self_norm(x, time)
        x = x + self.residual_dropout(self.self_attention(h, self.self_attention.context(h), self_mask))
        x = x + self.residual_dropout(self.cross_attention(self.cross_norm(x, time), text, cross_mask))
        return x + self.ffn(self.ffn_norm(x))


class MotionDenoiser(nn.Module):
    """p(z0 | z_t, t, text): logits (B, L, K) over the codes for every motion token. With
    ``embedding: codebook`` it holds the frozen codebook (K, code_dim) as a buffer: pass it when
    training starts; a saved state dict brings its own."""

    def __init__(self, config: DenoiserConfig, codebook: torch.Tensor | None = None) -> None:
        super().__init__()
        self.config = config
        self.mask_id = config.codebook_size
        if config.embedding == "codebook":
            shape = (config.codebook_size, config.code_dim)
            if codebook is not None and tuple(codebook.shape) != shape:
                raise ConfigError(f"the codebook is {tuple(codebook.shape)}, the config asks for {shape}")
            self.register_buffer(
                "codebook", torch.zeros(shape) if codebook is None else codebook.detach().float().clone()
            )
            self.code_projection = nn.Linear(config.code_dim, config.width)
            self.mask_vector = nn.Parameter(torch.zeros(config.width))
            self.token_embedding = None
        else:
            self.token_embedding = nn.Embedding(config.codebook_size + 1, config.width)
        self.time_embedding = TimestepEmbedding(config.width, config.steps)
        self.relative_bias = nn.Embedding(config.num_buckets, config.heads)
        self.offset_embedding = nn.Linear(config.width, config.width) if config.positions == "action" else None
        self._buckets: dict[tuple[int, str], torch.Tensor] = {}
        self.null_text = nn.Parameter(torch.zeros(1, 1, config.text_dim))
        self.blocks = nn.ModuleList(DenoiserBlock(config) for _ in range(config.layers))
        self.head_norm = nn.LayerNorm(config.width)
        self.head = nn.Linear(config.width, config.codebook_size)
        self.apply(self._init_weights)
        nn.init.normal_(self.null_text, std=0.02)
        if self.token_embedding is None:
            nn.init.normal_(self.mask_vector, std=0.02)

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

    def drop_condition(
        self, text: torch.Tensor, text_mask: torch.Tensor, p: float, generator: torch.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
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

    def nullify(
        self, text: torch.Tensor, text_mask: torch.Tensor, rows: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The condition with the samples where ``rows`` (B,) is True replaced by the null condition,
        which takes the first position, the rest of that sample's tokens becoming padding."""
        batch, length, _ = text.shape
        null_text = F.pad(self.null_text.to(text.dtype), (0, 0, 0, length - 1)).expand(batch, -1, -1)
        null_mask = torch.zeros_like(text_mask)
        null_mask[:, 0] = True
        rows = rows.to(text.device)
        return torch.where(rows[:, None, None], null_text, text), torch.where(rows[:, None], null_mask, text_mask)

    def embed(self, tokens: torch.Tensor) -> torch.Tensor:
        """(B, L, width) vectors of tokens in [0, K], K the mask."""
        if self.token_embedding is not None:
            return self.token_embedding(tokens)
        codes = self.code_projection(self.codebook[tokens.clamp(max=self.mask_id - 1)])
        return torch.where((tokens == self.mask_id)[..., None], self.mask_vector.to(codes.dtype), codes)

    def relative_position_bias(self, length: int, device: torch.device) -> torch.Tensor:
        """(heads, L, L) learned bias indexed by the bucket of ``key - query``. The buckets of a
        length are computed once (a sampler asks for the same lengths at every step), except under
        ``torch.compile``, where they become part of the compiled graph: writing to a cache there
        would make every call retrace."""
        if torch.compiler.is_compiling():
            return self.relative_bias(self._position_buckets(length, device)).permute(2, 0, 1)
        key = (length, str(device))
        if key not in self._buckets:
            self._buckets[key] = self._position_buckets(length, device)
        return self.relative_bias(self._buckets[key]).permute(2, 0, 1)

    def _position_buckets(self, length: int, device: torch.device) -> torch.Tensor:
        positions = torch.arange(length, device=device)
        offsets = positions[None, :] - positions[:, None]
        return relative_position_bucket(offsets, self.config.num_buckets, self.config.max_distance)

    def condition(
        self, text: torch.Tensor | None, text_mask: torch.Tensor | None, batch: int | None = None
    ) -> Condition:
        """The text condition (B, S, text_dim) with its mask (B, S), True = real (None: all real), as
        the blocks attend to it; ``text=None`` is the null condition of ``batch`` rows."""
        if text is None:
            text, text_mask = self.null_condition(batch or 1)
        elif text_mask is None:
            text_mask = torch.ones(text.shape[:2], dtype=torch.bool, device=text.device)
        keys_values = tuple(block.cross_attention.context(text) for block in self.blocks)
        return Condition(keys_values, _key_mask(text_mask, torch.float32))

    def forward(
        self,
        tokens: torch.Tensor,
        padding_mask: torch.Tensor | None,
        t: torch.Tensor,
        text: torch.Tensor | None = None,
        text_mask: torch.Tensor | None = None,
        offsets: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Logits (B, L, K) for z0.

        ``tokens`` (B, L) long in [0, K]; ``padding_mask`` (B, L) bool, True = real (None: all real);
        ``t`` (B,) long in [1, T] (or (1,): one t for every row); ``text`` (B, S, text_dim) with ``text_mask`` (B, S) bool, or
        ``text=None`` for the unconditional (null) condition; ``offsets`` see :meth:`denoise`.
        """
        return self.denoise(tokens, padding_mask, t, self.condition(text, text_mask, tokens.shape[0]), offsets)

    def denoise(
        self,
        tokens: torch.Tensor,
        padding_mask: torch.Tensor | None,
        t: torch.Tensor,
        condition: Condition,
        offsets: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """:meth:`forward` under a prepared :meth:`condition`. ``offsets`` (B, L, 2) are each
        position's distances from its action's first and to its last token
        (:func:`action_offsets`); None reads every row as one action. Only ``positions: action``
        uses them."""
        length = tokens.shape[1]
        if padding_mask is None:
            padding_mask = torch.ones_like(tokens, dtype=torch.bool)
        # Padded slots may hold anything; read them as the mask token so no index is out of range.
        tokens = tokens.masked_fill(~padding_mask, self.mask_id)
        x = self.embed(tokens)
        if self.offset_embedding is not None:
            if offsets is None:
                offsets = row_offsets(padding_mask)
            half = self.config.width // 2
            features = torch.cat(
                [sinusoid(offsets[..., 0], half), sinusoid(offsets[..., 1], self.config.width - half)], dim=-1
            )
            x = x + self.offset_embedding(features.to(x.dtype))
        time = self.time_embedding(t)
        # built once in the dtype the attention computes in, so no block converts this (B, heads, L, L) mask again
        dtype = _attention_dtype(tokens.device, self.head.weight.dtype)
        bias = self.relative_position_bias(length, tokens.device)[None]
        # contiguous: the bias is a permuted (L, L, heads) lookup, and a GPU's fused attention kernels
        # need the mask's last dimension at stride 1 (else SDPA falls back to its math path, 10× slower)
        self_mask = (bias + _key_mask(padding_mask, dtype)).to(dtype).contiguous()
        for block, keys_values in zip(self.blocks, condition.keys_values):
            x = block(x, time, self_mask, keys_values, condition.mask)
        return self.head(self.head_norm(x))
