"""M2D2M's training recipe (``m2d2m train-diffusion``): the discrete-diffusion denoiser on the
tokens of a VQ-VAE run, tokenizing first when its tokens are missing or stale."""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

from orchestration.recipes.token_data import TokenRecipe, TokenTraining, token_training


def _sampling(config: dict[str, Any]) -> dict[str, Any]:
    """The config's sampling defaults, checked against its diffusion steps (ValueError)."""
    from m2d2m.generators.m2d2m_checkpoint import sampling_defaults

    return sampling_defaults(config.get("sampling") or {}, int(config["diffusion"]["steps"]))


class M2D2MRecipe(TokenRecipe):
    renamed: ClassVar[dict[str, str]] = {"denoiser.condition_drop": "text_drop"}

    def check(self, config: dict[str, Any]) -> None:
        _sampling(config)

    def data(self, config: dict[str, Any]) -> TokenTraining:
        return token_training(config, lambda caption: caption["actions"] or [caption["text"]])

    def module(self, config: dict[str, Any], data: TokenTraining) -> Any:
        from training.m2d2m_module import M2D2MModule

        return M2D2MModule(
            config["denoiser"],
            config["text"],
            config["diffusion"],
            config["optim"],
            codebook=data.codebook,
            vocabulary=data.vocabulary,
            text_drop=config["text_drop"],
        )

    def save(
        self, path: Path, module: Any, config: dict[str, Any], data: TokenTraining, lengths: Any, extra: dict[str, Any]
    ) -> Path:
        from m2d2m.generators.m2d2m_checkpoint import save_m2d2m

        return save_m2d2m(
            path,
            module.denoiser,
            module.text_encoder,
            config["text"],
            module.schedule.config,
            module.codebook,
            data.vq_path,
            lengths,
            extra,
            _sampling(config),
        )


RECIPE = M2D2MRecipe()
