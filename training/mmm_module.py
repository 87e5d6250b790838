"""MMM's masked transformer as a LightningModule: masked-token prediction on VQ tokens with a text
condition (Pinyoanuntapong et al., CVPR 2024, §3.2, eq. 2) and deterministic validation, neither
reading a tensor back on the host (tests/test_host_syncs_models.py)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from m2d2m.generators.mmm.generator import Row, decode_sentences
from m2d2m.generators.mmm.options import DecodingOptions
from m2d2m.generators.token_model import FREE
from m2d2m.networks.config import ConfigError
from m2d2m.networks.mmm_transformer import MaskedMotionTransformer, MaskedTransformerConfig, canvas
from m2d2m.processes.masking import training_mask
from m2d2m.text import text_encoder_from_config
from training.conditioning import drop_captions
from training.optim import configure_adamw
from training.step import TrainingModule

IGNORED = -100  # F.cross_entropy's ignore_index: the target of every position that is not masked


def as_codebook(codebook: torch.Tensor | np.ndarray) -> torch.Tensor:
    """A tokenizer's (K, code_dim) code vectors as a float tensor."""
    codebook = torch.as_tensor(np.asarray(codebook) if not torch.is_tensor(codebook) else codebook).float()
    if codebook.dim() != 2:
        raise ValueError(f"codebook must have shape (K, code_dim), got {tuple(codebook.shape)}")
    return codebook


def masked_cross_entropy(logits: torch.Tensor, codes: torch.Tensor, masked: torch.Tensor) -> torch.Tensor:
    """The mean cross-entropy of the ``masked`` positions' codes (eq. 2), over a fixed shape:
    the other positions are ignored rather than indexed away, since a boolean index's size depends
    on the data and makes the host wait for it."""
    return F.cross_entropy(logits.flatten(0, 1), codes.masked_fill(~masked, IGNORED).flatten(), ignore_index=IGNORED)


class MMMModule(TrainingModule):
    """Cross-entropy of the masked tokens, r ~ U(α, 1) of each caption's tokens masked; AdamW
    with warm-up and step decay. A fraction ``text_drop`` (the config's top-level key) of the captions is replaced by the
    empty sentence, the null condition (ours: the paper's Table 3 edits "w/o text" but does not
    say how its model learned to). The tokenizer's codebook embeds the codes and is never trained.
    Each training sample is one caption and its segment of the tokens; the condition is the
    caption's sentence feature (prepended) and word features (cross-attended)."""

    def __init__(
        self,
        transformer: dict[str, Any],
        text: dict[str, Any],
        masking: dict[str, Any],
        optim: dict[str, Any],
        codebook: torch.Tensor | np.ndarray,
        vocabulary: list[str] | None = None,
        text_drop: float = 0.0,
    ) -> None:
        super().__init__()
        self.save_hyperparameters(ignore=["codebook", "lower_codebook"])
        self.text_encoder = text_encoder_from_config(text, vocabulary)
        self.transformer = self.build_transformer(transformer, codebook)
        self.alpha = float(masking.get("alpha", 0.5))
        self.text_drop = float(text_drop)
        for name, value in (("masking.alpha", self.alpha), ("text_drop", self.text_drop)):
            if not 0.0 <= value <= 1.0:
                raise ConfigError(f"{name} must lie in [0, 1], got {value}")

    def model_parts(self) -> dict[str, Any]:
        """The networks this module gives its model file (m2d2m/generators/mmm/checkpoint.py)."""
        return {"transformer": self.transformer, "text": self.text_encoder}

    def build_transformer(
        self, settings: dict[str, Any], codebook: torch.Tensor | np.ndarray
    ) -> MaskedMotionTransformer:
        """The network of the config section ``settings`` over the tokenizer's ``codebook``."""
        codebook = as_codebook(codebook)
        config = MaskedTransformerConfig.from_dict(
            {
                **settings,
                "codebook_size": codebook.shape[0],
                "code_dim": codebook.shape[1],
                "text_dim": self.text_encoder.dim,
            }
        )
        return MaskedMotionTransformer(config, codebook)

    def _condition(
        self, captions: list[str], rng: np.random.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The captions' sentence and word features, a fraction ``text_drop`` of them dropped to
        "" (with ``rng``: :func:`~training.conditioning.drop_captions`): the null condition that
        editing without text asks for."""
        words, word_mask, sentence = self.text_encoder.encode_pooled(drop_captions(captions, self.text_drop, rng))
        device = self.transformer.codebook.device
        return sentence.to(device), words.to(device), word_mask.to(device)

    def _masked_inputs(
        self, batch: dict[str, Any], generator: torch.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The batch's codes, the positions masked (drawn with ``generator``) and the transformer's
        input canvas with them masked."""
        config = self.transformer.config
        codes, valid = batch["tokens"].long(), batch["padding_mask"].bool()
        lengths = valid.sum(dim=1)
        masked = training_mask(lengths, codes.shape[1], self.alpha, generator)
        return codes, masked, canvas(codes.masked_fill(masked, config.mask_id), lengths, config)

    def _logits(
        self, inputs: torch.Tensor, sentence: torch.Tensor, words: torch.Tensor, word_mask: torch.Tensor
    ) -> torch.Tensor:
        """The transformer's logits at the canvas's token positions."""
        return self.transformer(inputs, sentence, words, word_mask)[:, :-1]

    def _predict(
        self, batch: dict[str, Any], generator: torch.Generator | None = None, rng: np.random.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Mask the batch's tokens (drawn with ``generator``) and predict them under the captions
        (dropped with ``rng``): (codes, masked positions, logits)."""
        codes, masked, inputs = self._masked_inputs(batch, generator)
        return codes, masked, self._logits(inputs, *self._condition(batch["text"], rng))

    def _masked_loss(
        self,
        inputs: torch.Tensor,
        codes: torch.Tensor,
        masked: torch.Tensor,
        sentence: torch.Tensor,
        words: torch.Tensor,
        word_mask: torch.Tensor,
    ) -> torch.Tensor:
        """A training step's pass from its tensors to the loss: what ``trainer.compile`` compiles
        (:class:`~training.step.TrainingModule`)."""
        return masked_cross_entropy(self._logits(inputs, sentence, words, word_mask), codes, masked)

    def training_step(self, batch: dict[str, Any], batch_idx: int) -> torch.Tensor:
        codes, masked, inputs = self._masked_inputs(batch)
        loss = self.compiled(self._masked_loss)(inputs, codes, masked, *self._condition(batch["text"]))
        self.guard_finite(loss)
        self.log("train/loss", loss, batch_size=codes.shape[0])
        return loss

    def validation_step(self, batch: dict[str, Any], batch_idx: int) -> None:
        """The same masks and dropped captions in every validation pass (generators seeded with
        ``batch_idx``), so the numbers are comparable across steps. Weighted by the number of
        masked tokens, a tensor the host never reads."""
        codes = batch["tokens"]
        generator = torch.Generator(device=codes.device).manual_seed(int(batch_idx))
        codes, masked, logits = self._predict(batch, generator, np.random.default_rng(int(batch_idx)))
        total = masked.sum()
        loss = masked_cross_entropy(logits, codes, masked)
        accuracy = ((logits.argmax(dim=-1) == codes) & masked).sum() / total
        self.log("val/loss", loss, batch_size=total, sync_dist=True, prog_bar=True)
        self.log("val/masked_accuracy", accuracy, batch_size=total, sync_dist=True, prog_bar=True)

    def preview_tokens(self, prompts: list[str], lengths: list[int], seed: int) -> list[torch.Tensor]:
        """Tokens for each prompt, decoded with the paper's settings (for previews)."""
        rows = [Row(prompt, torch.full((n,), FREE), seed) for prompt, n in zip(prompts, lengths)]
        was_training = self.training
        self.eval()
        try:
            return decode_sentences(self.transformer, self.text_encoder, rows, max(lengths), DecodingOptions())
        finally:
            self.train(was_training)

    def configure_optimizers(self) -> dict[str, Any]:
        return configure_adamw(
            [*self.transformer.parameters(), *self.text_encoder.parameters()],
            self.hparams.optim,
            decay_matrices_only=True,
            fused=self.fuses_optimizer(),
        )
