"""What the server offers: every registered model that generates from text and has a finished
run, with the knobs its ``<model>/options.py`` declares (:mod:`m2d2m.generators.options`), so the
page and the API are built from the same declarations as the command line.

Runs are found by listing the run folders (``runs/<dataset>/<stage>/``); a request names a run by
one of the listed names and is looked up among them, so no request value ever becomes a path.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from m2d2m.generators.options import MULTI, Sampling
from m2d2m.generators.protocol import MotionGenerator
from orchestration.errors import UserError
from orchestration.registry import ModelEntry, models
from orchestration.runs import LATEST, RUN_FILE, stage_dir

LATEST_RUN = "latest"  # what a request's run means when not given


class NotFound(UserError):
    """A model, run or generation the server does not have (HTTP 404)."""


@dataclass(frozen=True)
class Run:
    """A finished run of a model: its folder's name, its model file, and the sampling defaults its
    config chose (M2D2M's ``sampling`` section, which its model file carries too)."""

    name: str
    model_file: Path
    latest: bool
    started: float
    sampling: dict[str, Any]


def finished_runs(entry: ModelEntry, dataset: str) -> list[Run]:
    """The model's runs that finished with a model file, newest first."""
    runs: list[Run] = []
    folder = stage_dir(dataset, entry.stage)
    marker = folder / LATEST
    latest = marker.read_text(encoding="utf-8").strip() if marker.exists() else None
    for info_file in sorted(folder.glob(f"*/{RUN_FILE}")) if folder.is_dir() else ():
        info = json.loads(info_file.read_text(encoding="utf-8"))
        model_file = info_file.parent / entry.model_file
        if info.get("status") == "finished" and model_file.is_file():
            name = info_file.parent.name
            chosen = (info.get("config") or {}).get("sampling") or {}
            runs.append(Run(name, model_file, name == latest, float(info.get("started", 0.0)), chosen))
    runs.sort(key=lambda run: (not run.latest, -run.started))
    return runs


def load_run(entry: ModelEntry, run: Run, device: str = "cpu") -> MotionGenerator:
    """The generator of a finished run, or a one-line error naming the run that cannot be loaded."""
    try:
        return entry.load("generator").load(run.model_file, device)
    except (FileNotFoundError, ValueError, KeyError) as error:
        raise UserError(f"{entry.name} run {run.name} cannot be loaded: {error}") from error


def knob_table(sampling: Sampling, defaults: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The knobs as JSON: name, kind, optional, help, bounds, choices and the default."""
    return [{**asdict(knob), "default": defaults[knob.name]} for knob in sampling.knobs()]


class Catalog:
    """The served models and their loaded generators: each (model, run) is loaded once and kept."""

    def __init__(self, dataset: str, device: str = "cpu") -> None:
        self.dataset = dataset
        self.device = device
        self._generators: dict[tuple[str, str], MotionGenerator] = {}
        self._loading = threading.Lock()

    def entries(self) -> dict[str, ModelEntry]:
        """The registered models that generate from text alone (an editor needs a motion to edit)."""
        return {name: entry for name, entry in models().items() if entry.load("generator").needs_keep is None}

    def describe(self) -> list[dict[str, Any]]:
        """Every servable model with at least one finished run: ``GET /api/models``."""
        listed = []
        for name, entry in self.entries().items():
            runs = finished_runs(entry, self.dataset)
            if not runs:
                continue
            sampling: Sampling = entry.load("sampling")
            preset = sampling.defaults(MULTI, runs[0].sampling)  # the run a request gets by default
            listed.append(
                {
                    "name": name,
                    "summary": entry.summary,
                    "runs": [
                        {
                            "id": run.name,
                            "label": f"{run.name} (latest)" if run.latest else run.name,
                            "latest": run.latest,
                        }
                        for run in runs
                    ],
                    "methods": list(sampling.methods),
                    "method_labels": dict(sampling.method_labels),
                    "default_method": preset["method"],
                    "knobs": knob_table(sampling, preset),
                }
            )
        return listed

    def run(self, model: str, run: str) -> tuple[ModelEntry, Run]:
        """The entry and run a request names (``latest``: the newest finished one)."""
        entries = self.entries()
        if model not in entries:
            served = [name for name, entry in entries.items() if finished_runs(entry, self.dataset)]
            raise NotFound(f"unknown model {model!r}; this server has {', '.join(served) or 'none yet'}")
        runs = finished_runs(entries[model], self.dataset)
        if not runs:
            raise NotFound(f"{model} has no finished run for dataset {self.dataset!r}")
        chosen = runs[0] if run == LATEST_RUN else next((r for r in runs if r.name == run), None)
        if chosen is None:
            raise NotFound(f"{model} has no finished run {run!r}; GET /api/models lists them")
        return entries[model], chosen

    def generator(self, model: str, run: str) -> tuple[str, MotionGenerator]:
        """The run's name and its generator, loaded on first use and kept (a blocking call)."""
        entry, chosen = self.run(model, run)
        key = (model, chosen.name)
        with self._loading:
            if key not in self._generators:
                self._generators[key] = load_run(entry, chosen, self.device)
            return chosen.name, self._generators[key]

    def run_details(self, model: str, run: str) -> dict[str, Any]:
        """A run's own sampling defaults (a model file may carry its own) and the action lengths it
        supports: ``GET /api/models/{model}/runs/{run}``."""
        from pipelines.language import action_verbs

        name, generator = self.generator(model, run)
        defaults = generator.sampling.defaults(MULTI, generator.model_defaults)
        return {
            "model": model,
            "id": name,
            "fps": generator.fps,
            "seconds": [generator.frame_step / generator.fps, generator.longest_frames / generator.fps],
            "default_method": defaults["method"],
            "method_labels": dict(generator.sampling.method_labels),
            "knobs": knob_table(generator.sampling, defaults),
            "actions": action_verbs(generator.known_verbs),  # the page's examples: actions, not "do" or "back"
        }
