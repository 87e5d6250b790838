"""MotionDiffuse's training recipe (``m2d2m train-motiondiffuse``): the noise estimator on the
processed dataset's caption/motion pairs themselves, no tokens (Zhang et al. 2022, §3.3 and §4.1
"Implementation Details"). Pairs are drawn as for the evaluator (Guo et al.'s loader: a random
caption per clip, its segment, cut to a multiple of 4 frames)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from orchestration.errors import UserError
from orchestration.recipes.token_data import caption_vocabulary
from orchestration.registry import model
from orchestration.train import export_snapshots, finish, fit, open_run, validation_interval

NAME = "motiondiffuse"


def prepare(config: dict[str, Any]) -> None:
    """Nothing to make before parallel trials: they read the processed dataset as it is."""


def train(config_name: str = "demo", overrides: list[str] | None = None, resume: bool | str = False,
          extra_callbacks: list | None = None, join: Path | None = None, ray_train: bool = False) -> Path:
    """Train the noise estimator; returns the run directory (with ``model.pt`` on success).
    ``join`` and ``ray_train`` as for every recipe (orchestration/train.py)."""
    import lightning.pytorch as pl

    from m2d2m.generators.motiondiffuse_checkpoint import save_motiondiffuse
    from m2d2m.motion.skeleton import SKELETONS
    from training.callbacks import FeatureSamplePreview
    from training.data import length_prior
    from training.evaluator_module import CaptionMotionDataModule
    from training.motiondiffuse_module import MotionDiffuseModule

    entry = model(NAME)
    run_dir, config, run_id = open_run(entry.stage, entry.configs, config_name, overrides or [], resume, join)
    data = config["data"]
    try:
        datamodule = CaptionMotionDataModule(
            data["dir"], batch_size=data["batch_size"], num_workers=data["num_workers"],
            steps_per_epoch=validation_interval(config["trainer"]), min_frames=data["min_frames"],
            max_frames=data["max_frames"], seed=config["seed"])
        vocabulary = caption_vocabulary(config, datamodule, lambda caption: [caption["text"]])
    except (FileNotFoundError, ValueError) as error:
        raise UserError(str(error)) from error
    pl.seed_everything(config["seed"], workers=True, verbose=False)
    module = MotionDiffuseModule(config["network"], config["text"], config["diffusion"], config["optim"],
                                 datamodule.feature_dim, config["text_drop"], vocabulary)
    module.set_normalizer(datamodule.normalizer)
    preview = config["preview"]
    fitted = fit(entry.stage, config, run_dir, run_id, resume, module, datamodule, "val/loss",
                 [FeatureSamplePreview(run_dir / "previews", SKELETONS[datamodule.skeleton], preview["prompts"],
                                       preview["seconds"], every=config["trainer"]["gif_every"]),
                  *(extra_callbacks or [])], ray_train=ray_train)
    if not fitted.primary:
        return run_dir
    model_file = run_dir / entry.model_file
    data_dir = str(Path(data["dir"]).resolve())
    lengths = length_prior(datamodule.urls("train"), 1)
    extra = {"run": run_dir.name, "mlflow_run_id": fitted.logger.run_id, "dataset": config["dataset"],
             "data_dir": data_dir, "best_val_loss": float(fitted.checkpoints.best_model_score)}

    def save(path: Path) -> Path:
        return save_motiondiffuse(path, module.network, module.text_encoder, config["text"], config["diffusion"],
                                  datamodule.normalizer, datamodule.skeleton, lengths, extra=extra)

    save(model_file)
    export_snapshots(run_dir, module, save)
    finish(run_dir, fitted, [model_file, Path(fitted.checkpoints.best_model_path), fitted.last,
                             run_dir / "config.yaml"], model=str(model_file.resolve()), data=data_dir)
    return run_dir
