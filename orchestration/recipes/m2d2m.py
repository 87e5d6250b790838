"""M2D2M's training recipe (``m2d2m train-diffusion``): the discrete-diffusion denoiser on the
tokens of a VQ-VAE run, tokenizing first when its tokens are missing or stale."""

from __future__ import annotations

from typing import Any, ClassVar

from m2d2m.generators.m2d2m.checkpoint import M2D2M_FORMAT, sampling_defaults
from m2d2m.generators.m2d2m.options import MODEL_DEFAULTS
from orchestration.recipes.token_data import TokenRecipe, TokenTraining, token_training


def _sampling(config: dict[str, Any]) -> dict[str, Any]:
    """The config's sampling defaults, checked against its diffusion steps (ValueError)."""
    return sampling_defaults(config.get("sampling") or {}, int(config["diffusion"]["steps"]))


class M2D2MRecipe(TokenRecipe):
    model_format = M2D2M_FORMAT
    # a knob the sampling section leaves out samples as the preset says (paper-demo.yaml: guidance)
    optional: ClassVar[frozenset[str]] = frozenset(f"sampling.{knob}" for knob in MODEL_DEFAULTS)

    def check(self, config: dict[str, Any]) -> None:
        import torch

        from m2d2m.processes.discrete_diffusion import TransitionSchedule

        # the diffusion section's schedule built over a two-code stand-in codebook: its settings
        # are refused now, not after tokenizing the dataset that brings the real codebook
        try:
            TransitionSchedule.from_config(torch.eye(2), config["diffusion"])
        except ValueError as error:
            raise ValueError(f"diffusion: {error}") from error
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

    def parts(self, config: dict[str, Any], data: TokenTraining) -> dict[str, Any]:
        return {**data.model_parts(), "sampling": _sampling(config)}


RECIPE = M2D2MRecipe()
