"""The motion VQ-VAE as a LightningModule: T2M-GPT's losses, optimiser and schedule, and the
validation metrics that say whether the codebook is good enough for the denoiser."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from m2d2m.motion.representation.body_parts import part_joints
from m2d2m.motion.representation.features import features_to_joints
from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.motion.representation.skeleton import SKELETONS
from m2d2m.networks.vqvae import MotionVQVAE, VQConfig
from training.optim import configure_adamw
from training.step import TrainingModule


class VQVAEModule(TrainingModule):
    """Smooth-L1 reconstruction + ``joint`` × smooth-L1 on the root-relative joint positions
    (T2M-GPT's "velocity" term, which is really positions) + ``commit`` × commitment, AdamW with
    linear warm-up and step decay. Validation reconstructs whole clips and reports the feature
    error, the joint error in millimetres (MPJPE after ``features_to_joints``) and how many codes
    the validation set uses. A body part's tokenizer (``model.part``) is scored on its part's
    dimensions, positions and joints; for its MPJPE the rest of the body is the ground truth's."""

    def __init__(
        self, model: dict[str, Any], optim: dict[str, Any], loss: dict[str, Any], feature_dim: int, skeleton: str
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.model = MotionVQVAE(VQConfig.from_dict({**model, "feature_dim": feature_dim}))
        self.skeleton = SKELETONS[skeleton]
        j = self.skeleton.num_joints
        dims = self.model.config.dims
        # the root-relative positions among the dimensions the model reconstructs, and its joints
        self.register_buffer(
            "positions", torch.as_tensor(np.flatnonzero((dims >= 4) & (dims < 4 + 3 * (j - 1)))), persistent=False
        )
        self.register_buffer(
            "joints", torch.as_tensor(part_joints(self.skeleton, self.model.config.part)), persistent=False
        )
        # The normalisation travels inside the checkpoint, so a checkpoint alone can decode.
        self.register_buffer("feature_mean", torch.zeros(feature_dim))
        self.register_buffer("feature_scale", torch.ones(feature_dim))
        self.preview: tuple[np.ndarray, np.ndarray] | None = None
        self._val_codes: list[torch.Tensor] = []

    def model_parts(self) -> dict[str, Any]:
        """The network this module gives its model file (``VQ_FORMAT``, m2d2m/networks/vqvae.py)."""
        return {"model": self.model}

    def set_normalizer(self, normalizer: Normalizer) -> None:
        self.feature_mean.copy_(torch.as_tensor(np.asarray(normalizer.mean), dtype=torch.float32))
        self.feature_scale.copy_(torch.as_tensor(normalizer.scale, dtype=torch.float32))

    def _losses(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        out = self.model(x)
        x = self.model.select(x)
        recon = F.smooth_l1_loss(out.reconstruction, x)
        joint = F.smooth_l1_loss(out.reconstruction[..., self.positions], x[..., self.positions])
        weights = self.hparams.loss
        total = weights["recon"] * recon + weights["joint"] * joint + weights["commit"] * out.commit_loss
        losses = {"recon": recon, "joint": joint, "commit": out.commit_loss}
        if weights.get("acceleration", 0.0):
            losses["acceleration"] = F.smooth_l1_loss(
                _acceleration(out.reconstruction[..., self.positions]), _acceleration(x[..., self.positions])
            )
            total = total + weights["acceleration"] * losses["acceleration"]
        return {
            "loss": total,
            **losses,
            "perplexity": out.perplexity,
            "active_codes": out.active_codes.float(),
        }

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        """The losses and codebook statistics, logged without being read on the host (the
        progress bar shows the loss as Lightning last logged it: training/callbacks.py)."""
        losses = self._losses(batch["motion"])
        self.guard_finite(losses["loss"])
        batch_size = len(batch["motion"])
        for name, value in losses.items():
            self.log(f"train/{name}", value, batch_size=batch_size)
        return losses["loss"]

    def _joints(self, normalized: torch.Tensor) -> torch.Tensor:
        features = normalized.float() * self.feature_scale + self.feature_mean
        return features_to_joints(features, self.skeleton)

    def validation_step(self, batch: dict[str, Any], batch_idx: int) -> None:
        # Clips are reconstructed one by one at their own length: padding would leak into the
        # convolutions' context at the end of shorter clips.
        for n, length in enumerate(batch["lengths"].tolist()):
            x = batch["motion"][n : n + 1, :length]
            out = self.model(x)
            # under mixed precision the decoder answers in bf16: every metric is taken in float32
            decoded = out.reconstruction.float()
            error = F.smooth_l1_loss(decoded, self.model.select(x))
            whole = x.clone()  # the reconstructed part within the ground truth's other parts
            whole[..., self.model.dims] = decoded
            truth, reconstruction = self._joints(x)[0], self._joints(whole)[0]
            to_mm = self.skeleton.metres_per_unit * 1000.0
            mpjpe = (truth - reconstruction)[:, self.joints].norm(dim=-1).mean() * to_mm
            # The global error integrates root drift over the clip; the root-aligned one is the pose.
            aligned = ((truth - truth[:, :1]) - (reconstruction - reconstruction[:, :1]))[:, self.joints]
            aligned = aligned.norm(dim=-1).mean() * to_mm
            self.log("val/recon_loss", error, batch_size=1, sync_dist=True)
            self.log("val/feature_l1", (decoded - self.model.select(x)).abs().mean(), batch_size=1, sync_dist=True)
            self.log("val/mpjpe_mm", mpjpe, batch_size=1, sync_dist=True, prog_bar=True)
            self.log("val/mpjpe_root_aligned_mm", aligned, batch_size=1, sync_dist=True, prog_bar=True)
            self._val_codes.append(out.tokens.flatten())
            if batch_idx == 0 and n == 0:
                self.preview = (truth.cpu().numpy(), reconstruction.cpu().numpy())

    def on_validation_epoch_end(self) -> None:
        if self._val_codes:
            used = torch.unique(torch.cat(self._val_codes)).numel()
            self.log("val/active_codes", float(used), sync_dist=True)
        self._val_codes.clear()

    def configure_optimizers(self) -> dict[str, Any]:
        # T2M-GPT decays every weight alike: one parameter group
        return configure_adamw(self.parameters(), self.hparams.optim, fused=self.fuses_optimizer())


def _acceleration(x: torch.Tensor) -> torch.Tensor:
    """Second difference along time of (B, T, C): the optional acceleration term (not in
    T2M-GPT) that penalises the decoder's frame-to-frame jitter directly; docs/training.md."""
    return x[:, 2:] - 2 * x[:, 1:-1] + x[:, :-2]
