"""MMM's upper-body editor as a LightningModule (Pinyoanuntapong et al., CVPR 2024, §3.3, eq. 3):
predict the masked upper-body tokens from the partly masked lower-body tokens and the text."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from m2d2m.networks.config import ConfigError
from m2d2m.networks.mmm_body_transformer import BodyMaskedTransformer, BodyTransformerConfig, body_canvas
from m2d2m.processes.masking import corruption_mask, training_mask
from training.mmm_module import MMMModule, as_codebook

Codebook = torch.Tensor | np.ndarray


class BodyMMMModule(MMMModule):
    """MMM's training (:class:`MMMModule`: r ~ U(α, 1) of each caption's upper-body tokens masked,
    cross-entropy on those alone, AdamW) on token pairs (B, L, 2), with the lower-body tokens
    lightly corrupted: q ~ U(0, ``masking.lower_most``) of them replaced by [MASK] (eq. 3), so that
    the text keeps its say and the editor learns to fill in for masked lower tokens — the
    user's ``lower_mask`` at generation."""

    def __init__(
        self,
        transformer: dict[str, Any],
        text: dict[str, Any],
        masking: dict[str, Any],
        optim: dict[str, Any],
        codebook: Codebook,
        lower_codebook: Codebook,
        vocabulary: list[str] | None = None,
        text_drop: float = 0.0,
    ) -> None:
        super().__init__(transformer, text, masking, optim, (codebook, lower_codebook), vocabulary, text_drop)
        self.lower_most = float(masking.get("lower_most", 0.3))
        if not 0.0 <= self.lower_most <= 1.0:
            raise ConfigError(f"masking.lower_most must lie in [0, 1], got {self.lower_most}")

    def build_transformer(self, settings: dict[str, Any], codebook: tuple[Codebook, Codebook]) -> BodyMaskedTransformer:
        """The body transformer over the (upper, lower) part tokenizers' codebooks."""
        upper, lower = (as_codebook(c) for c in codebook)
        config = BodyTransformerConfig.from_dict(
            {
                **settings,
                "codebook_size": upper.shape[0],
                "code_dim": upper.shape[1],
                "lower_codebook_size": lower.shape[0],
                "lower_code_dim": lower.shape[1],
                "text_dim": self.text_encoder.dim,
            }
        )
        return BodyMaskedTransformer(config, upper, lower)

    def _masked_inputs(
        self, batch: dict[str, Any], generator: torch.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The upper codes, the upper positions masked and the canvas with them masked and the lower
        tokens corrupted (both drawn with ``generator``)."""
        config = self.transformer.config
        pairs, valid = batch["tokens"].long(), batch["padding_mask"].bool()
        upper, lower = pairs[..., 0], pairs[..., 1]
        lengths, width = valid.sum(dim=1), pairs.shape[1]
        masked = training_mask(lengths, width, self.alpha, generator)
        hidden = corruption_mask(lengths, width, self.lower_most, generator)
        inputs = body_canvas(
            upper.masked_fill(masked, config.mask_id), lower.masked_fill(hidden, config.lower_mask_id), lengths, config
        )
        return upper, masked, inputs
