"""The M2D2M denoiser as a LightningModule: discrete-diffusion training on VQ tokens with a text
condition (classifier-free guidance by condition dropout) and deterministic validation metrics."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from m2d2m.compiling import pad_to_bucket
from m2d2m.generators.m2d2m.options import M2D2MOptions
from m2d2m.generators.m2d2m.sampling import TokenRequest, TokenSampler
from m2d2m.networks.config import ConfigError
from m2d2m.networks.m2d2m_denoiser import DenoiserConfig, MotionDenoiser
from m2d2m.processes.discrete_diffusion import TransitionSchedule
from m2d2m.processes.discrete_diffusion_loss import DiffusionLoss, TimestepSampler, diffusion_loss
from m2d2m.text import encode_actions, text_encoder_from_config
from training.losses import log_by_quarter
from training.optim import configure_adamw
from training.step import TrainingModule


class M2D2MModule(TrainingModule):
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
        """The networks and settings this module gives its model file (m2d2m/generators/m2d2m/checkpoint.py)."""
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

    def _corrupt(
        self, z0: torch.Tensor, valid: torch.Tensor, t: torch.Tensor, generator: torch.Generator | None = None
    ) -> torch.Tensor:
        """z_t ~ q(z_t | z0) at ``t``, padding the mask.

        Nothing here or in :meth:`_score` reads a tensor back on the host, which on a GPU would
        stall the queue of kernels every step (``tests/test_host_syncs.py`` holds it so): the
        schedule's range checks are skipped, since the tokens are the VQ-VAE's codes and t comes
        from :class:`TimestepSampler` or ``randint`` over 1..T. The draw is float32, like the loss:
        no float64 on a GPU's training step."""
        schedule = self.schedule_on_device()
        z0 = z0.masked_fill(~valid, 0)
        z_t = schedule.q_sample(z0, t[:, None], generator=generator, validate=False, dtype=torch.float32)
        return z_t.masked_fill(~valid, schedule.mask_index)

    def _score(
        self,
        z0: torch.Tensor,
        valid: torch.Tensor,
        z_t: torch.Tensor,
        t: torch.Tensor,
        text: torch.Tensor,
        text_mask: torch.Tensor,
        drop_condition: bool = False,
        pt: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, DiffusionLoss]:
        """Denoise z_t under the text condition — dropped at the rate ``text_drop`` when
        ``drop_condition``, for classifier-free guidance — and score the logits against z0.
        Training and validation differ only in where t and the noise come from, so both go
        through here."""
        if drop_condition:
            text, text_mask = self.denoiser.drop_condition(text, text_mask, self.hparams.text_drop)
        logits = self.denoiser(z_t, valid, t, text, text_mask)
        loss = diffusion_loss(
            self.schedule_on_device(),
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
        return logits, loss

    def _training_loss(
        self,
        z0: torch.Tensor,
        valid: torch.Tensor,
        z_t: torch.Tensor,
        t: torch.Tensor,
        pt: torch.Tensor,
        text: torch.Tensor,
        text_mask: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """A training step's pass from its tensors to (loss, per-sample L_vlb, per-sample aux): what
        ``trainer.compile`` compiles (:class:`~training.step.TrainingModule`)."""
        out = self._score(z0, valid, z_t, t, text, text_mask, drop_condition=True, pt=pt)[1]
        return out.loss, out.vlb, out.aux

    def training_step(self, batch: dict[str, Any], batch_idx: int) -> torch.Tensor:
        z0, valid = batch["tokens"].long(), batch["padding_mask"].bool()
        batch_size = z0.shape[0]
        t, pt = self.timesteps.sample(batch_size)  # drawn where the sampler's buffers are: the module's device
        z_t = self._corrupt(z0, valid, t)
        text, text_mask = self._condition(batch["actions"])
        if self.compiles_steps():
            # a few shapes for the compiled pass: padded tokens and text are masked, so the loss,
            # a mean over the valid tokens, is that of the batch as it came
            z0, valid, z_t = (pad_to_bucket(x, 1) for x in (z0, valid, z_t))
            text, text_mask = pad_to_bucket(text, 1), pad_to_bucket(text_mask, 1)
        loss, vlb, aux = self.compiled(self._training_loss)(z0, valid, z_t, t, pt, text, text_mask)
        self.guard_finite(loss)
        self.log("train/loss", loss, batch_size=batch_size)
        self.log("train/vlb", vlb.mean(), batch_size=batch_size)
        self.log("train/aux", aux.mean(), batch_size=batch_size)
        log_by_quarter(self, "train/vlb", vlb, t, first=1, steps=self.steps)
        self.timesteps.update(t, vlb)
        return loss

    def validation_step(self, batch: dict[str, Any], batch_idx: int) -> None:
        """A fixed t and z_t per row, drawn from a generator seeded with ``batch_idx``: every
        validation pass scores the same noisy inputs, so the numbers are comparable across steps."""
        tokens = batch["tokens"]
        batch_size = tokens.shape[0]
        generator = torch.Generator(device=tokens.device).manual_seed(int(batch_idx))
        t = torch.randint(1, self.steps + 1, (batch_size,), generator=generator, device=tokens.device)
        z0, valid = tokens.long(), batch["padding_mask"].bool()
        z_t = self._corrupt(z0, valid, t, generator)
        logits, out = self._score(z0, valid, z_t, t, *self._condition(batch["actions"]))
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
            [*self.denoiser.parameters(), *self.text_encoder.parameters()],
            self.hparams.optim,
            decay_matrices_only=True,
            fused=self.fuses_optimizer(),
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
