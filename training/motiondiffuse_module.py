"""MotionDiffuse as a LightningModule: ε-prediction on normalised motion features (Zhang et al.
2022, §3.3, eq. 4) with the loss masked by each motion's length, logged per quarter of the
diffusion steps, and deterministic validation; t and the noise are drawn on the module's device,
and nothing is read back on the host (tests/test_host_syncs_models.py)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from m2d2m.generators.motiondiffuse.sampling import FeatureRequest, Term, sample
from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.networks.config import ConfigError
from m2d2m.networks.motiondiffuse_transformer import MotionDiffuseConfig, MotionDiffuseTransformer
from m2d2m.processes.gaussian_diffusion import GaussianDiffusion, prediction_of
from m2d2m.text import text_encoder_from_config
from training.conditioning import drop_captions
from training.data.samples import valid_frames
from training.losses import log_by_quarter
from training.optim import configure_adamw
from training.step import TrainingModule


def masked_mse(predicted: torch.Tensor, target: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
    """Per motion (B,): the mean squared error over its valid frames and every dimension, so that
    padding adds nothing and every motion weighs the same whatever its length."""
    valid = valid_frames(lengths, predicted.shape[1]).to(predicted.dtype)
    squared = ((predicted - target) ** 2).mean(dim=-1) * valid
    return squared.sum(dim=1) / valid.sum(dim=1)


class MotionDiffuseModule(TrainingModule):
    """Uniform t, x_t from q(x_t | x_0) (eq. 3), MSE between ε and ε_θ(x_t, t, text) over the
    valid frames (eq. 4; or between x_0 and the network's x_0 with ``diffusion.prediction: x0``); AdamW with the config's schedule (the paper: Adam, 2e-4). A fraction
    ``text_drop`` of the captions is replaced by the empty sentence, the null condition that
    editing without text asks for (ours, as MMM's). The dataset's normalisation is a buffer, so the
    DataModule hands over raw features and the module normalises them."""

    def __init__(
        self,
        network: dict[str, Any],
        text: dict[str, Any],
        diffusion: dict[str, Any],
        optim: dict[str, Any],
        feature_dim: int,
        text_drop: float = 0.1,
        vocabulary: list[str] | None = None,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        if not 0.0 <= text_drop <= 1.0:
            raise ConfigError(f"text_drop must lie in [0, 1], got {text_drop}")
        self.text_encoder = text_encoder_from_config(text, vocabulary)
        self.network = MotionDiffuseTransformer(
            MotionDiffuseConfig.from_dict({**network, "feature_dim": feature_dim, "text_dim": self.text_encoder.dim})
        )
        try:
            self.process = GaussianDiffusion.from_config(diffusion)
        except ValueError as error:
            raise ConfigError(str(error)) from error
        self.prediction = prediction_of(diffusion)
        self.register_buffer("feature_mean", torch.zeros(feature_dim))
        self.register_buffer("feature_scale", torch.ones(feature_dim))

    def model_parts(self) -> dict[str, Any]:
        """The networks this module gives its model file (m2d2m/generators/motiondiffuse/checkpoint.py)."""
        return {"network": self.network, "text": self.text_encoder}

    def set_normalizer(self, normalizer: Normalizer) -> None:
        self.feature_mean.copy_(torch.as_tensor(np.asarray(normalizer.mean), dtype=torch.float32))
        self.feature_scale.copy_(torch.as_tensor(normalizer.scale, dtype=torch.float32))

    def _losses(
        self, batch: dict[str, Any], generator: torch.Generator | None = None, rng: np.random.Generator | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Each motion's loss (B,) and its step t (B,); ``generator`` (on the module's device)
        fixes t and the noise, and ``rng`` the dropped captions, for validation."""
        motion = batch["motion"]
        lengths = batch["lengths"].to(motion.device)
        t = torch.randint(0, self.process.num_steps, (len(motion),), generator=generator, device=motion.device)
        noise = torch.randn(motion.shape, generator=generator, device=motion.device)
        words, mask = self.text_encoder.encode(drop_captions(batch["text"], self.hparams.text_drop, rng))
        losses = self.compiled(self._noise_losses)(
            motion, lengths, t, noise, words.to(self.device), mask.to(self.device)
        )
        return losses, t

    def _noise_losses(
        self,
        motion: torch.Tensor,
        lengths: torch.Tensor,
        t: torch.Tensor,
        noise: torch.Tensor,
        words: torch.Tensor,
        word_mask: torch.Tensor,
    ) -> torch.Tensor:
        """Each motion's loss from the pass's tensors: what ``trainer.compile`` compiles in a
        training step (:class:`~training.step.TrainingModule`)."""
        x0 = (motion - self.feature_mean) / self.feature_scale
        text = self.network.encode_text(words, word_mask)
        predicted = self.network(self.process.q_sample(x0, t, noise), t, lengths, text)
        return masked_mse(predicted.float(), noise if self.prediction == "epsilon" else x0, lengths)

    def _log_losses(self, split: str, losses: torch.Tensor, t: torch.Tensor, **options: Any) -> torch.Tensor:
        loss = losses.mean()
        # on the progress bar at validation only: a training step's would be read every step
        self.log(f"{split}/loss", loss, batch_size=len(losses), prog_bar=split == "val", **options)
        log_by_quarter(self, f"{split}/loss", losses, t, first=0, steps=self.process.num_steps, **options)
        return loss

    def training_step(self, batch: dict[str, Any], batch_idx: int) -> torch.Tensor:
        losses, t = self._losses(batch)
        loss = self._log_losses("train", losses, t)
        self.guard_finite(loss)
        return loss

    def validation_step(self, batch: dict[str, Any], batch_idx: int) -> None:
        """The same steps, noise and dropped captions in every validation pass (generators seeded
        with ``batch_idx``), so the numbers compare across steps."""
        generator = torch.Generator(device=self.device).manual_seed(int(batch_idx))
        losses, t = self._losses(batch, generator, np.random.default_rng(int(batch_idx)))
        self._log_losses("val", losses, t, sync_dist=True)

    def preview(self, prompts: list[str], frames: list[int], seed: int, steps: int = 50) -> list[np.ndarray]:
        """Un-normalised features for each prompt, by DDIM with ``steps`` steps (a quick look, not
        the paper's 1000)."""
        was_training = self.training
        self.eval()
        try:
            with torch.no_grad():
                words, mask = self.text_encoder.encode(list(prompts))
                text = self.network.encode_text(words.to(self.device), mask.to(self.device))
            process = self.process.respaced(min(steps, self.process.num_steps))
            requests = [FeatureRequest(n, (Term(prompt, 0, n),), seed) for prompt, n in zip(prompts, frames)]
            motions = sample(
                self.network,
                text,
                requests,
                process,
                lambda x, t, eps, noise: process.ddim_sample(x, t, eps, noise, 0.0),
                0.0,
                prediction=self.prediction,
            )
            return [(x * self.feature_scale + self.feature_mean).cpu().numpy() for x in motions]
        finally:
            self.train(was_training)

    def configure_optimizers(self) -> dict[str, Any]:
        return configure_adamw(
            [*self.network.parameters(), *self.text_encoder.parameters()],
            self.hparams.optim,
            fused=self.fuses_optimizer(),
        )
