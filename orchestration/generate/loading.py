"""A model's generator loaded from its model file: ``latest``, a file, a run directory or name,
or an MLflow run id, found the way every stage's files are (:func:`orchestration.runs.run_file`).
"""

from __future__ import annotations

from pathlib import Path

import torch

from m2d2m.generators.protocol import MotionGenerator
from orchestration.errors import UserError
from orchestration.registry import DEFAULT_MODEL, model
from orchestration.runs import run_file


def resolve_model_file(name: str, reference: str | Path, dataset: str) -> Path:
    """The model file of model ``name`` from a path, a run directory, ``latest``, a run name or an
    MLflow run id."""
    entry = model(name)
    return run_file(reference, dataset, entry.stage, entry.model_file, f"make {entry.train_verb}")


def load_generator(
    name: str = DEFAULT_MODEL, reference: str | Path = "latest", dataset: str = "synthetic", device: str = "auto"
) -> MotionGenerator:
    """Model ``name``'s generator from its model file (on a GPU when there is one, by default)."""
    path = resolve_model_file(name, reference, dataset)
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    try:
        return model(name).load("generator").load(path, device)
    except (FileNotFoundError, ValueError, KeyError) as error:
        raise UserError(str(error)) from error
