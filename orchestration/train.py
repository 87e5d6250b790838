"""Training runs: a config in, a run directory, an MLflow run and a model file out.

``train_vq`` is ``m2d2m train-vq``: it resolves the config, opens (or, with ``resume``, reopens)
the run directory and the MLflow run, trains with Lightning, and on success exports ``vq.pt`` —
the plain model file later stages read — and marks the run as the stage's ``latest``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch
import yaml

from m2d2m.layout import VQ_FILE
from orchestration.config import flatten, load_config
from orchestration.errors import UserError
from orchestration.runs import mark_latest, new_run_dir, newest_run, read_run_info, write_run_info
from orchestration.tracking import artifact_location, ensure_experiment, experiment_name, tracking_uri

VQ_STAGE = "vq"


def _precision(setting: str) -> str:
    """``auto``: bf16 mixed precision where a GPU supports it, full precision on a CPU."""
    if setting != "auto":
        return setting
    return "bf16-mixed" if torch.cuda.is_available() and torch.cuda.is_bf16_supported() else "32-true"


def _open_run(stage: str, config_name: str, overrides: list[str], resume: bool) -> tuple[Path, dict[str, Any], str | None]:
    """The run directory, its config and its MLflow run id (None for a new run)."""
    config = load_config(stage, config_name, overrides)
    if not resume:
        return new_run_dir(config["dataset"], stage), config, None
    if overrides:
        raise UserError("--set cannot change a run being resumed; resume as it was, or start a new run")
    run_dir = newest_run(config["dataset"], stage)
    info = read_run_info(run_dir)
    if info.get("status") == "finished":
        raise UserError(f"{run_dir} already finished; start a new run instead of --resume")
    return run_dir, info["config"], info.get("mlflow_run_id")


def _mlflow_logger(dataset: str, stage: str, run_dir: Path, run_id: str | None):
    from lightning.pytorch.loggers import MLFlowLogger

    experiment = experiment_name(dataset, stage)
    ensure_experiment(experiment)
    return MLFlowLogger(
        experiment_name=experiment,
        tracking_uri=tracking_uri(),
        run_name=run_dir.name,
        run_id=run_id,
        tags={"dataset": dataset, "stage": stage, "run_dir": str(run_dir.resolve())},
        artifact_location=artifact_location(experiment),
    )


def train_vq(config_name: str = "demo", overrides: list[str] | None = None, resume: bool = False,
             extra_callbacks: list | None = None) -> Path:
    """Train the motion VQ-VAE; returns the run directory (with ``vq.pt`` on success).
    ``extra_callbacks`` join the trainer's (a sweep's reporting callback, for instance)."""
    import lightning.pytorch as pl
    from lightning.pytorch.callbacks import LearningRateMonitor, ModelCheckpoint

    from m2d2m.vqvae import save_vq
    from training.callbacks import ReconstructionPreview
    from training.data import MotionWindowDataModule
    from training.vq_module import NonFiniteLossError, VQVAEModule

    run_dir, config, run_id = _open_run(VQ_STAGE, config_name, overrides or [], resume)
    data, trainer_cfg = config["data"], config["trainer"]
    try:
        datamodule = MotionWindowDataModule(
            data["dir"], window=data["window"], batch_size=data["batch_size"], num_workers=data["num_workers"],
            steps_per_epoch=trainer_cfg["val_every_steps"], seed=config["seed"],
        )
    except (FileNotFoundError, ValueError) as error:
        raise UserError(str(error)) from error
    pl.seed_everything(config["seed"], workers=True, verbose=False)
    module = VQVAEModule(config["model"], config["optim"], config["loss"], datamodule.feature_dim, datamodule.skeleton)
    module.set_normalizer(datamodule.normalizer)

    logger = _mlflow_logger(config["dataset"], VQ_STAGE, run_dir, run_id)
    (run_dir / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False), encoding="utf-8")
    write_run_info(run_dir, stage=VQ_STAGE, dataset=config["dataset"], status="running",
                   mlflow_run_id=logger.run_id, config=config)
    if run_id is None:
        logger.log_hyperparams(flatten(config))

    checkpoints = ModelCheckpoint(dirpath=run_dir / "checkpoints", filename="best", monitor="val/recon_loss",
                                  mode="min", save_last=True, save_top_k=1)
    trainer = pl.Trainer(
        max_steps=trainer_cfg["max_steps"],
        accelerator=trainer_cfg["accelerator"],
        devices=trainer_cfg["devices"],
        precision=_precision(trainer_cfg["precision"]),
        logger=logger,
        callbacks=[checkpoints, LearningRateMonitor(logging_interval="step"),
                   ReconstructionPreview(run_dir / "previews", every=trainer_cfg["gif_every"]),
                   *(extra_callbacks or [])],
        gradient_clip_val=config["optim"]["grad_clip"],
        limit_val_batches=trainer_cfg["val_batches"],
        log_every_n_steps=min(50, trainer_cfg["val_every_steps"]),
        default_root_dir=run_dir,
        num_sanity_val_steps=0,
    )
    last = run_dir / "checkpoints" / "last.ckpt"
    try:
        trainer.fit(module, datamodule=datamodule, ckpt_path=last if resume and last.exists() else None)
    except NonFiniteLossError as error:
        write_run_info(run_dir, status="failed", error=str(error))
        raise UserError(f"{error}; training stopped. The last good checkpoint is {last} "
                        "(lower optim.lr or set optim.grad_clip, then start a new run)") from error

    best = torch.load(checkpoints.best_model_path, map_location="cpu", weights_only=True)
    module.load_state_dict(best["state_dict"])
    final = {name: float(value) for name, value in trainer.callback_metrics.items() if name.startswith("val/")}
    save_vq(run_dir / VQ_FILE, module.model, datamodule.normalizer, datamodule.skeleton,
            extra={"run": run_dir.name, "mlflow_run_id": logger.run_id, "dataset": config["dataset"],
                   "data_dir": str(Path(data["dir"]).resolve()),
                   "best_val_recon_loss": float(checkpoints.best_model_score)})
    for path in (run_dir / VQ_FILE, Path(checkpoints.best_model_path), last, run_dir / "config.yaml",
                 Path(data["dir"]) / "stats.npz"):
        logger.experiment.log_artifact(logger.run_id, str(path), artifact_path="model")
    write_run_info(run_dir, status="finished", final_validation=final, vq=str((run_dir / VQ_FILE).resolve()))
    mark_latest(run_dir)
    return run_dir
