"""The training recipe of MMM's upper-body editor (``m2d2m train-mmm-body``): the body transformer
on the token pairs of two part tokenizers (``m2d2m train-vq --config mmm-upper-demo`` and
``mmm-lower-demo``), tokenizing first when their tokens are missing or stale."""

from __future__ import annotations

from pathlib import Path

from orchestration.recipes.token_data import body_token_training, export_model
from orchestration.recipes.token_data import prepare_body as prepare
from orchestration.registry import model
from orchestration.train import fit, open_run

__all__ = ["prepare", "train"]  # a recipe: prepare (both part tokenizers' tokens) and train

NAME = "mmm-body"


def train(config_name: str = "demo", overrides: list[str] | None = None, resume: bool | str = False,
          extra_callbacks: list | None = None, join: Path | None = None, ray_train: bool = False) -> Path:
    """Train the upper-body editor; returns the run directory (with ``model.pt`` on success).
    ``join`` and ``ray_train`` as for every recipe (orchestration/train.py). No sample previews:
    an edit needs a motion's lower body, which the module's validation loss already scores."""
    import lightning.pytorch as pl

    from m2d2m.generators.mmm_checkpoint import save_body_mmm
    from training.mmm_body_module import BodyMMMModule

    entry = model(NAME)
    run_dir, config, run_id = open_run(entry.stage, entry.configs, config_name, overrides or [], resume, join)
    data = body_token_training(config, lambda caption: [caption["text"]],
                               max_tokens=config["transformer"]["max_tokens"])
    pl.seed_everything(config["seed"], workers=True, verbose=False)
    module = BodyMMMModule(config["transformer"], config["text"], config["masking"], config["optim"],
                           codebook=data.codebook, lower_codebook=data.lower_codebook, vocabulary=data.vocabulary)
    fitted = fit(entry.stage, config, run_dir, run_id, resume, module, data.datamodule, "val/loss",
                 list(extra_callbacks or []), ray_train=ray_train)
    if not fitted.primary:
        return run_dir
    export_model(run_dir, fitted, config, data, run_dir / entry.model_file,
                 lambda path, lengths, extra: save_body_mmm(path, module.transformer, module.text_encoder,
                                                            config["text"], data.vq_path, data.lower_vq_path,
                                                            lengths, extra), module)
    return run_dir
