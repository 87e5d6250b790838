"""MMM's model files: the masked transformer (config and weights), its text encoder, the VQ-VAE
whose tokens it predicts (embedded, with its normalisation and skeleton) and the corpus's length
prior, so ``load_mmm(path)`` alone turns text into motion on any machine. The upper-body editor's
file (:func:`save_body_mmm`) holds the body transformer and both part tokenizers instead."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from m2d2m.generators.token_model import BodyCodec, TokenCodec
from m2d2m.model_files import LengthPrior, ModelFileKind, network_payload, text_encoder_from_payload, text_payload
from m2d2m.networks.mmm_body_transformer import BodyMaskedTransformer, BodyTransformerConfig
from m2d2m.networks.mmm_transformer import MaskedMotionTransformer, MaskedTransformerConfig
from m2d2m.networks.vqvae import VQ_FORMAT
from m2d2m.text import TextEncoder

MMM_FORMAT = ModelFileKind("mmm-transformer/1", "an MMM model file")
BODY_FORMAT = ModelFileKind("mmm-body/1", "an MMM upper-body model file")


@dataclass
class MMMCheckpoint:
    """A loaded MMM model file, on one device, in eval mode."""

    transformer: MaskedMotionTransformer
    text_encoder: TextEncoder
    codec: TokenCodec
    lengths: LengthPrior
    extra: dict[str, Any]


def _payload(
    transformer: MaskedMotionTransformer,
    text_encoder: TextEncoder,
    text: dict[str, Any],
    vq_files: dict[str, str | Path],
    lengths: LengthPrior,
    extra: dict[str, Any] | None,
) -> dict[str, Any]:
    """A model file's contents; the transformer's codebook buffers travel with its weights, each
    VQ-VAE of ``vq_files`` (payload key → file) whole."""
    return {
        "transformer": network_payload(transformer),
        "text": text_payload(text_encoder, text),
        **{key: VQ_FORMAT.read(path) for key, path in vq_files.items()},
        "lengths": lengths.to_payload(),
        "extra": {} if extra is None else extra,
    }


def _checkpoint(
    payload: dict[str, Any], transformer: MaskedMotionTransformer, codec: TokenCodec, device: str | torch.device
) -> MMMCheckpoint:
    transformer.load_state_dict(payload["transformer"]["state_dict"])
    text_encoder = text_encoder_from_payload(payload["text"])
    return MMMCheckpoint(
        transformer.to(device).eval(),
        text_encoder.to(device).eval(),
        codec,
        LengthPrior(**payload["lengths"]),
        payload["extra"],
    )


def save_mmm(
    path: str | Path,
    transformer: MaskedMotionTransformer,
    text_encoder: TextEncoder,
    text: dict[str, Any],
    vq_file: str | Path,
    lengths: LengthPrior,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write a model file; ``text`` is the run's config section."""
    return MMM_FORMAT.write(path, _payload(transformer, text_encoder, text, {"vq": vq_file}, lengths, extra))


def load_mmm(path: str | Path, device: str | torch.device = "cpu") -> MMMCheckpoint:
    """Read a file written by :func:`save_mmm`, models in eval mode on ``device``."""
    payload = MMM_FORMAT.read(path)
    state = payload["transformer"]["state_dict"]
    transformer = MaskedMotionTransformer(
        MaskedTransformerConfig.from_dict(payload["transformer"]["config"]), state["codebook"]
    )
    return _checkpoint(payload, transformer, TokenCodec.from_payload(payload["vq"], device), device)


def save_body_mmm(
    path: str | Path,
    transformer: BodyMaskedTransformer,
    text_encoder: TextEncoder,
    text: dict[str, Any],
    upper_vq_file: str | Path,
    lower_vq_file: str | Path,
    lengths: LengthPrior,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write an upper-body editor's model file, with both part tokenizers."""
    vq_files = {"upper_vq": upper_vq_file, "lower_vq": lower_vq_file}
    return BODY_FORMAT.write(path, _payload(transformer, text_encoder, text, vq_files, lengths, extra))


def load_body_mmm(path: str | Path, device: str | torch.device = "cpu") -> MMMCheckpoint:
    """Read a file written by :func:`save_body_mmm`; its codec is a :class:`BodyCodec`."""
    payload = BODY_FORMAT.read(path)
    state = payload["transformer"]["state_dict"]
    transformer = BodyMaskedTransformer(
        BodyTransformerConfig.from_dict(payload["transformer"]["config"]), state["codebook"], state["lower_codebook"]
    )
    codec = BodyCodec.pair(
        TokenCodec.from_payload(payload["upper_vq"], device), TokenCodec.from_payload(payload["lower_vq"], device)
    )
    return _checkpoint(payload, transformer, codec, device)
