"""The M2D2M denoiser as a LightningModule: discrete-diffusion training on VQ tokens with a text
condition (classifier-free guidance by condition dropout) and deterministic validation metrics."""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import torch

from m2d2m.generators.m2d2m_options import M2D2MOptions
from m2d2m.generators.m2d2m_sampling import TokenRequest, TokenSampler
from m2d2m.networks.config import ConfigError
from m2d2m.networks.m2d2m_denoiser import DenoiserConfig, MotionDenoiser
from m2d2m.processes.discrete_diffusion import TransitionSchedule
from m2d2m.processes.discrete_diffusion_loss import DiffusionLoss, TimestepSampler, diffusion_loss
from m2d2m.text import encode_actions, text_encoder_from_config
from training.losses import FiniteLossGuard, log_by_quarter
from training.optim import configure_adamw


class Denoised(NamedTuple):
    """One noising and denoising pass over a batch: the clean and corrupted tokens, where they are
    real, the denoiser's logits and the loss terms."""

    z0: torch.Tensor
    valid: torch.Tensor
    z_t: torch.Tensor
    logits: torch.Tensor
    loss: DiffusionLoss


class M2D2MModule(FiniteLossGuard):
    """L_vlb + λ·aux on tokens of the frozen VQ codebook, AdamW with warm-up and step decay. A
    non-finite loss stops training at the next step Lightning logs at (:class:`FiniteLossGuard`):
    its steps never read a tensor on the host.

    The codebook is a buffer (not a hyper-parameter), so a checkpoint carries it and the transition
    schedule is rebuilt from it whenever a state dict is loaded. The schedule itself is a plain
    object and follows the module's device lazily (see :meth:`schedule_on_device`).
    """

    def __init__(
        self,
        denoiser: dict[str, Any],
        text: dict[str, Any],
        diffusion: dict[str, Any],
        optim: dict[str, Any],
        codebook: torch.Tensor | np.ndarray,
        vocabulary: list[str] | None = None,
        text_drop: float = 0.1,
    ) -> None:
        super().__init__()
        self.save_hyperparameters(ignore=["codebook"])
        if not 0.0 <= text_drop <= 1.0:
            raise ConfigError(f"text_drop must lie in [0, 1], got {text_drop}")
        codebook = torch.as_tensor(np.asarray(codebook) if not torch.is_tensor(codebook) else codebook)
        codebook = codebook.detach().to(torch.float32).cpu()
        if codebook.dim() != 2:
            raise ValueError(f"codebook must have shape (K, code_dim), got {tuple(codebook.shape)}")
        self.register_buffer("codebook", codebook)
        num_codes = codebook.shape[0]
        steps = int(diffusion.get("steps", 100))

        self.text_encoder = text_encoder_from_config(text, vocabulary)

        config = {
            **denoiser,
            "codebook_size": num_codes,
            "code_dim": codebook.shape[1],
            "steps": steps,
            "text_dim": self.text_encoder.dim,
        }
        if "text_dim" in denoiser and denoiser["text_dim"] != self.text_encoder.dim:
            raise ValueError(
                f"denoiser text_dim ({denoiser['text_dim']}) differs from the text encoder's "
                f"dim ({self.text_encoder.dim})"
            )
        if "steps" in denoiser and denoiser["steps"] != steps:
            raise ValueError(f"denoiser steps ({denoiser['steps']}) differ from diffusion steps ({steps})")
        self.denoiser = MotionDenoiser(DenoiserConfig.from_dict(config), codebook)
        self.aux_weight = float(diffusion.get("aux_weight", 5e-4))
        self.adaptive_aux = bool(diffusion.get("adaptive_aux", False))
        self.timesteps = TimestepSampler(steps, diffusion.get("timestep_sampling", "uniform"))
        self.schedule: TransitionSchedule = self._build_schedule()
        # a loaded checkpoint brings its own codebook: rebuild the schedule from it
        self.register_load_state_dict_post_hook(lambda module, keys: module._rebuild_schedule())

    def model_parts(self) -> dict[str, Any]:
        """The networks and settings this module gives its model file (m2d2m/generators/m2d2m_checkpoint.py)."""
        return {
            "denoiser": self.denoiser,
            "text": self.text_encoder,
            "schedule": self.schedule.config.to_dict(),
            "codebook": self.codebook,
        }

    # ----------------------------------------------------------------------------------- schedule
    def _build_schedule(self) -> TransitionSchedule:
        return TransitionSchedule.from_config(self.codebook, self.hparams.diffusion)

    def _rebuild_schedule(self) -> None:
        self.schedule = self._build_schedule()

    def schedule_on_device(self) -> TransitionSchedule:
        """The schedule, moved to the module's device if it is elsewhere."""
        if self.schedule.device != self.codebook.device:
            self.schedule.to(self.codebook.device)
        return self.schedule

    @property
    def steps(self) -> int:
        return self.schedule.steps

    # ----------------------------------------------------------------------------------- training
    def _condition(self, actions: list[list[str]]) -> tuple[torch.Tensor, torch.Tensor]:
        """The captions' text features and mask, on the text encoder's device (the module's)."""
        return encode_actions(self.text_encoder, actions)

    def _denoise(
        self,
        batch: dict[str, Any],
        t: torch.Tensor,
        generator: torch.Generator | None = None,
        drop_condition: bool = False,
        pt: torch.Tensor | None = None,
    ) -> Denoised:
        """Corrupt the batch's tokens to z_t ~ q(z_t | z0) at ``t`` (padding becomes the mask), denoise
        them under the text condition — dropped at the rate ``text_drop`` when ``drop_condition``, for
        classifier-free guidance — and score the logits. Training and validation differ only in
        where t and the noise come from, so both go through here.

        Nothing here reads a tensor back on the host, which on a GPU would stall the queue of
        kernels every step (``tests/test_host_syncs.py`` holds it so): the schedule's range checks
        are skipped, since the tokens are the VQ-VAE's codes and t comes from
        :class:`TimestepSampler` or ``randint`` over 1..T."""
        schedule = self.schedule_on_device()
        z0, valid = batch["tokens"].long(), batch["padding_mask"].bool()
        z_t = schedule.q_sample(z0.masked_fill(~valid, 0), t[:, None], generator=generator, validate=False)
        z_t = z_t.masked_fill(~valid, schedule.mask_index)
        text, text_mask = self._condition(batch["actions"])
        if drop_condition:
            text, text_mask = self.denoiser.drop_condition(text, text_mask, self.hparams.text_drop)
        logits = self.denoiser(z_t, valid, t, text, text_mask)
        loss = diffusion_loss(
            schedule,
            logits,
            z0,
            z_t,
            t,
            valid=valid,
            aux_weight=self.aux_weight,
            pt=pt,
            adaptive_aux=self.adaptive_aux,
            validate=False,
        )
        return Denoised(z0, valid, z_t, logits, loss)

    def training_step(self, batch: dict[str, Any], batch_idx: int) -> torch.Tensor:
        batch_size = batch["tokens"].shape[0]
        t, pt = self.timesteps.sample(batch_size)  # drawn where the sampler's buffers are: the module's device
        out = self._denoise(batch, t, drop_condition=True, pt=pt).loss
        self.guard_finite(out.loss)
        self.log("train/loss", out.loss, batch_size=batch_size)
        self.log("train/vlb", out.vlb.mean(), batch_size=batch_size)
        self.log("train/aux", out.aux.mean(), batch_size=batch_size)
        log_by_quarter(self, "train/vlb", out.vlb, t, first=1, steps=self.steps)
        self.timesteps.update(t, out.vlb)
        return out.loss

    def validation_step(self, batch: dict[str, Any], batch_idx: int) -> None:
        """A fixed t and z_t per row, drawn from a generator seeded with ``batch_idx``: every
        validation pass scores the same noisy inputs, so the numbers are comparable across steps."""
        tokens = batch["tokens"]
        batch_size = tokens.shape[0]
        generator = torch.Generator(device=tokens.device).manual_seed(int(batch_idx))
        t = torch.randint(1, self.steps + 1, (batch_size,), generator=generator, device=tokens.device)
        z0, valid, z_t, logits, out = self._denoise(batch, t, generator=generator)
        self.log("val/loss", out.loss, batch_size=batch_size, sync_dist=True, prog_bar=True)
        self.log("val/vlb", out.vlb.mean(), batch_size=batch_size, sync_dist=True)
        # accuracy on the positions the model has to restore: masked or replaced ones; weighted by
        # their count as a tensor, so the host never waits for it (a batch with none weighs nothing)
        corrupted = valid & ((z_t == self.schedule.mask_index) | (z_t != z0))
        total = corrupted.sum()
        correct = ((logits.argmax(dim=-1) == z0) & corrupted).sum().float()
        accuracy = correct / total.clamp_min(1)
        self.log("val/token_accuracy", accuracy, batch_size=total, sync_dist=True, prog_bar=True)

    def configure_optimizers(self) -> dict[str, Any]:
        return configure_adamw(
            [*self.denoiser.parameters(), *self.text_encoder.parameters()], self.hparams.optim, decay_matrices_only=True
        )

    # ----------------------------------------------------------------------------------- sampling
    def preview_tokens(
        self, prompts: list[str], lengths: list[int], seed: int, guidance: float = 4.0
    ) -> list[torch.Tensor]:
        """Tokens for each prompt, sampled with no joint phase at guidance ``guidance`` (previews)."""
        requests = [TokenRequest([[prompt]], [n], seed=seed) for prompt, n in zip(prompts, lengths)]
        return [tokens for (tokens,) in self.sampler().sample(requests, M2D2MOptions(guidance=guidance, ts=0))]

    def sampler(self) -> TokenSampler:
        """The reverse process over this module's denoiser, text encoder and schedule (for previews)."""
        return TokenSampler(self.denoiser, self.text_encoder, self.schedule_on_device())
