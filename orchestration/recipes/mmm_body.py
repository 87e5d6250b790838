"""The training recipe of MMM's upper-body editor (``m2d2m train-mmm-body``): the body transformer
on the token pairs of two part tokenizers (``m2d2m train-vq --config mmm-upper-demo`` and
``mmm-lower-demo``), tokenizing first when their tokens are missing or stale. No sample previews:
an edit needs a motion's lower body, which the module's validation loss already scores."""

from __future__ import annotations

from typing import Any

from m2d2m.generators.mmm.checkpoint import BODY_FORMAT
from orchestration.recipes.token_data import BodyTokenRecipe, BodyTokenTraining, body_token_training


class BodyMMMRecipe(BodyTokenRecipe):
    model_format = BODY_FORMAT

    def data(self, config: dict[str, Any]) -> BodyTokenTraining:
        return body_token_training(
            config, lambda caption: [caption["text"]], max_tokens=config["transformer"]["max_tokens"]
        )

    def module(self, config: dict[str, Any], data: BodyTokenTraining) -> Any:
        from training.mmm_body_module import BodyMMMModule

        return BodyMMMModule(
            config["transformer"],
            config["text"],
            config["masking"],
            config["optim"],
            codebook=data.codebook,
            lower_codebook=data.lower_codebook,
            vocabulary=data.vocabulary,
            text_drop=config["text_drop"],
        )


RECIPE = BodyMMMRecipe()
