"""The motion VQ-VAE's training recipe (``m2d2m train-vq``): windows of the processed dataset's
features, reconstruction previews, and ``vq.pt``, the model file that tokenizing and every token
model read. A config's ``model.part`` trains MMM's part tokenizers, filed under their own stage
(:func:`orchestration.runs.vq_stage`)."""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

from m2d2m.layout import STATS, VQ_FILE
from m2d2m.motion.representation.body_parts import FULL
from m2d2m.networks.vqvae import VQ_FORMAT
from orchestration.recipe import Recipe, Trainable, TrainingData, train
from orchestration.runs import VQ_STAGE, vq_stage
from orchestration.train import OpenedRun, validation_interval


class VQRecipe(Recipe):
    monitor = "val/recon_loss"
    model_format = VQ_FORMAT

    def stage(self, stage: str, config: dict[str, Any]) -> str:
        return vq_stage(config["model"].get("part", FULL))

    def data(self, config: dict[str, Any]) -> TrainingData:
        from training.data.motion_windows import MotionWindowDataModule

        data = config["data"]
        datamodule = MotionWindowDataModule(
            data["dir"],
            window=data["window"],
            batch_size=data["batch_size"],
            num_workers=data["num_workers"],
            steps_per_epoch=validation_interval(config["trainer"]),
            seed=config["seed"],
        )
        return TrainingData(datamodule, Path(data["dir"]), None)

    def module(self, config: dict[str, Any], data: TrainingData) -> Any:
        from training.vq_module import VQVAEModule

        datamodule = data.datamodule
        module = VQVAEModule(
            config["model"], config["optim"], config["loss"], datamodule.feature_dim, datamodule.skeleton
        )
        module.set_normalizer(datamodule.normalizer)
        return module

    def callbacks(self, run: OpenedRun, data: TrainingData) -> list:
        from training.callbacks import ReconstructionPreview

        return [ReconstructionPreview(run.run_dir / "previews", every=run.config["trainer"]["gif_every"])]

    def artifacts(self, data: TrainingData) -> list[Path]:
        return [data.data_dir / STATS]

    def parts(self, config: dict[str, Any], data: TrainingData) -> dict[str, Any]:
        return {"normalizer": data.datamodule.normalizer, "skeleton": data.datamodule.skeleton}


VQ_TRAINING = Trainable(VQ_STAGE, VQ_STAGE, VQ_FILE, VQRecipe())


train_vq = functools.partial(train, VQ_TRAINING)  # ``m2d2m train-vq``: the run directory, with vq.pt on success
