"""Text to motion for people: `m2d2m generate` with any registered model.

:func:`load_generator` finds a model file (``latest``, a file, a run directory or name, an MLflow
run id) and loads the model's generator. In front of the generator's protocol call sit the
optional steps a person's prompts need: splitting free text into action sentences with the
dataset's tagger (as the corpus was split) and giving each action a length (the seconds asked
for, or the corpus's typical length for its verb). Each generation is recorded in MLflow.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from m2d2m.generators.protocol import MotionGenerator, keep_spans
from m2d2m.layout import NLP
from m2d2m.motion.clip import Motion
from orchestration.errors import UserError
from orchestration.registry import model
from orchestration.runs import run_file
from orchestration.tracking import experiment_name, tracked_run

GENERATE_STAGE = "generate"


def resolve_model_file(name: str, reference: str | Path, dataset: str) -> Path:
    """The model file of model ``name`` from a path, a run directory, ``latest``, a run name or an
    MLflow run id."""
    entry = model(name)
    return run_file(reference, dataset, entry.stage, entry.model_file, f"make {entry.train_verb}",
                    entry.legacy_stages)


def load_generator(name: str = "m2d2m", reference: str | Path = "latest", dataset: str = "synthetic",
                   device: str = "auto") -> MotionGenerator:
    """Model ``name``'s generator from its model file (on a GPU when there is one, by default)."""
    path = resolve_model_file(name, reference, dataset)
    if device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    try:
        return model(name).load("generator").load(path, device)
    except (FileNotFoundError, ValueError, KeyError) as error:
        raise UserError(str(error)) from error


class PromptPlanner:
    """Free-text prompts → action sentences and lengths in frames for one generator."""

    def __init__(self, generator: MotionGenerator) -> None:
        self.generator = generator
        self._tagger = None

    def seconds_range(self) -> tuple[float, float]:
        """The shortest and longest action the model supports: one step of its granularity, and
        the longest clip it was trained on."""
        return self.generator.frame_step / self.generator.fps, self.generator.longest_frames / self.generator.fps

    def split(self, prompt: str) -> tuple[list[str], list[str | None]]:
        """Action sentences and their verbs, split as the corpus's captions were."""
        from pipelines.language import decompose, load_tagger

        if self._tagger is None:
            data_dir = self.generator.data_dir
            try:
                self._tagger = load_tagger(data_dir / NLP if data_dir else None)
            except FileNotFoundError as error:
                raise UserError(f"{error} (or pass --no-split)") from error
        parts = decompose(prompt, tagger=self._tagger)
        verbs: list[str | None] = list(parts.verbs) if len(parts.verbs) == len(parts.actions) else [None] * len(parts.actions)
        return list(parts.actions), verbs

    def plan(self, prompts: Sequence[str], seconds: Sequence[float] | None = None,
             split: bool = True) -> tuple[list[str], list[int]]:
        """The action sentences and their lengths in frames for ``prompts``.

        With ``split`` a prompt with several verbs becomes several actions; a prompt's ``seconds``
        are then shared among its actions in proportion to their typical lengths. Without
        ``seconds`` every action gets the corpus's typical length for its verb.
        """
        prompts = list(prompts)
        if not prompts or any(not p.strip() for p in prompts):
            raise UserError("give at least one non-empty prompt")
        if seconds is not None and len(seconds) not in (1, len(prompts)):
            raise UserError(f"give one duration per prompt ({len(prompts)}) or one for all, not {len(seconds)}")
        lo, hi = self.seconds_range()
        step = self.generator.frame_step
        actions: list[str] = []
        frames: list[int] = []
        for index, prompt in enumerate(prompts):
            parts, verbs = self.split(prompt) if split else ([" ".join(prompt.lower().split())], [None])
            typical = [self.generator.typical_frames(verb) // step for verb in verbs]
            if seconds is not None:
                wanted = float(seconds[0] if len(seconds) == 1 else seconds[index])
                if not lo <= wanted <= hi * len(parts):
                    raise UserError(f"{wanted:g} s for {prompt!r} is outside what this model supports "
                                    f"({lo:g}–{hi:g} s per action)")
                typical = share(max(len(parts), round(wanted * self.generator.fps / step)), typical)
            actions.extend(parts)
            frames.extend(n * step for n in typical)
        return actions, frames


def share(total: int, typical: list[int]) -> list[int]:
    """Split ``total`` steps among actions in proportion to their typical lengths, at least one each."""
    weights = np.asarray(typical, dtype=np.float64)
    raw = np.maximum(1, np.floor(total * weights / weights.sum())).astype(int)
    raw[np.argmax(weights)] += total - int(raw.sum())
    return [int(n) for n in raw]


def generate(generator: MotionGenerator, prompts: str | Sequence[str], seconds: float | Sequence[float] | None = None,
             seed: int = 0, split: bool = True, **options: Any) -> Motion:
    """One motion doing ``prompts`` in order, with the generator's multi-action preset changed by
    ``options`` (for M2D2M: method, ts, eta, guidance, truncation)."""
    prompts = [prompts] if isinstance(prompts, str) else list(prompts)
    seconds = [seconds] if isinstance(seconds, (int, float)) else seconds
    actions, frames = PromptPlanner(generator).plan(prompts, seconds, split)
    try:
        return generator.generate([actions], [frames], generator.options(**options), [seed])[0]
    except ValueError as error:
        raise UserError(str(error)) from error


def edit(generator: MotionGenerator, motion: Motion, keep: Sequence[tuple[float, float]],
         actions: Sequence[str] | None = None, seed: int = 0, **options: Any) -> Motion:
    """Regenerate ``motion`` except the time spans ``keep`` (seconds): keep the start and the end
    to in-between, the start alone to complete a prefix. ``actions`` may replace the texts of the
    motion's actions, one each; every action keeps its frames."""
    actions = list(motion.actions if actions is None else actions)
    if len(actions) != len(motion.actions):
        raise UserError(f"give one text per action of the motion ({len(motion.actions)})")
    starts = [first for first, _ in motion.ranges] + [len(motion.features)]
    frames = [end - start for start, end in zip(starts[:-1], starts[1:])]
    try:
        return generator.generate([actions], [frames], generator.options(**options), [seed],
                                  [keep_spans(motion, keep)])[0]
    except ValueError as error:
        raise UserError(str(error)) from error


def log_generation(motion: Motion, prompts: Sequence[str], files: dict[str, Path], dataset: str) -> str:
    """Record one generation in MLflow (experiment ``<dataset>/generate``): prompts, actions,
    settings as params, the files as artifacts; returns the MLflow run id."""
    params = {**{k: str(v) for k, v in motion.settings.items()}, "prompts": " | ".join(prompts)[:500],
              "actions": " | ".join(motion.actions)[:500], "seconds": f"{motion.seconds:.2f}"}
    tags = {"dataset": dataset, "stage": GENERATE_STAGE, "model": str(motion.settings.get("model")),
            "method": str(motion.settings.get("method"))}
    with tracked_run(experiment_name(dataset, GENERATE_STAGE), tags=tags, params=params) as (client, run_id):
        for path in files.values():
            client.log_artifact(run_id, str(path), artifact_path="motion")
        features = files.get("npy")
        if features is not None and features.with_suffix(".json").exists():
            client.log_artifact(run_id, str(features.with_suffix(".json")), artifact_path="motion")
    return run_id
