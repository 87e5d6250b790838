"""The data side of the training recipes of models over VQ tokens (M2D2M, MMM, MMM's upper-body
editor): the VQ-VAE a run names, its token set (made first when missing or stale), the DataModule
over it and the vocabulary of a learned text encoder."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from m2d2m.layout import relative_to_project
from m2d2m.motion.representation.body_parts import FULL, LOWER, UPPER
from orchestration.recipe import Recipe, TrainingData, caption_vocabulary
from orchestration.runs import vq_file
from orchestration.train import OpenedRun, validation_interval
from pipelines.token_sets import ensure_tokens


class TokenRecipe(Recipe):
    """A recipe over the tokens of one whole-body tokenizer (``config["vq"]``)."""

    def prepare(self, config: dict[str, Any]) -> None:
        """The tokens every trial of a training sweep reads, made once by the sweep's driver."""
        ensure_tokens(vq_file(config["vq"], config["dataset"]))

    def callbacks(self, run: OpenedRun, data: TrainingData) -> list:
        """Preview GIFs of ``preview.prompts``, sampled with the section's other keys as knobs
        (M2D2M's ``guidance``) and decoded by the run's VQ-VAE."""
        from training.callbacks import TokenSamplePreview

        preview = dict(run.config["preview"])
        prompts, seconds = preview.pop("prompts"), preview.pop("seconds")
        every = run.config["trainer"]["gif_every"]
        return [TokenSamplePreview(run.run_dir / "previews", data.vq_path, prompts, seconds, every=every, **preview)]


class BodyTokenRecipe(Recipe):
    """A recipe over the token pairs of an upper- and a lower-body tokenizer (``config["vq"]``)."""

    def prepare(self, config: dict[str, Any]) -> None:
        """The tokens of both part tokenizers, made once by a sweep's driver."""
        for part in (UPPER, LOWER):
            ensure_tokens(vq_file(config["vq"][part], config["dataset"], part))


@dataclass
class TokenTraining(TrainingData):
    """A token model's data: its DataModule is a ``training.data.tokens.TokenDataModule``."""

    vq_path: Path
    codebook: torch.Tensor
    tokens_dir: Path

    @property
    def frames_per_unit(self) -> int:
        return self.datamodule.frames_per_token

    def records(self) -> dict[str, str]:
        """Where the run's tokenizer and tokens are, for its run.json."""
        return {"vq": relative_to_project(self.vq_path), "tokens": relative_to_project(self.tokens_dir)}

    def model_parts(self) -> dict[str, Any]:
        """The tokenizer travels whole in the model file, to decode its tokens."""
        return {**super().model_parts(), "vq": self.vq_path}


@dataclass
class BodyTokenTraining(TokenTraining):
    """The upper body's tokenizer and tokens in the inherited fields, the lower body's here."""

    lower_vq_path: Path
    lower_codebook: torch.Tensor
    lower_tokens_dir: Path

    def records(self) -> dict[str, str]:
        return {
            **super().records(),
            "lower_vq": relative_to_project(self.lower_vq_path),
            "lower_tokens": relative_to_project(self.lower_tokens_dir),
        }

    def model_parts(self) -> dict[str, Any]:
        return {"lengths": self.lengths, "upper_vq": self.vq_path, "lower_vq": self.lower_vq_path}


def _tokenizer(reference: str, dataset: str, part: str) -> tuple[Path, Any, Path, Path]:
    """A run's tokenizer of ``part``: its file, model, dataset and token set (made when missing)."""
    from m2d2m.networks.vqvae import load_vq

    path = vq_file(reference, dataset, part)
    vq, _, meta = load_vq(path)
    if meta["part"] != part:
        raise ValueError(
            f"{path} tokenizes the {meta['part']} body, not the {part} body"
            + ("; whole-body models need a whole-body VQ-VAE (make train-vq)" if part == FULL else "")
        )
    return (path, vq, *ensure_tokens(path, meta["extra"]))


def _loader_settings(config: dict[str, Any], max_tokens: int | None) -> dict[str, Any]:
    data = config["data"]
    return {
        "batch_size": data["batch_size"],
        "num_workers": data["num_workers"],
        "steps_per_epoch": validation_interval(config["trainer"]),
        "max_tokens": data["max_tokens"] or max_tokens,
        "seed": config["seed"],
        "bucket": data.get("bucket", True),  # batches of similar lengths (docs/training.md, "Data loading")
    }


def token_training(
    config: dict[str, Any], sentences: Callable[[dict[str, Any]], Iterable[str]], max_tokens: int | None = None
) -> TokenTraining:
    """The data side of a token model's run; ``sentences(caption)`` are the texts a caption
    conditions on (its action sentences for M2D2M, its text for MMM), whose words make the
    vocabulary of a learned text encoder; ``max_tokens`` crops longer token sequences when the
    config's ``data.max_tokens`` does not."""
    from training.data.tokens import TokenDataModule

    vq_path, vq, data_dir, tokens_dir = _tokenizer(config["vq"], config["dataset"], FULL)
    datamodule = TokenDataModule(tokens_dir, **_loader_settings(config, max_tokens))
    return TokenTraining(
        datamodule, data_dir, caption_vocabulary(config, datamodule, sentences), vq_path, vq.codebook, tokens_dir
    )


def body_token_training(
    config: dict[str, Any], sentences: Callable[[dict[str, Any]], Iterable[str]], max_tokens: int | None = None
) -> BodyTokenTraining:
    """:func:`token_training` for the upper-body editor: ``config["vq"]`` names an ``upper`` and a
    ``lower`` part tokenizer of one dataset, whose token sets are read as pairs."""
    from training.data.tokens import BodyTokenDataModule

    vqs = config["vq"]
    if not isinstance(vqs, dict) or set(vqs) != {UPPER, LOWER}:
        raise ValueError(f"vq must name an upper and a lower part tokenizer (vq.upper, vq.lower), got {vqs!r}")
    upper_path, upper, data_dir, upper_tokens = _tokenizer(vqs[UPPER], config["dataset"], UPPER)
    lower_path, lower, lower_data, lower_tokens = _tokenizer(vqs[LOWER], config["dataset"], LOWER)
    if data_dir.resolve() != lower_data.resolve():
        raise ValueError(f"the part tokenizers were trained on different datasets ({data_dir}, {lower_data})")
    datamodule = BodyTokenDataModule(upper_tokens, lower_tokens, **_loader_settings(config, max_tokens))
    return BodyTokenTraining(
        datamodule,
        data_dir,
        caption_vocabulary(config, datamodule, sentences),
        upper_path,
        upper.codebook,
        upper_tokens,
        lower_path,
        lower.codebook,
        lower_tokens,
    )
