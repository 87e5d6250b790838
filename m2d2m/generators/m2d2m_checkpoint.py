"""The denoiser checkpoint: everything sampling needs in one file.

It holds the denoiser (config and weights), the text encoder (its kind and options; weights when
it was trained, a path when it is the frozen CLIP tower), the transition settings and the codebook
they are built from, the sampling defaults its config chose (``sampling``: the number of steps, the
truncation and the guidance scale every preset starts from), the VQ-VAE that decodes tokens (embedded, with its
normalisation and skeleton), and the corpus's length prior, so ``load_checkpoint(path)`` alone can
turn text into motion on any machine.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import torch

from m2d2m.generators.m2d2m_options import MODEL_DEFAULTS, SAMPLING, M2D2MOptions
from m2d2m.generators.token_model import TokenCodec
from m2d2m.model_files import (LengthPrior, cpu_state, read_model_file, text_encoder_from_payload, text_payload,
                               write_model_file)
from m2d2m.networks.m2d2m_denoiser import DenoiserConfig, MotionDenoiser
from m2d2m.networks.vqvae import FORMAT as VQ_FORMAT
from m2d2m.processes.discrete_diffusion import ScheduleConfig, TransitionSchedule
from m2d2m.text import TextEncoder

FORMAT = "m2d2m-denoiser/1"
SCHEDULE_KEYS = tuple(f.name for f in fields(ScheduleConfig))


def schedule_from_config(codebook: torch.Tensor, diffusion: dict[str, Any]) -> TransitionSchedule:
    """The transition schedule a run's ``diffusion`` settings (or a saved schedule config) build
    from its codebook (float64); the settings that are not the schedule's (loss weights) are ignored."""
    options = {k: diffusion[k] for k in SCHEDULE_KEYS if k in diffusion}
    options["steps"] = int(options.get("steps", 100))
    return TransitionSchedule.build(codebook.detach().double(), **options)


@dataclass
class Checkpoint:
    """A loaded checkpoint, on one device, in eval mode."""

    denoiser: MotionDenoiser
    text_encoder: TextEncoder
    schedule: TransitionSchedule
    codec: TokenCodec
    lengths: LengthPrior
    extra: dict[str, Any]
    sampling: dict[str, Any]  # SamplingOptions fields of MODEL_DEFAULTS; empty in files older than them


def save_checkpoint(path: str | Path, denoiser: MotionDenoiser, text_encoder: TextEncoder, text: dict[str, Any],
                    schedule: ScheduleConfig, codebook: torch.Tensor, vq_file: str | Path, lengths: LengthPrior,
                    extra: dict[str, Any] | None = None, sampling: dict[str, Any] | None = None) -> Path:
    """Write a checkpoint; ``text`` is the run's config section, ``schedule`` the trained schedule's
    whole config (endpoints included, so a configured ᾱ_T or γ̄_T survives the round trip),
    ``sampling`` the run's sampling defaults (checked by :func:`sampling_defaults`)."""
    vq_payload = read_model_file(vq_file, VQ_FORMAT, "m2d2m VQ model file")
    payload = {
        "format": FORMAT,
        "denoiser": {"config": denoiser.config.to_dict(),
                     "state_dict": cpu_state(denoiser)},
        "text": text_payload(text_encoder, text),
        "schedule": schedule.to_dict(),
        "codebook": codebook.detach().cpu().to(torch.float32),
        "vq": vq_payload,
        "lengths": lengths.to_payload(),
        "extra": {} if extra is None else extra,
        "sampling": sampling_defaults(sampling or {}, schedule.steps),
    }
    return write_model_file(path, payload)


def load_checkpoint(path: str | Path, device: str | torch.device = "cpu") -> Checkpoint:
    """Read a file written by :func:`save_checkpoint`, models in eval mode on ``device``."""
    payload = read_model_file(path, FORMAT, "m2d2m denoiser checkpoint")
    denoiser = MotionDenoiser(DenoiserConfig.from_dict(payload["denoiser"]["config"]))
    denoiser.load_state_dict(payload["denoiser"]["state_dict"])
    text_encoder = text_encoder_from_payload(payload["text"])
    schedule = schedule_from_config(payload["codebook"].to(device), payload["schedule"])
    return Checkpoint(denoiser.to(device).eval(), text_encoder.to(device).eval(), schedule,
                      TokenCodec.from_payload(payload["vq"], device), LengthPrior(**payload["lengths"]),
                      payload["extra"], payload.get("sampling", {}))


def sampling_defaults(values: dict[str, Any], steps: int) -> dict[str, Any]:
    """A config's ``sampling`` section as the options every preset of the model starts from;
    ValueError names a knob that is not one of :data:`MODEL_DEFAULTS` or a value a schedule of
    ``steps`` steps cannot sample with."""
    unknown = sorted(set(values) - set(MODEL_DEFAULTS))
    if unknown:
        raise ValueError(f"sampling.{unknown[0]}: a model's sampling defaults are {', '.join(MODEL_DEFAULTS)}")
    SAMPLING.changed(M2D2MOptions(), **values).check(steps)
    return dict(values)
