"""Sweeps with Ray Tune over any registered model: sampling-time (the knobs of its generator's
options on a trained model file, e.g. M2D2M's η, T_s, guidance) or training-time (overrides of its
training config, each trial trained then evaluated), every trial an MLflow child run of one
parent run per sweep.

``m2d2m sweep --config configs/sweep/<name>.yaml [--ray-address ADDR]``. The driver resolves every
file the trials read (relative to the project, as every record names them) and creates the MLflow
store, experiment and parent run before any trial starts (parallel trials would otherwise race on
SQLite's schema migration); trials are Tune function trainables that chdir to the project, so
relative paths (``runs/``, ``data/``) mean what they mean for the driver. The Tune experiment lives in ``runs/<dataset>/sweep/<name>/tune``:
re-running a sweep whose driver died restores it there (finished trials are kept, unfinished and
errored ones run again, and one whose evaluation finished before Tune heard of it gives that
evaluation's metrics instead of running again) instead of starting over. A restored Tune experiment keeps the parameters it
was started with, so a re-run whose config differs from the one recorded in ``sweep.json`` is refused
(``--name`` for a new sweep, ``--restart`` to replace it). A training sweep's keys are checked
against the model's training config before Ray starts. The parent run gets a summary table and, for
sampling sweeps, Jerk and FID against the space's last knob (for M2D2M's T_s per η: the paper's
Tables 5 and 7 as pictures). A parent run whose sweep fails ends FAILED.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from pathlib import Path
from typing import Any

from m2d2m.plugins import plugins_for_workers
from orchestration.config import apply_overrides, flatten, load_config
from orchestration.errors import UserError
from orchestration.registry import DEFAULT_MODEL, load_plugins, model
from orchestration.runs import enter_project, exclusive, stage_dir
from orchestration.tracking import client as tracking_client
from orchestration.tracking import experiment_name, finishing, start_run, tracking_uri

SWEEP_STAGE = "sweep"
KINDS = ("sampling", "training")
SWEEP_FILE = "sweep.json"
SUMMARY_MD, SUMMARY_JSON = "summary.md", "summary.json"
METRICS = ("jerk", "fid", "r_top3", "transition_fid")  # the summary's columns, per method


def summary_plot(knob: str) -> str:
    """The file name of a sampling sweep's picture of Jerk and FID against ``knob``."""
    return f"jerk-fid-vs-{knob}.png"


def trial_name(params: dict[str, Any]) -> str:
    """A child run's name from its parameters, e.g. ``eta=0.25 ts=90``."""
    return " ".join(f"{key}={value}" for key, value in params.items())


# the keys a sweep config may leave out: a sampling sweep of the default model, trials in-process
SWEEP_DEFAULTS = {"model": DEFAULT_MODEL, "train_config": None, "resources": {"workers": 0}}


def load_sweep_config(config_name: str, overrides: list[str]) -> dict[str, Any]:
    """``configs/sweep/<config_name>.yaml`` (or a path) with the overrides: its keys checked against
    the other sweep configs', its ``space`` holding knobs of the user's choosing."""
    return load_config(SWEEP_STAGE, config_name, overrides, SWEEP_DEFAULTS, free=("space",))


def _check(config: dict[str, Any]) -> None:
    if config["kind"] not in KINDS:
        raise UserError(f"sweep kind must be one of {', '.join(KINDS)}, got {config['kind']!r}")
    space = config["space"]
    if not space or any(not isinstance(values, list) or not values for values in space.values()):
        raise UserError("space: give every knob a non-empty list of values")
    knobs = model(config["model"]).load("sampling").names()
    if config["kind"] == "sampling" and set(space) - set(knobs):
        raise UserError(
            f"a sampling sweep of {config['model']} varies {', '.join(knobs)}; "
            f"unknown: {', '.join(sorted(set(space) - set(knobs)))}"
        )
    if config["search"] not in ("grid", "random"):
        raise UserError(f"search must be grid or random, got {config['search']!r}")
    workers = config["resources"]["workers"]
    if not isinstance(workers, int) or workers < 0:
        raise UserError(f"resources.workers must be a whole number >= 0, got {workers!r}")
    if workers and config["kind"] != "training":
        raise UserError("resources.workers (Ray Train workers) applies to training sweeps only")
    if config["kind"] == "training":
        _check_training_space(config)


def training_overrides(params: dict[str, Any]) -> list[str]:
    """A training trial's parameters as ``--set`` overrides; values as JSON, which YAML reads
    back as they were (null, true, lists), unlike Python's ``str``."""
    return [f"{key}={json.dumps(value)}" for key, value in params.items()]


def _check_training_space(config: dict[str, Any]) -> None:
    """Every value of the space applied to the model's training config, as the trials will: an
    unknown key or a value of the wrong kind is one line now, not a traceback inside a Ray trial."""
    entry = model(config["model"])
    base = entry.load("recipe").load_config(entry, config["train_config"])
    for key, values in config["space"].items():
        for value in values:
            try:
                apply_overrides(base, training_overrides({key: value}))
            except UserError as error:
                raise UserError(f"space of this training sweep (config {config['train_config']}): {error}") from error


# ------------------------------------------------------------------------------------- trials
def run_trial(params: dict[str, Any], context: dict[str, Any]) -> dict[str, float]:
    """One trial in the project directory: (train, then) evaluate as a child run of the sweep;
    returns the evaluation's metrics under their MLflow names (``multi/tps/jerk``, ``gt/jerk_concat``, ...)."""
    from orchestration.evaluate.records import ParentRun
    from orchestration.evaluate.request import EvalRequest
    from orchestration.evaluate.run import evaluate
    from orchestration.evaluate.settings import new_settings
    from orchestration.recipe import train, train_on_workers
    from orchestration.reports import table_metrics

    resources = context["resources"]
    enter_project(context["project"], context["tracking_uri"], resources["cpu"])
    load_plugins(**context["plugins"])
    parent = ParentRun(context["experiment_id"], context["parent_run_id"], trial_name(params))
    finished = _earlier_child(parent)
    if finished is not None:
        return finished
    evaluation = dict(context["evaluation"])
    name = context["model"]
    if context["kind"] == "training":
        overrides = training_overrides(params)
        if resources["workers"]:
            run_dir = train_on_workers(
                name,
                context["train_config"],
                overrides,
                resources["workers"],
                resources["gpu"] > 0,
                resources["cpu"],
                Path(context["train_storage"]),
            )
        else:
            run_dir = train(name, context["train_config"], overrides)
        evaluation["checkpoints"] = [str(run_dir / model(name).model_file)]
    else:
        evaluation["options"] = params
    settings = new_settings(context["dataset"], EvalRequest(models=[name], **evaluation))
    _, table = evaluate(settings, context["dataset"], parent=parent, progress=False)
    return table_metrics(table)


def _earlier_child(parent: Any) -> dict[str, float] | None:
    """A trial run again after its driver died. Its child run that finished before the kill
    (its evaluation whole, its metrics logged, Tune not yet told) gives its metrics instead of
    a second evaluation; one that never finished is marked KILLED rather than left looking alive
    beside the new one."""
    mlflow_client = tracking_client()
    earlier = mlflow_client.search_runs(
        [parent.experiment_id],
        f"tags.mlflow.parentRunId = '{parent.run_id}' and attributes.run_name = '{parent.child_name}'",
    )
    for run in earlier:
        if run.info.status == "FINISHED":
            return dict(run.data.metrics)
    for run in earlier:
        if run.info.status == "RUNNING":
            mlflow_client.set_terminated(run.info.run_id, "KILLED")
    return None


def _tune_trainable(config: dict[str, Any]) -> None:
    """The Tune function trainable: the sampled parameters beside the shared context."""
    from ray import tune

    context = config["context"]
    params = {key: config[key] for key in context["knobs"]}
    tune.report(run_trial(params, context))


# ------------------------------------------------------------------------------------- driver
def _context(config: dict[str, Any], parent: tuple[str, str], sweep_dir: Path) -> dict[str, Any]:
    """What every trial needs: the project's absolute path, which a trial enters first, so that the
    files the settings name relative to it are found."""
    from orchestration.evaluate.request import EvalRequest
    from orchestration.evaluate.settings import new_settings

    dataset, entry = config["dataset"], model(config["model"])
    evaluation = {
        "testset": config["testset"],
        "evaluator": config["evaluator"],
        "methods": [config["method"]],
        "repeats": config["repeats"],
    }
    if config["kind"] == "sampling":
        checkpoints = [] if config["checkpoint"] is None else [config["checkpoint"]]
        resolved = new_settings(dataset, EvalRequest(models=[entry.name], checkpoints=checkpoints, **evaluation))
        evaluation.update(
            checkpoints=[resolved.candidates[0].checkpoint], evaluator=resolved.evaluator, testset=resolved.testset
        )
    else:
        recipe = entry.load("recipe")
        train_config = recipe.load_config(entry, config["train_config"])
        try:  # a missing or damaged VQ-VAE, or its tokens being made by another command: one line
            recipe.prepare(train_config)
        except (FileNotFoundError, ValueError) as error:
            raise UserError(str(error)) from error
    return {
        "project": str(Path.cwd().resolve()),
        "tracking_uri": tracking_uri(),
        "dataset": dataset,
        "model": entry.name,
        "plugins": plugins_for_workers(),
        "kind": config["kind"],
        "knobs": list(config["space"]),
        "evaluation": evaluation,
        "train_config": config["train_config"],
        "resources": config["resources"],
        "train_storage": str(sweep_dir / "train"),
        "experiment_id": parent[0],
        "parent_run_id": parent[1],
    }


def _trial_lines(name: str, config: dict[str, Any]) -> list[Any]:
    """The callback that prints a line per finished trial in a log (orchestration/sweep_lines.py)."""
    from orchestration.sweep_lines import TrialLines

    grid = config["search"] == "grid"
    total = math.prod(len(values) for values in config["space"].values()) if grid else config["samples"]
    return [TrialLines(name, list(config["space"]), total)]


def _trial_resources(resources: dict[str, Any]) -> dict[str, float]:
    """What a trial reserves: its CPUs and GPUs, or, when Ray Train workers train for it, one
    CPU for the trial itself (it waits for the workers, then evaluates on what they trained)."""
    if resources["workers"]:
        return {"cpu": 1, "gpu": 0}
    return {"cpu": resources["cpu"], "gpu": resources["gpu"]}


def _recorded(sweep_dir: Path) -> dict[str, Any] | None:
    """What ``sweep.json`` says of a sweep started before: its parent run and its config."""
    record = sweep_dir / SWEEP_FILE
    return json.loads(record.read_text(encoding="utf-8")) if record.exists() else None


def _check_resumable(sweep_dir: Path, config: dict[str, Any]) -> None:
    """A re-run restores the Tune experiment with the parameters it was started with, so one
    whose config (file and ``--set``) differs from the recorded one is refused, naming what
    changed, instead of silently resuming the old sweep."""
    saved = _recorded(sweep_dir)
    if saved is None:
        return
    if "model" not in saved["config"]:  # its Tune experiment holds trials of the older layout
        raise UserError(
            f"{sweep_dir} was started by an m2d2m without the model registry and cannot be "
            f"resumed; --restart replaces it"
        )
    before, now = flatten(saved["config"]), flatten(json.loads(json.dumps(config)))
    changed = sorted(key for key in before.keys() | now.keys() if before.get(key, ()) != now.get(key, ()))
    if changed:
        raise UserError(
            f"{sweep_dir} was started with another config ({', '.join(changed)} changed); "
            f"give this sweep a new --name, or --restart to replace that one"
        )


def _discard(sweep_dir: Path) -> None:
    """``--restart``: the sweep's folder (Tune experiment, trained runs' storage, record) goes; its
    parent run, if a dead driver left it RUNNING, is marked KILLED."""
    from mlflow.exceptions import MlflowException

    saved = _recorded(sweep_dir)
    if saved is not None:
        mlflow_client = tracking_client()
        try:
            if mlflow_client.get_run(saved["parent_run_id"]).info.status == "RUNNING":
                mlflow_client.set_terminated(saved["parent_run_id"], "KILLED")
        except MlflowException:  # the run is gone from this store: nothing to mark
            pass
    shutil.rmtree(sweep_dir, ignore_errors=True)


def _parent_run(sweep_dir: Path, name: str, config: dict[str, Any]) -> tuple[str, str]:
    """The sweep's MLflow parent run (experiment ``<dataset>/sweep``), reused when the sweep resumes."""
    saved = _recorded(sweep_dir)
    if saved is not None:
        return saved["experiment_id"], saved["parent_run_id"]
    params = {
        "model": config["model"],
        "kind": config["kind"],
        "method": config["method"],
        "repeats": config["repeats"],
        "search": config["search"],
        **{f"space.{k}": json.dumps(v) for k, v in config["space"].items()},
    }
    run_id = start_run(
        experiment_name(config["dataset"], SWEEP_STAGE),
        name,
        {"dataset": config["dataset"], "stage": SWEEP_STAGE, "sweep_kind": config["kind"]},
        params,
    )
    experiment_id = tracking_client().get_run(run_id).info.experiment_id
    sweep_dir.mkdir(parents=True, exist_ok=True)
    (sweep_dir / SWEEP_FILE).write_text(
        json.dumps({"experiment_id": experiment_id, "parent_run_id": run_id, "config": config}, indent=2),
        encoding="utf-8",
    )
    return experiment_id, run_id


def sweep(
    config_name: str,
    overrides: list[str] | None = None,
    ray_address: str | None = None,
    name: str | None = None,
    restart: bool = False,
) -> Path:
    """Run (or resume) the sweep ``name`` (default: the config's file name), or with ``restart``
    start it over; returns its directory with the summary table and plot."""
    from ray import tune

    from pipelines.features import init_ray

    config = load_sweep_config(config_name, overrides or [])
    _check(config)
    name = name or Path(config_name).stem
    if not name or Path(name).name != name or name in (".", ".."):
        raise UserError(f"--name {name!r}: give a plain folder name, e.g. demo-wide")
    sweep_dir = (stage_dir(config["dataset"], SWEEP_STAGE) / name).resolve()
    # a second `m2d2m sweep` of this name would restore and write the same Tune experiment
    with exclusive(
        sweep_dir.parent / f".{name}.lock", f"the sweep {name!r} is running in another command; let it finish first"
    ):
        if restart:
            _discard(sweep_dir)
        else:
            _check_resumable(sweep_dir, config)
        init_ray(ray_address, os.cpu_count() or 1)  # first: tokenizing for a training sweep joins the same Ray
        parent = _parent_run(sweep_dir, name, config)
        with finishing(parent[1]):
            context = _context(config, parent, sweep_dir)
            trainable = tune.with_resources(_tune_trainable, _trial_resources(config["resources"]))
            storage = sweep_dir / "tune"
            if tune.Tuner.can_restore(str(storage / name)):
                print(f"resuming the sweep in {storage / name}")
                tuner = tune.Tuner.restore(str(storage / name), trainable, resume_errored=True)
            else:
                space = {
                    key: (tune.grid_search(values) if config["search"] == "grid" else tune.choice(values))
                    for key, values in config["space"].items()
                }
                tuner = tune.Tuner(
                    trainable,
                    param_space={**space, "context": context},
                    tune_config=tune.TuneConfig(
                        num_samples=1 if config["search"] == "grid" else config["samples"],
                        max_concurrent_trials=config["max_concurrent"],
                    ),
                    run_config=tune.RunConfig(
                        name=name,
                        storage_path=str(storage),
                        verbose=1,
                        failure_config=tune.FailureConfig(max_failures=config["max_failures"]),
                        callbacks=_trial_lines(name, config),
                    ),
                )
            results = tuner.fit()
            failed = [result for result in results if result.error is not None]
            rows = [
                {**{k: result.config[k] for k in context["knobs"]}, **result.metrics}
                for result in results
                if result.error is None and result.metrics
            ]
            summarize(sweep_dir, rows, config, parent[1])
            if failed:
                raise UserError(
                    f"{len(failed)} of {len(results)} trials failed after {config['max_failures']} retries; "
                    f"see {storage / name}"
                )
        return sweep_dir


def summarize(sweep_dir: Path, rows: list[dict[str, Any]], config: dict[str, Any], parent_run_id: str) -> None:
    """summary.json / summary.md (one row per trial) and, for sampling sweeps, Jerk and FID
    against the last knob of the space, one line per value of the first (for M2D2M's demo: T_s,
    per η); logged to the parent run."""
    knobs = list(config["space"])
    metric_names = [f"multi/{config['method']}/{m}" for m in METRICS]
    kept = [{**{k: row[k] for k in knobs}, **{m: row.get(m) for m in metric_names}} for row in rows]
    kept.sort(key=lambda row: tuple(row[k] for k in knobs))
    (sweep_dir / SUMMARY_JSON).write_text(json.dumps(kept, indent=2), encoding="utf-8")
    lines = ["| " + " | ".join(knobs + metric_names) + " |", "|" + " --- |" * (len(knobs) + len(metric_names))]
    lines += [
        "| "
        + " | ".join(str(row[k]) for k in knobs)
        + " | "
        + " | ".join("–" if row[m] is None else f"{row[m]:.3f}" for m in metric_names)
        + " |"
        for row in kept
    ]
    (sweep_dir / SUMMARY_MD).write_text("\n".join(lines) + "\n", encoding="utf-8")
    client = tracking_client()
    client.log_artifact(parent_run_id, str(sweep_dir / SUMMARY_MD))
    client.log_artifact(parent_run_id, str(sweep_dir / SUMMARY_JSON))
    if config["kind"] == "sampling":
        x = knobs[-1]
        path = plot_against(
            sweep_dir / summary_plot(x), kept, config["method"], x, knobs[0] if len(knobs) > 1 else None
        )
        client.log_artifact(parent_run_id, str(path))


def plot_against(path: Path, rows: list[dict[str, Any]], method: str, x: str, line: str | None) -> Path:
    """Jerk and FID of ``method`` against the knob ``x``, one curve per value of the knob ``line``."""
    from orchestration.reports import KNOB_METRICS, plot_against_knob

    values = sorted({row[line] for row in rows}) if line else [None]
    series = {
        metric: {
            (f"{line} = {value}" if line else method): [
                (row[x], row[f"multi/{method}/{metric}"], None) for row in rows if line is None or row[line] == value
            ]
            for value in values
        }
        for metric, _ in KNOB_METRICS
    }
    return plot_against_knob(path, series, x)
