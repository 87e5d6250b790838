"""``m2d2m models``: what each trained model of a dataset (or of every dataset) can be asked for, before anyone asks —
the actions it was shown, how long an action may be, the words it reads, its methods and the
defaults a generation with nothing set samples with (issue 38: the demo model's 18 actions and
0.2–10 s per action were shown nowhere until an error)."""

from __future__ import annotations

from typing import Any

from m2d2m.generators.options import MULTI
from m2d2m.generators.protocol import MotionGenerator
from m2d2m.layout import relative_to_project
from orchestration.errors import NotInProject
from orchestration.registry import models
from orchestration.runs import RUNS_ROOT
from orchestration.web.catalog import finished_runs, load_run


def trained_datasets() -> list[str]:
    """The datasets (folders of ``runs/``) holding a finished run of a registered model, by name."""
    if not RUNS_ROOT.is_dir():
        return []
    return sorted(
        folder.name
        for folder in RUNS_ROOT.iterdir()
        if folder.is_dir() and any(finished_runs(entry, folder.name) for entry in models().values())
    )


def also_trained(dataset: str) -> str | None:
    """The line `m2d2m serve --dataset <dataset>` says about the other datasets' trained models
    (the real-motion ones beside the demo's), or None when there are none."""
    others = [name for name in trained_datasets() if name != dataset]
    if not others:
        return None
    serving = ", ".join(f"{name} (--dataset {name})" for name in others)
    return f"serving the models of dataset {dataset}; models of {serving} are trained too"


def summary_lines(dataset: str | None = None) -> list[str]:
    """The summary of every registered model with a finished run of ``dataset``: its latest run's;
    of every dataset's, under a line naming the dataset and how to serve it, when none is named
    (a real-motion model beside the demo's is then found without knowing its dataset's name)."""
    if dataset is not None:
        return _dataset_lines(dataset)
    datasets = trained_datasets()
    if not datasets:
        raise NotInProject("no model has finished training; run `make demo` (or `make train-diffusion`) first")
    lines: list[str] = []
    for name in datasets:
        lines += [f"dataset {name} (serve it: m2d2m serve --dataset {name})"]
        lines += [f"  {line}" for line in _dataset_lines(name)]
    return lines


def _dataset_lines(dataset: str) -> list[str]:
    lines: list[str] = []
    for entry in models().values():
        runs = finished_runs(entry, dataset)
        if not runs:
            continue
        generator = load_run(entry, runs[0])
        others = f", {len(runs) - 1} older" if len(runs) > 1 else ""
        lines += [
            f"{entry.name}: {entry.summary}",
            f"  run {runs[0].name}{others} ({relative_to_project(runs[0].model_file)})",
        ]
        lines += [f"  {line}" for line in _knowledge(generator)]
    if not lines:
        raise NotInProject(f"no model of dataset {dataset!r} has finished training; run `make train-diffusion` first")
    return lines


def _knowledge(generator: MotionGenerator) -> list[str]:
    from pipelines.language import action_verbs

    verbs = action_verbs(generator.known_verbs)
    shortest, longest = generator.frame_step / generator.fps, generator.longest_frames / generator.fps
    encoder = generator.text_encoder
    reads = (
        "what its model file does not say"
        if encoder is None
        else "any English"
        if encoder.reads_any_word
        else "only the words of its training captions (others are warned about)"
    )
    defaults: dict[str, Any] = generator.sampling.defaults(MULTI, generator.model_defaults)
    method = defaults.pop("method")
    lines = [
        f"actions it was shown alone ({len(verbs)}): {', '.join(verbs) or 'none recorded'}",
        f"each action {shortest:g}–{longest:g} s, at {generator.fps:g} frames per second; it reads {reads}",
    ]
    if generator.needs_keep is not None:
        lines.append(f"an editor: {generator.needs_keep}")
    lines += [
        f"methods: {', '.join(m + (' (default)' if m == method else '') for m in generator.sampling.methods)}",
        "defaults: " + ", ".join(f"{name} {'none' if value is None else value}" for name, value in defaults.items()),
    ]
    return lines
