"""MotionDiffuse's training recipe (``m2d2m train-motiondiffuse``): the noise estimator on the
processed dataset's caption/motion pairs themselves, no tokens (Zhang et al. 2022, §3.3 and §4.1
"Implementation Details"). Pairs are drawn as for the evaluator (Guo et al.'s loader: a random
caption per clip, its segment, cut to a multiple of 4 frames)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from m2d2m.generators.motiondiffuse.checkpoint import MOTIONDIFFUSE_FORMAT
from orchestration.recipe import Recipe, TrainingData, caption_motion_data, caption_vocabulary
from orchestration.train import OpenedRun


class MotionDiffuseRecipe(Recipe):
    """Nothing to prepare before parallel trials: they read the processed dataset as it is."""

    model_format = MOTIONDIFFUSE_FORMAT

    def data(self, config: dict[str, Any]) -> TrainingData:
        datamodule = caption_motion_data(config, bucket=True)
        vocabulary = caption_vocabulary(config, datamodule, lambda caption: [caption["text"]])
        return TrainingData(datamodule, Path(config["data"]["dir"]), vocabulary)

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
        from m2d2m.motion.representation.skeleton import SKELETONS
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
