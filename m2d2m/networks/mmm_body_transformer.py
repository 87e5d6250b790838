"""MMM's masked transformer for upper-body editing (Pinyoanuntapong et al., CVPR 2024, §3.3
"Upper Body Editing", Fig. 4 right): the text-conditioned masked transformer of
:mod:`m2d2m.networks.mmm_transformer`, over pairs of tokens.

Each motion position holds an upper-body token and a lower-body token, from two part tokenizers
(:class:`m2d2m.networks.vqvae.VQConfig` ``part``). Its input vector is the upper token's code
vector concatenated with the lower token's ("the upper and lower tokens are concatenated back to
form full body embeddings"), each from its own frozen codebook, with its own learned [END],
[PAD] and [MASK] vectors; the rest of the network is unchanged and the head predicts upper-body
codes only. Tokens are (B, L, 2): column 0 upper (ids as in the base config: codes, then
END = K, PAD = K + 1, MASK = K + 2), column 1 lower (the same over the lower codebook's K').
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from m2d2m.networks.config import ConfigError
from m2d2m.networks.mmm_transformer import (
    SPECIAL_TOKENS,
    MaskedMotionTransformer,
    MaskedTransformerConfig,
    code_vectors,
    framed,
)


@dataclass(frozen=True)
class BodyTransformerConfig(MaskedTransformerConfig):
    """The masked transformer's config with the lower body's codebook beside the upper's
    (``codebook_size`` and ``code_dim``, which the head predicts); the paper's part tokenizers
    have 8192 codes of half the full code width, 16, each."""

    codebook_size: int = 8192
    code_dim: int = 16
    lower_codebook_size: int = 8192
    lower_code_dim: int = 16

    def __post_init__(self) -> None:
        super().__post_init__()
        self.require_positive("lower_codebook_size", "lower_code_dim")

    @property
    def lower_end_id(self) -> int:
        return self.lower_codebook_size

    @property
    def lower_pad_id(self) -> int:
        return self.lower_codebook_size + 1

    @property
    def lower_mask_id(self) -> int:
        return self.lower_codebook_size + 2

    @property
    def token_width(self) -> int:
        return self.code_dim + self.lower_code_dim


def body_canvas(
    upper: torch.Tensor, lower: torch.Tensor, lengths: torch.Tensor, config: BodyTransformerConfig
) -> torch.Tensor:
    """The network's input (B, W + 1, 2) for upper and lower tokens (B, W) each (codes or their
    [MASK]), of which the first ``lengths[b]`` are sequence b's: each column ends with its [END]
    and is padded with its [PAD]."""
    return torch.stack(
        [
            framed(upper, lengths, config.end_id, config.pad_id),
            framed(lower, lengths, config.lower_end_id, config.lower_pad_id),
        ],
        dim=-1,
    )


class BodyMaskedTransformer(MaskedMotionTransformer):
    """p(upper token | upper and lower tokens with [MASK], text): logits (B, L, K_upper)."""

    config: BodyTransformerConfig

    def __init__(self, config: BodyTransformerConfig, codebook: torch.Tensor, lower_codebook: torch.Tensor) -> None:
        super().__init__(config, codebook)
        if tuple(lower_codebook.shape) != (config.lower_codebook_size, config.lower_code_dim):
            raise ConfigError(
                f"the lower-body codebook is {tuple(lower_codebook.shape)}, the config asks for "
                f"({config.lower_codebook_size}, {config.lower_code_dim})"
            )
        self.register_buffer("lower_codebook", lower_codebook.detach().clone().float())
        self.lower_special = nn.Parameter(torch.randn(SPECIAL_TOKENS, config.lower_code_dim) * 0.02)

    def embed_tokens(self, tokens: torch.Tensor) -> torch.Tensor:
        """(B, L, width) from (B, L, 2): the two halves' vectors side by side, projected."""
        if tokens.dim() != 3 or tokens.shape[-1] != 2:
            raise ValueError(f"expected (upper, lower) token pairs (B, L, 2), got {tuple(tokens.shape)}")
        upper = code_vectors(tokens[..., 0], self.codebook, self.special)
        lower = code_vectors(tokens[..., 1], self.lower_codebook, self.lower_special)
        return self.token_projection(torch.cat([upper, lower], dim=-1))

    def padding(self, tokens: torch.Tensor) -> torch.Tensor:
        return tokens[..., 0] == self.config.pad_id
