"""The training recipe of Guo et al.'s text–motion matching evaluator (``m2d2m train-evaluator``):
caption/motion pairs of the dataset's train split, the best checkpoint by validation loss, and
``evaluator.pt``, all that computing the metrics needs."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from m2d2m.evaluation.evaluator import EVALUATOR_FORMAT
from orchestration.recipe import Recipe, Trainable, TrainingData, caption_motion_data, train
from orchestration.runs import EVALUATOR_FILE, EVALUATOR_STAGE


@dataclass
class EvaluatorTraining(TrainingData):
    """The evaluator's data: its vocabulary's word vectors when they are GloVe's (None: learned)."""

    vectors: torch.Tensor | None


class EvaluatorRecipe(Recipe):
    model_format = EVALUATOR_FORMAT

    def data(self, config: dict[str, Any]) -> EvaluatorTraining:
        from m2d2m.evaluation.evaluator import learned_vocabulary, load_glove

        datamodule = caption_motion_data(config, bucket=False)  # off: it pads to 196 frames itself (docs/training.md)
        if config["model"]["word_features"] == "glove":
            if not config.get("glove_dir"):
                raise ValueError("model.word_features: glove needs glove_dir (Guo's glove/ directory)")
            vocabulary, vectors = load_glove(config["glove_dir"])
        else:
            vocabulary, vectors = learned_vocabulary(datamodule.train_captions(), config["min_word_count"]), None
        return EvaluatorTraining(datamodule, Path(config["data"]["dir"]), vocabulary, vectors)

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


train_evaluator = functools.partial(train, EVALUATOR_TRAINING)  # ``m2d2m train-evaluator``: the run directory
