"""MotionDiffuse's training recipe (``m2d2m train-motiondiffuse``): the noise estimator on the
processed dataset's caption/motion pairs themselves, no tokens (Zhang et al. 2022, §3.3 and §4.1
"Implementation Details"). Pairs are drawn as for the evaluator (Guo et al.'s loader: a random
caption per clip, its segment, cut to a multiple of 4 frames)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from m2d2m.generators.motiondiffuse_checkpoint import MOTIONDIFFUSE_FORMAT
from orchestration.recipe import Recipe, TrainingData, caption_vocabulary
from orchestration.train import OpenedRun, validation_interval


class MotionDiffuseRecipe(Recipe):
    """Nothing to prepare before parallel trials: they read the processed dataset as it is."""

    model_format = MOTIONDIFFUSE_FORMAT

    def data(self, config: dict[str, Any]) -> TrainingData:
        from training.evaluator_module import CaptionMotionDataModule

        data = config["data"]
        datamodule = CaptionMotionDataModule(
            data["dir"],
            batch_size=data["batch_size"],
            num_workers=data["num_workers"],
            steps_per_epoch=validation_interval(config["trainer"]),
            min_frames=data["min_frames"],
            max_frames=data["max_frames"],
            seed=config["seed"],
            bucket=data.get("bucket", True),
        )
        return TrainingData(
            datamodule, Path(data["dir"]), caption_vocabulary(config, datamodule, lambda caption: [caption["text"]])
        )

    def module(self, config: dict[str, Any], data: TrainingData) -> Any:
        from training.motiondiffuse_module import MotionDiffuseModule

        module = MotionDiffuseModule(
            config["network"],
            config["text"],
            config["diffusion"],
            config["optim"],
            data.datamodule.feature_dim,
            config["text_drop"],
            data.vocabulary,
        )
        module.set_normalizer(data.datamodule.normalizer)
        return module

    def callbacks(self, run: OpenedRun, data: TrainingData) -> list:
        from m2d2m.motion.skeleton import SKELETONS
        from training.callbacks import FeatureSamplePreview

        preview = run.config["preview"]
        return [
            FeatureSamplePreview(
                run.run_dir / "previews",
                SKELETONS[data.datamodule.skeleton],
                preview["prompts"],
                preview["seconds"],
                every=run.config["trainer"]["gif_every"],
            )
        ]

    def parts(self, config: dict[str, Any], data: TrainingData) -> dict[str, Any]:
        datamodule = data.datamodule
        return {
            **data.model_parts(),
            "diffusion": config["diffusion"],
            "normalizer": datamodule.normalizer,
            "skeleton": datamodule.skeleton,
        }


RECIPE = MotionDiffuseRecipe()
