"""The models the framework hosts, by name: where each one's generator, sampling knobs, training
recipe and configs live. Generation, evaluation, sweeps and
the command line reach a model only through its entry here and its generator's protocol
(:mod:`m2d2m.generators.protocol`), so a new model is its own files and one entry
(docs/architecture.md, "How to add a model").

Entries name code as ``"module:attribute"`` and load it on first use: listing the models (the
command line does) imports neither torch nor Lightning. Models outside this repository register
themselves from a plugin module (:mod:`m2d2m.plugins`: named in ``M2D2M_PLUGINS``), imported
on first use; the same modules may register metrics and corpora. Ray trials and workers import
the same plugins as their driver (:func:`m2d2m.plugins.plugins_for_workers`).
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from m2d2m.plugins import import_plugins
from orchestration.errors import UserError


@dataclass(frozen=True)
class ModelEntry:
    """One model. ``stage`` names its run directories (``runs/<dataset>/<stage>/``) and MLflow
    experiments."""

    name: str
    summary: str  # one line for the command line's help
    stage: str
    configs: str  # configs/<configs>/<name>.yaml
    train_verb: str  # `m2d2m <train_verb>`, `make <train_verb>`
    model_file: str  # what a finished run directory holds
    generator: str  # a MotionGenerator subclass with ``load(path, device)``
    recipe: str  # an orchestration.recipe.Recipe: how its config becomes data, a LightningModule, a model file
    # its knobs, methods and presets (an m2d2m.generators.options.Sampling, the generator's own),
    # in a module that loads without torch: the command line's help and shortcuts come from it
    sampling: str
    shortcuts: tuple[str, ...] = ()  # knobs that get their own flag (``--eta`` for ``--option eta=``)

    def load(self, part: str) -> Any:
        """The object a ``"module:attribute"`` field names (``part``: generator, recipe, sampling)."""
        module_name, _, attribute = getattr(self, part).partition(":")
        module = importlib.import_module(module_name)
        return getattr(module, attribute) if attribute else module


_MODELS: dict[str, ModelEntry] = {}
DEFAULT_MODEL = "m2d2m"  # what --model means when not given: the project's own


def register(entry: ModelEntry) -> ModelEntry:
    """Add (or replace) a model; a plugin module calls this when it is imported."""
    _MODELS[entry.name] = entry
    return entry


register(
    ModelEntry(
        name="m2d2m",
        summary="M2D2M: discrete diffusion over VQ tokens, β(t, d), Two-Phase Sampling",
        stage="m2d2m",
        configs="m2d2m",
        train_verb="train-diffusion",
        model_file="model.pt",
        generator="m2d2m.generators.m2d2m.generator:M2D2MGenerator",
        recipe="orchestration.recipes.m2d2m:RECIPE",
        sampling="m2d2m.generators.m2d2m.options:SAMPLING",
        shortcuts=("ts", "eta", "guidance", "truncation"),
    )
)

register(
    ModelEntry(
        name="mmm",
        summary="MMM: a masked motion model over VQ tokens, parallel decoding, transition tokens",
        stage="mmm",
        configs="mmm",
        train_verb="train-mmm",
        model_file="model.pt",
        generator="m2d2m.generators.mmm.generator:MMMGenerator",
        recipe="orchestration.recipes.mmm:RECIPE",
        sampling="m2d2m.generators.mmm.options:SAMPLING",
    )
)

register(
    ModelEntry(
        name="mmm-body",
        summary="MMM's upper-body editor: new upper body from text, the lower body kept",
        stage="mmm-body",
        configs="mmm-body",
        train_verb="train-mmm-body",
        model_file="model.pt",
        generator="m2d2m.generators.mmm.body:BodyMMMGenerator",
        recipe="orchestration.recipes.mmm_body:RECIPE",
        sampling="m2d2m.generators.mmm.options:BODY_SAMPLING",
    )
)

register(
    ModelEntry(
        name="motiondiffuse",
        summary="MotionDiffuse: Gaussian diffusion on features, time-varied and body-part control",
        stage="motiondiffuse",
        configs="motiondiffuse",
        train_verb="train-motiondiffuse",
        model_file="model.pt",
        generator="m2d2m.generators.motiondiffuse.generator:MotionDiffuseGenerator",
        recipe="orchestration.recipes.motiondiffuse:RECIPE",
        sampling="m2d2m.generators.motiondiffuse.options:SAMPLING",
    )
)


def load_plugins(modules: list[str] | None = None, paths: Sequence[str] = ()) -> list[str]:
    """:func:`m2d2m.plugins.import_plugins`, a plugin that cannot be imported a one-line error."""
    try:
        return import_plugins(modules, paths)
    except ImportError as error:
        raise UserError(str(error)) from error


def models() -> dict[str, ModelEntry]:
    """Every registered model, plugins included."""
    load_plugins()
    return dict(_MODELS)


def methods_of_models() -> str:
    """Every model's multi-action methods, as declared, for the command line's help:
    ``m2d2m: tps, independent, ...; mmm: ...``."""
    return "; ".join(f"{name}: {', '.join(entry.load('sampling').methods)}" for name, entry in models().items())


def model(name: str) -> ModelEntry:
    """The entry of ``name``, or a one-line error listing the models there are."""
    known = models()
    if name not in known:
        raise UserError(f"unknown model {name!r}; choose one of {', '.join(known)}")
    return known[name]
