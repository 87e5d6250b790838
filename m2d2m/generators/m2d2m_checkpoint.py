"""M2D2M's model file: everything sampling needs in one file.

It holds the denoiser (config and weights), the text encoder (its kind and options; weights when
it was trained, a path when it is the frozen CLIP tower), the transition settings and the codebook
they are built from, the sampling defaults its config chose (``sampling``: the number of steps, the
truncation and the guidance scale every preset starts from), the VQ-VAE that decodes tokens (embedded, with its
normalisation and skeleton), and the corpus's length prior, so ``load_m2d2m(path)`` alone can
turn text into motion on any machine.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from m2d2m.generators.m2d2m_options import MODEL_DEFAULTS, SAMPLING, M2D2MOptions
from m2d2m.generators.token_model import TokenCodec
from m2d2m.model_files import LengthPrior, ModelFileKind, network_payload, text_encoder_from_payload, text_payload
from m2d2m.networks.m2d2m_denoiser import DenoiserConfig, MotionDenoiser
from m2d2m.networks.vqvae import VQ_FORMAT
from m2d2m.processes.discrete_diffusion import ScheduleConfig, TransitionSchedule
from m2d2m.text import TextEncoder

M2D2M_FORMAT = ModelFileKind("m2d2m-denoiser/1", "an M2D2M model file")


@dataclass
class M2D2MCheckpoint:
    """A loaded model file, on one device, in eval mode."""

    denoiser: MotionDenoiser
    text_encoder: TextEncoder
    schedule: TransitionSchedule
    codec: TokenCodec
    lengths: LengthPrior
    extra: dict[str, Any]
    sampling: dict[str, Any]  # M2D2MOptions fields of MODEL_DEFAULTS; empty in files older than them


def save_m2d2m(
    path: str | Path,
    denoiser: MotionDenoiser,
    text_encoder: TextEncoder,
    text: dict[str, Any],
    schedule: ScheduleConfig,
    codebook: torch.Tensor,
    vq_file: str | Path,
    lengths: LengthPrior,
    extra: dict[str, Any] | None = None,
    sampling: dict[str, Any] | None = None,
) -> Path:
    """Write a model file; ``text`` is the run's config section, ``schedule`` the trained schedule's
    whole config (endpoints included, so a configured ᾱ_T or γ̄_T survives the round trip),
    ``sampling`` the run's sampling defaults (checked by :func:`sampling_defaults`)."""
    return M2D2M_FORMAT.write(
        path,
        {
            "denoiser": network_payload(denoiser),
            "text": text_payload(text_encoder, text),
            "schedule": schedule.to_dict(),
            "codebook": codebook.detach().cpu().to(torch.float32),
            "vq": VQ_FORMAT.read(vq_file),
            "lengths": lengths.to_payload(),
            "extra": {} if extra is None else extra,
            "sampling": sampling_defaults(sampling or {}, schedule.steps),
        },
    )


def load_m2d2m(path: str | Path, device: str | torch.device = "cpu") -> M2D2MCheckpoint:
    """Read a file written by :func:`save_m2d2m`, models in eval mode on ``device``."""
    payload = M2D2M_FORMAT.read(path)
    denoiser = MotionDenoiser(DenoiserConfig.from_dict(payload["denoiser"]["config"]))
    denoiser.load_state_dict(payload["denoiser"]["state_dict"])
    text_encoder = text_encoder_from_payload(payload["text"])
    schedule = TransitionSchedule.from_config(payload["codebook"].to(device), payload["schedule"])
    return M2D2MCheckpoint(
        denoiser.to(device).eval(),
        text_encoder.to(device).eval(),
        schedule,
        TokenCodec.from_payload(payload["vq"], device),
        LengthPrior(**payload["lengths"]),
        payload["extra"],
        payload.get("sampling", {}),
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
