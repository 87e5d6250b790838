"""MMM's model file: the masked transformer (config and weights), its text encoder, the VQ-VAE
whose tokens it predicts (embedded, with its normalisation and skeleton) and the corpus's length
prior, so ``load_mmm(path)`` alone turns text into motion on any machine."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from m2d2m.generators.token_model import LengthPrior, TokenCodec, text_encoder_from_payload, text_payload
from m2d2m.model_files import cpu_state, read_model_file, write_model_file
from m2d2m.networks.mmm_transformer import MaskedMotionTransformer, MaskedTransformerConfig
from m2d2m.networks.vqvae import FORMAT as VQ_FORMAT
from m2d2m.text import TextEncoder

FORMAT = "mmm-transformer/1"


@dataclass
class MMMCheckpoint:
    """A loaded MMM model file, on one device, in eval mode."""

    transformer: MaskedMotionTransformer
    text_encoder: TextEncoder
    codec: TokenCodec
    lengths: LengthPrior
    extra: dict[str, Any]


def save_mmm(path: str | Path, transformer: MaskedMotionTransformer, text_encoder: TextEncoder,
             text: dict[str, Any], vq_file: str | Path, lengths: LengthPrior,
             extra: dict[str, Any] | None = None) -> Path:
    """Write a model file; ``text`` is the run's config section. The transformer's codebook
    buffer travels with its weights, the VQ-VAE whole."""
    payload = {
        "format": FORMAT,
        "transformer": {"config": transformer.config.to_dict(), "state_dict": cpu_state(transformer)},
        "text": text_payload(text_encoder, text),
        "vq": read_model_file(vq_file, VQ_FORMAT, "m2d2m VQ model file"),
        "lengths": lengths.to_payload(),
        "extra": {} if extra is None else extra,
    }
    return write_model_file(path, payload)


def load_mmm(path: str | Path, device: str | torch.device = "cpu") -> MMMCheckpoint:
    """Read a file written by :func:`save_mmm`, models in eval mode on ``device``."""
    payload = read_model_file(path, FORMAT, "m2d2m MMM model file")
    state = payload["transformer"]["state_dict"]
    transformer = MaskedMotionTransformer(MaskedTransformerConfig.from_dict(payload["transformer"]["config"]),
                                          state["codebook"])
    transformer.load_state_dict(state)
    text_encoder = text_encoder_from_payload(payload["text"])
    return MMMCheckpoint(transformer.to(device).eval(), text_encoder.to(device).eval(),
                         TokenCodec.from_payload(payload["vq"], device), LengthPrior(**payload["lengths"]),
                         payload["extra"])
