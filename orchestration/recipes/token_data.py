"""What the training recipes of models over VQ tokens (M2D2M, MMM, MMM's upper-body editor) share:
the VQ-VAE a run names, its token set (made first when missing or stale), the DataModule over it,
the vocabulary of a learned text encoder, and the model file a finished run exports with what it
records."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from m2d2m.motion.body_parts import FULL, LOWER, UPPER
from orchestration.errors import UserError
from orchestration.train import ensure_tokens, export_snapshots, finish, validation_interval, vq_file


def prepare(config: dict[str, Any]) -> None:
    """The tokens every trial of a training sweep reads, made once by the sweep's driver."""
    ensure_tokens(vq_file(config["vq"], config["dataset"]))


def prepare_body(config: dict[str, Any]) -> None:
    """:func:`prepare` for the upper-body editor: the tokens of both part tokenizers."""
    for part in (UPPER, LOWER):
        ensure_tokens(vq_file(config["vq"][part], config["dataset"], part))


@dataclass
class TokenTraining:
    vq_path: Path
    codebook: torch.Tensor
    data_dir: Path
    tokens_dir: Path
    datamodule: Any  # training.data.TokenDataModule
    vocabulary: list[str] | None  # for a learned text encoder; None for CLIP

    def records(self) -> dict[str, str]:
        """Where the run's tokenizer and tokens are, for its run.json."""
        return {"vq": str(self.vq_path.resolve()), "tokens": str(self.tokens_dir.resolve())}


@dataclass
class BodyTokenTraining(TokenTraining):
    """The upper body's tokenizer and tokens in the inherited fields, the lower body's here."""

    lower_vq_path: Path
    lower_codebook: torch.Tensor
    lower_tokens_dir: Path

    def records(self) -> dict[str, str]:
        return {**super().records(), "lower_vq": str(self.lower_vq_path.resolve()),
                "lower_tokens": str(self.lower_tokens_dir.resolve())}


def _tokenizer(reference: str, dataset: str, part: str) -> tuple[Path, Any, Path, Path]:
    """A run's tokenizer of ``part``: its file, model, dataset and token set (made when missing)."""
    from m2d2m.networks.vqvae import load_vq

    path = vq_file(reference, dataset, part)
    try:
        vq, _, meta = load_vq(path)
        if meta["part"] != part:
            raise ValueError(f"{path} tokenizes the {meta['part']} body, not the {part} body"
                             + ("; whole-body models need a whole-body VQ-VAE (make train-vq)" if part == FULL else ""))
        return (path, vq, *ensure_tokens(path))
    except (FileNotFoundError, ValueError) as error:
        raise UserError(str(error)) from error


def caption_vocabulary(config: dict[str, Any], datamodule: Any, sentences: Callable[[dict[str, Any]], Iterable[str]]
                ) -> list[str] | None:
    """The words of a learned text encoder: those of ``sentences(caption)`` over the train captions."""
    from m2d2m.text import LearnedTextEncoder
    from training.data import clip_metas

    if config["text"]["kind"] != "learned":
        return None
    return LearnedTextEncoder.build_vocabulary(
        text for meta in clip_metas(datamodule.urls("train")) for caption in meta["captions"]
        for text in sentences(caption))


def _loader_settings(config: dict[str, Any], max_tokens: int | None) -> dict[str, Any]:
    data = config["data"]
    return {"batch_size": data["batch_size"], "num_workers": data["num_workers"],
            "steps_per_epoch": validation_interval(config["trainer"]),
            "max_tokens": data["max_tokens"] or max_tokens, "seed": config["seed"]}


def token_training(config: dict[str, Any], sentences: Callable[[dict[str, Any]], Iterable[str]],
                   max_tokens: int | None = None) -> TokenTraining:
    """The data side of a token model's run; ``sentences(caption)`` are the texts a caption
    conditions on (its action sentences for M2D2M, its text for MMM), whose words make the
    vocabulary of a learned text encoder; ``max_tokens`` crops longer token sequences when the
    config's ``data.max_tokens`` does not."""
    from training.data import TokenDataModule

    vq_path, vq, data_dir, tokens_dir = _tokenizer(config["vq"], config["dataset"], FULL)
    try:
        datamodule = TokenDataModule(tokens_dir, **_loader_settings(config, max_tokens))
    except (FileNotFoundError, ValueError) as error:
        raise UserError(str(error)) from error
    return TokenTraining(vq_path, vq.codebook, data_dir, tokens_dir, datamodule,
                         caption_vocabulary(config, datamodule, sentences))


def body_token_training(config: dict[str, Any], sentences: Callable[[dict[str, Any]], Iterable[str]],
                        max_tokens: int | None = None) -> BodyTokenTraining:
    """:func:`token_training` for the upper-body editor: ``config["vq"]`` names an ``upper`` and a
    ``lower`` part tokenizer of one dataset, whose token sets are read as pairs."""
    from training.data import BodyTokenDataModule

    vqs = config["vq"]
    if not isinstance(vqs, dict) or set(vqs) != {UPPER, LOWER}:
        raise UserError(f"vq must name an upper and a lower part tokenizer (vq.upper, vq.lower), got {vqs!r}")
    upper_path, upper, data_dir, upper_tokens = _tokenizer(vqs[UPPER], config["dataset"], UPPER)
    lower_path, lower, lower_data, lower_tokens = _tokenizer(vqs[LOWER], config["dataset"], LOWER)
    if data_dir.resolve() != lower_data.resolve():
        raise UserError(f"the part tokenizers were trained on different datasets ({data_dir}, {lower_data})")
    try:
        datamodule = BodyTokenDataModule(upper_tokens, lower_tokens, **_loader_settings(config, max_tokens))
    except (FileNotFoundError, ValueError) as error:
        raise UserError(str(error)) from error
    return BodyTokenTraining(upper_path, upper.codebook, data_dir, upper_tokens, datamodule,
                             caption_vocabulary(config, datamodule, sentences), lower_path, lower.codebook, lower_tokens)


def export_model(run_dir: Path, fitted: Any, config: dict[str, Any], data: TokenTraining, model_file: Path,
                 save: Callable[..., Path], module: Any) -> None:
    """Write the model file with ``save(model_file, lengths, extra=...)`` (the length prior of the
    training captions, and where the run, its data and tokens are) from ``module``'s weights, and
    one per snapshot of the run, then finish the run with it."""
    from training.data import length_prior

    datamodule = data.datamodule
    lengths = length_prior(datamodule.urls("train"), datamodule.frames_per_token)
    extra = {"run": run_dir.name, "mlflow_run_id": fitted.logger.run_id, "dataset": config["dataset"],
             "data_dir": str(data.data_dir.resolve()), **data.records(),
             "best_val_loss": float(fitted.checkpoints.best_model_score)}
    save(model_file, lengths, extra)
    export_snapshots(run_dir, module, lambda path: save(path, lengths, extra))
    finish(run_dir, fitted, [model_file, Path(fitted.checkpoints.best_model_path), fitted.last,
                             run_dir / "config.yaml"],
           model=str(model_file.resolve()), **data.records())
