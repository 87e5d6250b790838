"""M2D2M's training recipe (``m2d2m train-diffusion``): the discrete-diffusion denoiser on the
tokens of a VQ-VAE run, tokenizing first when its tokens are missing or stale."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from orchestration.recipes.token_data import token_training
from orchestration.registry import model
from orchestration.train import ensure_tokens, finish, fit, open_run, vq_file

NAME = "m2d2m"


def prepare(config: dict[str, Any]) -> None:
    """The tokens every trial of a training sweep reads, made once by the sweep's driver."""
    ensure_tokens(vq_file(config["vq"], config["dataset"]))


def train(config_name: str = "demo", overrides: list[str] | None = None, resume: bool = False,
          extra_callbacks: list | None = None, join: Path | None = None, ray_train: bool = False) -> Path:
    """Train the denoiser; returns the run directory (with ``model.pt`` on success). ``join``: a run
    another process opened (its config is used, ``config_name`` and ``overrides`` are not);
    ``ray_train``: this process is a Ray Train worker."""
    import lightning.pytorch as pl

    from m2d2m.generators.m2d2m_checkpoint import save_checkpoint
    from training.callbacks import SamplePreview
    from training.data import length_prior
    from training.m2d2m_module import M2D2MModule

    entry = model(NAME)
    run_dir, config, run_id = open_run(entry.stage, entry.configs, config_name, overrides or [], resume, join)
    data = token_training(config, lambda caption: caption["actions"] or [caption["text"]])
    datamodule, vq_path, trainer_cfg = data.datamodule, data.vq_path, config["trainer"]
    pl.seed_everything(config["seed"], workers=True, verbose=False)
    module = M2D2MModule(config["denoiser"], config["text"], config["diffusion"], config["optim"],
                         codebook=data.codebook, vocabulary=data.vocabulary)
    preview = config["preview"]
    fitted = fit(entry.stage, config, run_dir, run_id, resume, module, datamodule, "val/loss",
                 [SamplePreview(run_dir / "previews", vq_path, preview["prompts"], preview["seconds"],
                                every=trainer_cfg["gif_every"], guidance=preview["guidance"]),
                  *(extra_callbacks or [])], ray_train=ray_train)
    if not fitted.primary:
        return run_dir
    lengths = length_prior(datamodule.urls("train"), datamodule.frames_per_token)
    model_file = run_dir / entry.model_file
    save_checkpoint(model_file, module.denoiser, module.text_encoder, config["text"], module.schedule.config,
                    module.codebook, vq_path, lengths,
                    extra={"run": run_dir.name, "mlflow_run_id": fitted.logger.run_id, "dataset": config["dataset"],
                           "data_dir": str(data.data_dir.resolve()), "tokens": str(data.tokens_dir.resolve()),
                           "best_val_loss": float(fitted.checkpoints.best_model_score)})
    finish(run_dir, fitted, [model_file, Path(fitted.checkpoints.best_model_path), fitted.last,
                             run_dir / "config.yaml"],
           model=str(model_file.resolve()), vq=str(vq_path.resolve()), tokens=str(data.tokens_dir.resolve()))
    return run_dir
