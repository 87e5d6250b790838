"""MMM's training recipe (``m2d2m train-mmm``): the masked transformer on the tokens of a VQ-VAE
run (the demo's by default, so the comparison with M2D2M isolates the generator), tokenizing
first when its tokens are missing or stale."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from orchestration.recipes.token_data import token_training
from orchestration.registry import model
from orchestration.train import ensure_tokens, finish, fit, open_run, vq_file

NAME = "mmm"


def prepare(config: dict[str, Any]) -> None:
    """The tokens every trial of a training sweep reads, made once by the sweep's driver."""
    ensure_tokens(vq_file(config["vq"], config["dataset"]))


def train(config_name: str = "demo", overrides: list[str] | None = None, resume: bool = False,
          extra_callbacks: list | None = None, join: Path | None = None, ray_train: bool = False) -> Path:
    """Train the masked transformer; returns the run directory (with ``model.pt`` on success).
    ``join`` and ``ray_train`` as for every recipe (orchestration/train.py)."""
    import lightning.pytorch as pl

    from m2d2m.generators.mmm_checkpoint import save_mmm
    from training.callbacks import SamplePreview
    from training.data import length_prior
    from training.mmm_module import MMMModule

    entry = model(NAME)
    run_dir, config, run_id = open_run(entry.stage, entry.configs, config_name, overrides or [], resume, join)
    data = token_training(config, lambda caption: [caption["text"]], max_tokens=config["transformer"]["max_tokens"])
    pl.seed_everything(config["seed"], workers=True, verbose=False)
    module = MMMModule(config["transformer"], config["text"], config["masking"], config["optim"],
                       codebook=data.codebook, vocabulary=data.vocabulary)
    preview = config["preview"]
    fitted = fit(entry.stage, config, run_dir, run_id, resume, module, data.datamodule, "val/loss",
                 [SamplePreview(run_dir / "previews", data.vq_path, preview["prompts"], preview["seconds"],
                                every=config["trainer"]["gif_every"]), *(extra_callbacks or [])], ray_train=ray_train)
    if not fitted.primary:
        return run_dir
    datamodule = data.datamodule
    lengths = length_prior(datamodule.urls("train"), datamodule.frames_per_token)
    model_file = run_dir / entry.model_file
    save_mmm(model_file, module.transformer, module.text_encoder, config["text"], data.vq_path, lengths,
             extra={"run": run_dir.name, "mlflow_run_id": fitted.logger.run_id, "dataset": config["dataset"],
                    "data_dir": str(data.data_dir.resolve()), "tokens": str(data.tokens_dir.resolve()),
                    "best_val_loss": float(fitted.checkpoints.best_model_score)})
    finish(run_dir, fitted, [model_file, Path(fitted.checkpoints.best_model_path), fitted.last,
                             run_dir / "config.yaml"],
           model=str(model_file.resolve()), vq=str(data.vq_path.resolve()), tokens=str(data.tokens_dir.resolve()))
    return run_dir
