"""What the training recipes of models over VQ tokens (M2D2M, MMM) share: the VQ-VAE a run names,
its token set (made first when missing or stale), the DataModule over it, the vocabulary of a
learned text encoder, and the model file a finished run exports with what it records."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from orchestration.errors import UserError
from orchestration.train import ensure_tokens, finish, validation_interval, vq_file


def prepare(config: dict[str, Any]) -> None:
    """The tokens every trial of a training sweep reads, made once by the sweep's driver."""
    ensure_tokens(vq_file(config["vq"], config["dataset"]))


@dataclass
class TokenTraining:
    vq_path: Path
    codebook: torch.Tensor
    data_dir: Path
    tokens_dir: Path
    datamodule: Any  # training.data.TokenDataModule
    vocabulary: list[str] | None  # for a learned text encoder; None for CLIP


def token_training(config: dict[str, Any], sentences: Callable[[dict[str, Any]], Iterable[str]],
                   max_tokens: int | None = None) -> TokenTraining:
    """The data side of a token model's run; ``sentences(caption)`` are the texts a caption
    conditions on (its action sentences for M2D2M, its text for MMM), whose words make the
    vocabulary of a learned text encoder; ``max_tokens`` crops longer token sequences when the
    config's ``data.max_tokens`` does not."""
    from m2d2m.networks.vqvae import load_vq
    from m2d2m.text import LearnedTextEncoder
    from training.data import TokenDataModule, clip_metas

    vq_path = vq_file(config["vq"], config["dataset"])
    try:
        vq, _, _ = load_vq(vq_path)
        data_dir, tokens_dir = ensure_tokens(vq_path)
        data = config["data"]
        datamodule = TokenDataModule(tokens_dir, batch_size=data["batch_size"], num_workers=data["num_workers"],
                                     steps_per_epoch=validation_interval(config["trainer"]),
                                     max_tokens=data["max_tokens"] or max_tokens, seed=config["seed"])
    except (FileNotFoundError, ValueError) as error:
        raise UserError(str(error)) from error
    vocabulary = None
    if config["text"]["kind"] == "learned":
        vocabulary = LearnedTextEncoder.build_vocabulary(
            text for meta in clip_metas(datamodule.urls("train")) for caption in meta["captions"]
            for text in sentences(caption))
    return TokenTraining(vq_path, vq.codebook, data_dir, tokens_dir, datamodule, vocabulary)


def export_model(run_dir: Path, fitted: Any, config: dict[str, Any], data: TokenTraining, model_file: Path,
                 save: Callable[..., Path]) -> None:
    """Write the model file with ``save(model_file, lengths, extra=...)`` (the length prior of the
    training captions, and where the run, its data and tokens are), then finish the run with it."""
    from training.data import length_prior

    datamodule = data.datamodule
    save(model_file, length_prior(datamodule.urls("train"), datamodule.frames_per_token),
         extra={"run": run_dir.name, "mlflow_run_id": fitted.logger.run_id, "dataset": config["dataset"],
                "data_dir": str(data.data_dir.resolve()), "tokens": str(data.tokens_dir.resolve()),
                "best_val_loss": float(fitted.checkpoints.best_model_score)})
    finish(run_dir, fitted, [model_file, Path(fitted.checkpoints.best_model_path), fitted.last,
                             run_dir / "config.yaml"],
           model=str(model_file.resolve()), vq=str(data.vq_path.resolve()), tokens=str(data.tokens_dir.resolve()))
