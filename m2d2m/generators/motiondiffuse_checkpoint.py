"""MotionDiffuse's model files: the noise estimator (config and weights), its text encoder, the
diffusion schedule it was trained with, the dataset's normalisation and skeleton, and the corpus's
length prior in frames, so ``load_motiondiffuse(path)`` alone turns text into motion on any
machine. There is no codec: the model generates the features themselves."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from m2d2m.model_files import LengthPrior, ModelFileKind, network_payload, text_encoder_from_payload, text_payload
from m2d2m.motion.normalization import Normalizer
from m2d2m.motion.skeleton import SKELETONS, Skeleton
from m2d2m.networks.motiondiffuse_transformer import MotionDiffuseConfig, MotionDiffuseTransformer
from m2d2m.processes.gaussian_diffusion import GaussianDiffusion
from m2d2m.text import TextEncoder

MOTIONDIFFUSE_FORMAT = ModelFileKind("motiondiffuse/1", "a MotionDiffuse model file")


@dataclass
class MotionDiffuseCheckpoint:
    """A loaded model file, on one device, in eval mode."""

    network: MotionDiffuseTransformer
    text_encoder: TextEncoder
    diffusion: dict[str, Any]
    normalizer: Normalizer
    skeleton: Skeleton
    lengths: LengthPrior  # in frames
    extra: dict[str, Any]

    @property
    def process(self) -> GaussianDiffusion:
        return GaussianDiffusion.from_config(self.diffusion)


def save_motiondiffuse(
    path: str | Path,
    network: MotionDiffuseTransformer,
    text_encoder: TextEncoder,
    text: dict[str, Any],
    diffusion: dict[str, Any],
    normalizer: Normalizer,
    skeleton: str,
    lengths: LengthPrior,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write a model file; ``text`` and ``diffusion`` are the run's config sections."""
    GaussianDiffusion.from_config(diffusion)  # refuse a schedule the file could not be read back with
    return MOTIONDIFFUSE_FORMAT.write(
        path,
        {
            "network": network_payload(network),
            "text": text_payload(text_encoder, text),
            "diffusion": dict(diffusion),
            "normalizer": {
                "mean": torch.as_tensor(np.asarray(normalizer.mean, dtype=np.float32)),
                "std": torch.as_tensor(np.asarray(normalizer.std, dtype=np.float32)),
                "feat_bias": float(normalizer.feat_bias),
            },
            "skeleton": str(skeleton),
            "lengths": lengths.to_payload(),
            "extra": {} if extra is None else extra,
        },
    )


def load_motiondiffuse(path: str | Path, device: str | torch.device = "cpu") -> MotionDiffuseCheckpoint:
    """Read a file written by :func:`save_motiondiffuse`, models in eval mode on ``device``."""
    payload = MOTIONDIFFUSE_FORMAT.read(path)
    network = MotionDiffuseTransformer(MotionDiffuseConfig.from_dict(payload["network"]["config"]))
    network.load_state_dict(payload["network"]["state_dict"])
    text_encoder = text_encoder_from_payload(payload["text"])
    stats = payload["normalizer"]
    normalizer = Normalizer(stats["mean"].numpy(), stats["std"].numpy(), stats["feat_bias"])
    return MotionDiffuseCheckpoint(
        network.to(device).eval(),
        text_encoder.to(device).eval(),
        payload["diffusion"],
        normalizer,
        SKELETONS[payload["skeleton"]],
        LengthPrior(**payload["lengths"]),
        payload["extra"],
    )
