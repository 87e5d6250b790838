"""MMM's training recipe (``m2d2m train-mmm``): the masked transformer on the tokens of a VQ-VAE
run (the demo's by default, so the comparison with M2D2M isolates the generator), tokenizing
first when its tokens are missing or stale."""

from __future__ import annotations

from typing import Any

from m2d2m.generators.mmm.checkpoint import MMM_FORMAT
from orchestration.recipes.token_data import TokenRecipe, TokenTraining, token_training


class MMMRecipe(TokenRecipe):
    model_format = MMM_FORMAT

    def data(self, config: dict[str, Any]) -> TokenTraining:
        return token_training(config, lambda caption: [caption["text"]], max_tokens=config["transformer"]["max_tokens"])

    def module(self, config: dict[str, Any], data: TokenTraining) -> Any:
        from training.mmm_module import MMMModule

        return MMMModule(
            config["transformer"],
            config["text"],
            config["masking"],
            config["optim"],
            codebook=data.codebook,
            vocabulary=data.vocabulary,
            text_drop=config["text_drop"],
        )


RECIPE = MMMRecipe()
