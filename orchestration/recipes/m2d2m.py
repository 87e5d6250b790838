"""M2D2M's training recipe (``m2d2m train-diffusion``): the discrete-diffusion denoiser on the
tokens of a VQ-VAE run, tokenizing first when its tokens are missing or stale."""

from __future__ import annotations

from pathlib import Path

from orchestration.recipes.token_data import export_model, prepare, token_training
from orchestration.errors import UserError
from orchestration.registry import model
from orchestration.train import fit, open_run

__all__ = ["prepare", "train"]  # a recipe: prepare (the tokens, shared by token models) and train

NAME = "m2d2m"


def train(config_name: str = "demo", overrides: list[str] | None = None, resume: bool | str = False,
          extra_callbacks: list | None = None, join: Path | None = None, ray_train: bool = False) -> Path:
    """Train the denoiser; returns the run directory (with ``model.pt`` on success). ``join``: a run
    another process opened (its config is used, ``config_name`` and ``overrides`` are not);
    ``ray_train``: this process is a Ray Train worker."""
    import lightning.pytorch as pl

    from m2d2m.generators.m2d2m_checkpoint import sampling_defaults, save_m2d2m
    from training.callbacks import TokenSamplePreview
    from training.m2d2m_module import M2D2MModule

    entry = model(NAME)
    run_dir, config, run_id = open_run(entry.stage, entry.configs, config_name, overrides or [], resume, join)
    try:  # before hours of training, not at its end
        sampling = sampling_defaults(config.get("sampling") or {}, int(config["diffusion"]["steps"]))
    except ValueError as error:
        raise UserError(str(error)) from error
    data = token_training(config, lambda caption: caption["actions"] or [caption["text"]])
    pl.seed_everything(config["seed"], workers=True, verbose=False)
    module = M2D2MModule(config["denoiser"], config["text"], config["diffusion"], config["optim"],
                         codebook=data.codebook, vocabulary=data.vocabulary)
    preview = config["preview"]
    fitted = fit(entry.stage, config, run_dir, run_id, resume, module, data.datamodule, "val/loss",
                 [TokenSamplePreview(run_dir / "previews", data.vq_path, preview["prompts"], preview["seconds"],
                                     every=config["trainer"]["gif_every"], guidance=preview["guidance"]),
                  *(extra_callbacks or [])], ray_train=ray_train)
    if not fitted.primary:
        return run_dir
    export_model(run_dir, fitted, config, data, run_dir / entry.model_file,
                 lambda path, lengths, extra: save_m2d2m(path, module.denoiser, module.text_encoder,
                                                              config["text"], module.schedule.config,
                                                              module.codebook, data.vq_path, lengths, extra,
                                                              sampling), module)
    return run_dir
