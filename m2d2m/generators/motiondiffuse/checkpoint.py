"""MotionDiffuse's model files: the noise estimator (config and weights), its text encoder, the
diffusion schedule it was trained with, the dataset's normalisation and skeleton, and the corpus's
length prior in frames, so ``load_motiondiffuse(path)`` alone turns text into motion on any
machine. There is no codec: the model generates the features themselves. Training writes it with
``MOTIONDIFFUSE_FORMAT.save(path, ...)``, each part by its name."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from m2d2m.model_files import PLAIN, LengthPrior, Lengths, ModelFileKind, Network, Normalization, Part, Text
from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.motion.representation.skeleton import SKELETONS, Skeleton
from m2d2m.networks.motiondiffuse_transformer import MotionDiffuseConfig, MotionDiffuseTransformer
from m2d2m.processes.gaussian_diffusion import GaussianDiffusion
from m2d2m.text import TextEncoder


class _DiffusionSettings(Part):
    """The run's ``diffusion`` section, refused at save time when no schedule can be built from it
    (a file that could not be read back)."""

    def dump(self, value: dict[str, Any]) -> dict[str, Any]:
        GaussianDiffusion.from_config(value)
        return dict(value)


MOTIONDIFFUSE_FORMAT = ModelFileKind(
    "motiondiffuse/1",
    "a MotionDiffuse model file",
    {
        "network": Network.of(MotionDiffuseTransformer, MotionDiffuseConfig),
        "text": Text(),
        "diffusion": _DiffusionSettings(),
        "normalizer": Normalization(),
        "skeleton": PLAIN,
        "lengths": Lengths(),
        "extra": PLAIN,
    },
)


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


def load_motiondiffuse(path: str | Path, device: str | torch.device = "cpu") -> MotionDiffuseCheckpoint:
    """Read a MotionDiffuse model file, models in eval mode on ``device``."""
    parts = MOTIONDIFFUSE_FORMAT.load(path, device)
    return MotionDiffuseCheckpoint(
        parts["network"],
        parts["text"],
        parts["diffusion"],
        parts["normalizer"],
        SKELETONS[parts["skeleton"]],
        parts["lengths"],
        parts["extra"],
    )
