"""M2D2M's training recipe (``m2d2m train-diffusion``): the discrete-diffusion denoiser on the
tokens of a VQ-VAE run, tokenizing first when its tokens are missing or stale."""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar

from m2d2m.generators.m2d2m_options import MODEL_DEFAULTS
from orchestration.recipes.token_data import TokenRecipe, TokenTraining, token_training


def _sampling(config: dict[str, Any]) -> dict[str, Any]:
    """The config's sampling defaults, checked against its diffusion steps (ValueError)."""
    from m2d2m.generators.m2d2m_checkpoint import sampling_defaults

    return sampling_defaults(config.get("sampling") or {}, int(config["diffusion"]["steps"]))


class M2D2MRecipe(TokenRecipe):
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

    def save(self, path: Path, module: Any, config: dict[str, Any], data: TokenTraining, extra: dict[str, Any]) -> Path:
        from m2d2m.generators.m2d2m_checkpoint import save_m2d2m

        return save_m2d2m(
            path,
            module.denoiser,
            module.text_encoder,
            config["text"],
            module.schedule.config,
            module.codebook,
            data.vq_path,
            data.lengths,
            extra,
            _sampling(config),
        )


RECIPE = M2D2MRecipe()
