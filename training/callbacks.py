"""Callbacks shared by the training stages: pictures of progress logged to MLflow."""

from __future__ import annotations

from pathlib import Path

import lightning.pytorch as pl
from lightning.pytorch.loggers import MLFlowLogger

from m2d2m.render import render_comparison


class ReconstructionPreview(pl.Callback):
    """Every ``every`` validations, a GIF of the first validation clip: ground truth beside the
    model's reconstruction, written under ``directory`` and logged as an MLflow artifact."""

    def __init__(self, directory: str | Path, every: int = 1) -> None:
        self.directory = Path(directory)
        self.every = max(1, every)
        self.validations = 0

    def on_validation_epoch_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        if trainer.sanity_checking or not trainer.is_global_zero or module.preview is None:
            return
        self.validations += 1
        if (self.validations - 1) % self.every:
            return
        truth, reconstruction = module.preview
        path = render_comparison([truth, reconstruction], ["ground truth", "reconstruction"],
                                 self.directory / f"step-{trainer.global_step:07d}.gif",
                                 skeleton=module.skeleton, size=240)
        if isinstance(trainer.logger, MLFlowLogger):
            trainer.logger.experiment.log_artifact(trainer.logger.run_id, str(path), artifact_path="previews")
