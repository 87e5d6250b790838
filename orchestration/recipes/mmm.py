"""MMM's training recipe (``m2d2m train-mmm``): the masked transformer on the tokens of a VQ-VAE
run (the demo's by default, so the comparison with M2D2M isolates the generator), tokenizing
first when its tokens are missing or stale."""

from __future__ import annotations

from pathlib import Path

from orchestration.recipes.token_data import export_model, prepare, token_training
from orchestration.registry import model
from orchestration.train import fit, open_run

__all__ = ["prepare", "train"]  # a recipe: prepare (the tokens, shared by token models) and train

NAME = "mmm"


def train(config_name: str = "demo", overrides: list[str] | None = None, resume: bool | str = False,
          extra_callbacks: list | None = None, join: Path | None = None, ray_train: bool = False) -> Path:
    """Train the masked transformer; returns the run directory (with ``model.pt`` on success).
    ``join`` and ``ray_train`` as for every recipe (orchestration/train.py)."""
    import lightning.pytorch as pl

    from m2d2m.generators.mmm_checkpoint import save_mmm
    from training.callbacks import TokenSamplePreview
    from training.mmm_module import MMMModule

    entry = model(NAME)
    run_dir, config, run_id = open_run(entry.stage, entry.configs, config_name, overrides or [], resume, join)
    data = token_training(config, lambda caption: [caption["text"]], max_tokens=config["transformer"]["max_tokens"])
    pl.seed_everything(config["seed"], workers=True, verbose=False)
    module = MMMModule(config["transformer"], config["text"], config["masking"], config["optim"],
                       codebook=data.codebook, vocabulary=data.vocabulary)
    preview = config["preview"]
    fitted = fit(entry.stage, config, run_dir, run_id, resume, module, data.datamodule, "val/loss",
                 [TokenSamplePreview(run_dir / "previews", data.vq_path, preview["prompts"], preview["seconds"],
                                     every=config["trainer"]["gif_every"]), *(extra_callbacks or [])], ray_train=ray_train)
    if not fitted.primary:
        return run_dir
    export_model(run_dir, fitted, config, data, run_dir / entry.model_file,
                 lambda path, lengths, extra: save_mmm(path, module.transformer, module.text_encoder, config["text"],
                                                       data.vq_path, lengths, extra), module)
    return run_dir
