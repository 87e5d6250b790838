"""The training recipe of Guo et al.'s text–motion matching evaluator (``m2d2m train-evaluator``):
caption/motion pairs of the dataset's train split, the best checkpoint by validation loss, and
``evaluator.pt``, all that computing the metrics needs."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from m2d2m.evaluation.evaluator import EVALUATOR_FORMAT
from orchestration.recipe import Recipe, Trainable, TrainingData, train
from orchestration.runs import EVALUATOR_FILE, EVALUATOR_STAGE
from orchestration.train import validation_interval


@dataclass
class EvaluatorTraining(TrainingData):
    """The evaluator's data: its vocabulary's word vectors when they are GloVe's (None: learned)."""

    vectors: torch.Tensor | None


class EvaluatorRecipe(Recipe):
    model_format = EVALUATOR_FORMAT

    def data(self, config: dict[str, Any]) -> EvaluatorTraining:
        from m2d2m.evaluation.evaluator import learned_vocabulary, load_glove
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
            bucket=data.get("bucket", False),  # off: the evaluator pads to 196 frames itself (docs/training.md)
        )
        if config["model"]["word_features"] == "glove":
            if not config.get("glove_dir"):
                raise ValueError("model.word_features: glove needs glove_dir (Guo's glove/ directory)")
            vocabulary, vectors = load_glove(config["glove_dir"])
        else:
            vocabulary, vectors = learned_vocabulary(datamodule.train_captions(), config["min_word_count"]), None
        return EvaluatorTraining(datamodule, Path(data["dir"]), vocabulary, vectors)

    def module(self, config: dict[str, Any], data: EvaluatorTraining) -> Any:
        from training.evaluator_module import EvaluatorModule

        module = EvaluatorModule(
            config["model"], config["optim"], config["loss"], data.datamodule.feature_dim, data.vocabulary, data.vectors
        )
        module.set_normalizer(data.datamodule.normalizer)
        return module

    def save(
        self, path: Path, module: Any, config: dict[str, Any], data: EvaluatorTraining, extra: dict[str, Any]
    ) -> Path:
        """The evaluator's file is its network alone: it records no run (``extra``)."""
        return self.model_format.save(path, **module.model_parts())


EVALUATOR_TRAINING = Trainable(EVALUATOR_STAGE, EVALUATOR_STAGE, EVALUATOR_FILE, EvaluatorRecipe())


def train_evaluator(
    config_name: str = "demo",
    overrides: list[str] | None = None,
    resume: bool | str = False,
    extra_callbacks: list | None = None,
) -> Path:
    """``m2d2m train-evaluator``: returns the run directory, with ``evaluator.pt`` on success."""
    return train(EVALUATOR_TRAINING, config_name, overrides, resume, extra_callbacks)
