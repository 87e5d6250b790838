"""MMM's model files: the masked transformer (config and weights), its text encoder, the VQ-VAE
whose tokens it predicts (embedded, with its normalisation and skeleton) and the corpus's length
prior, so ``load_mmm(path)`` alone turns text into motion on any machine. The upper-body editor's
file (:data:`BODY_FORMAT`) holds the body transformer and both part tokenizers instead. Training
writes them with ``MMM_FORMAT.save`` / ``BODY_FORMAT.save``, each part by its name; the
transformers' codebook buffers travel with their weights."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from m2d2m.generators.token_model import BodyCodec, EmbeddedVQ, TokenCodec
from m2d2m.model_files import PLAIN, LengthPrior, Lengths, ModelFileKind, Network, Part, Text
from m2d2m.networks.mmm_body_transformer import BodyMaskedTransformer, BodyTransformerConfig
from m2d2m.networks.mmm_transformer import MaskedMotionTransformer, MaskedTransformerConfig
from m2d2m.text import TextEncoder

_SHARED: dict[str, Part] = {"text": Text(), "lengths": Lengths(), "extra": PLAIN}
MMM_FORMAT = ModelFileKind(
    "mmm-transformer/1",
    "an MMM model file",
    {
        "transformer": Network.of(MaskedMotionTransformer, MaskedTransformerConfig, "codebook"),
        "vq": EmbeddedVQ(),
        **_SHARED,
    },
)
BODY_FORMAT = ModelFileKind(
    "mmm-body/1",
    "an MMM upper-body model file",
    {
        "transformer": Network.of(BodyMaskedTransformer, BodyTransformerConfig, "codebook", "lower_codebook"),
        "upper_vq": EmbeddedVQ(),
        "lower_vq": EmbeddedVQ(),
        **_SHARED,
    },
)


@dataclass
class MMMCheckpoint:
    """A loaded MMM model file, on one device, in eval mode."""

    transformer: MaskedMotionTransformer
    text_encoder: TextEncoder
    codec: TokenCodec
    lengths: LengthPrior
    extra: dict[str, Any]


def _checkpoint(parts: dict[str, Any], codec: TokenCodec) -> MMMCheckpoint:
    return MMMCheckpoint(parts["transformer"], parts["text"], codec, parts["lengths"], parts["extra"])


def load_mmm(path: str | Path, device: str | torch.device = "cpu") -> MMMCheckpoint:
    """Read an MMM model file, models in eval mode on ``device``."""
    parts = MMM_FORMAT.load(path, device)
    return _checkpoint(parts, parts["vq"])


def load_body_mmm(path: str | Path, device: str | torch.device = "cpu") -> MMMCheckpoint:
    """Read an upper-body editor's model file; its codec is a :class:`BodyCodec`."""
    parts = BODY_FORMAT.load(path, device)
    return _checkpoint(parts, BodyCodec.pair(parts["upper_vq"], parts["lower_vq"]))
