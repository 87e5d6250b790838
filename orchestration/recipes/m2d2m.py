"""M2D2M's training recipe (``m2d2m train-diffusion``): the discrete-diffusion denoiser on the
tokens of a VQ-VAE run, tokenizing first when its tokens are missing or stale."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from orchestration.errors import UserError
from orchestration.registry import model
from orchestration.train import ensure_tokens, finish, fit, open_run, validation_interval, vq_file

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
    from m2d2m.networks.vqvae import load_vq
    from m2d2m.text import LearnedTextEncoder
    from training.callbacks import SamplePreview
    from training.data import TokenDataModule, clip_metas, length_prior
    from training.m2d2m_module import M2D2MModule

    entry = model(NAME)
    run_dir, config, run_id = open_run(entry.stage, entry.configs, config_name, overrides or [], resume, join)
    vq_path = vq_file(config["vq"], config["dataset"])
    try:
        vq, _, _ = load_vq(vq_path)
        data_dir, tokens_dir = ensure_tokens(vq_path)
        data, trainer_cfg = config["data"], config["trainer"]
        datamodule = TokenDataModule(tokens_dir, batch_size=data["batch_size"], num_workers=data["num_workers"],
                                     steps_per_epoch=validation_interval(trainer_cfg), max_tokens=data["max_tokens"],
                                     seed=config["seed"])
    except (FileNotFoundError, ValueError) as error:
        raise UserError(str(error)) from error
    vocabulary = None
    if config["text"]["kind"] == "learned":
        sentences = (action for meta in clip_metas(datamodule.urls("train")) for caption in meta["captions"]
                     for action in (caption["actions"] or [caption["text"]]))
        vocabulary = LearnedTextEncoder.build_vocabulary(sentences)
    pl.seed_everything(config["seed"], workers=True, verbose=False)
    module = M2D2MModule(config["denoiser"], config["text"], config["diffusion"], config["optim"],
                         codebook=vq.codebook, vocabulary=vocabulary)
    preview = config["preview"]
    fitted = fit(entry.stage, config, run_dir, run_id, resume, module, datamodule, "val/loss",
                 [SamplePreview(run_dir / "previews", vq_path, preview["prompts"], preview["seconds"],
                                guidance=preview["guidance"], every=trainer_cfg["gif_every"]),
                  *(extra_callbacks or [])], ray_train=ray_train)
    if not fitted.primary:
        return run_dir
    lengths = length_prior(datamodule.urls("train"), datamodule.frames_per_token)
    model_file = run_dir / entry.model_file
    save_checkpoint(model_file, module.denoiser, module.text_encoder, config["text"], module.schedule.config,
                    module.codebook, vq_path, lengths,
                    extra={"run": run_dir.name, "mlflow_run_id": fitted.logger.run_id, "dataset": config["dataset"],
                           "data_dir": str(data_dir.resolve()), "tokens": str(tokens_dir.resolve()),
                           "best_val_loss": float(fitted.checkpoints.best_model_score)})
    finish(run_dir, fitted, [model_file, Path(fitted.checkpoints.best_model_path), fitted.last,
                             run_dir / "config.yaml"],
           model=str(model_file.resolve()), vq=str(vq_path.resolve()), tokens=str(tokens_dir.resolve()))
    return run_dir
