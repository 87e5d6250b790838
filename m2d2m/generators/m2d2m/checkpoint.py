"""M2D2M's model file: everything sampling needs in one file.

It holds the denoiser (config and weights), the text encoder (its kind and options; weights when
it was trained, a path when it is the frozen CLIP tower), the transition settings and the codebook
they are built from, the sampling defaults its config chose (``sampling``: the number of steps, the
truncation and the guidance scale every preset starts from), the VQ-VAE that decodes tokens (embedded, with its
normalisation and skeleton), and the corpus's length prior, so ``load_m2d2m(path)`` alone can
turn text into motion on any machine. Training writes it with ``M2D2M_FORMAT.save(path, ...)``,
each part by its name (:class:`m2d2m.model_files.ModelFileKind`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from m2d2m.generators.m2d2m.options import MODEL_DEFAULTS, SAMPLING, M2D2MOptions
from m2d2m.generators.token_model import EmbeddedVQ, TokenCodec
from m2d2m.model_files import PLAIN, Float32, LengthPrior, Lengths, ModelFileKind, Network, Text
from m2d2m.networks.m2d2m_denoiser import DenoiserConfig, MotionDenoiser
from m2d2m.processes.discrete_diffusion import TransitionSchedule
from m2d2m.text import TextEncoder

# ``schedule``: the trained schedule's whole config (endpoints included, so a configured ᾱ_T or γ̄_T
# survives the round trip); ``sampling``: the run's sampling defaults (checked by sampling_defaults)
M2D2M_FORMAT = ModelFileKind(
    "m2d2m-denoiser/1",
    "an M2D2M model file",
    {
        "denoiser": Network.of(MotionDenoiser, DenoiserConfig),
        "text": Text(),
        "schedule": PLAIN,
        "codebook": Float32(),
        "vq": EmbeddedVQ(),
        "lengths": Lengths(),
        "extra": PLAIN,
        "sampling": PLAIN,
    },
)


@dataclass
class M2D2MCheckpoint:
    """A loaded model file, on one device, in eval mode."""

    denoiser: MotionDenoiser
    text_encoder: TextEncoder
    schedule: TransitionSchedule
    codec: TokenCodec
    lengths: LengthPrior
    extra: dict[str, Any]
    sampling: dict[str, Any]  # M2D2MOptions fields of MODEL_DEFAULTS


def load_m2d2m(path: str | Path, device: str | torch.device = "cpu") -> M2D2MCheckpoint:
    """Read an M2D2M model file, models in eval mode on ``device``."""
    parts = M2D2M_FORMAT.load(path, device)
    return M2D2MCheckpoint(
        parts["denoiser"],
        parts["text"],
        TransitionSchedule.from_config(parts["codebook"], parts["schedule"]),
        parts["vq"],
        parts["lengths"],
        parts["extra"],
        parts["sampling"],
    )


def sampling_defaults(values: dict[str, Any], steps: int) -> dict[str, Any]:
    """A config's ``sampling`` section as the options every preset of the model starts from;
    ValueError names a knob that is not one of :data:`MODEL_DEFAULTS` or a value a schedule of
    ``steps`` steps cannot sample with."""
    unknown = sorted(set(values) - set(MODEL_DEFAULTS))
    if unknown:
        raise ValueError(f"sampling.{unknown[0]}: a model's sampling defaults are {', '.join(MODEL_DEFAULTS)}")
    SAMPLING.changed(M2D2MOptions(), **values).check(steps)
    return dict(values)
