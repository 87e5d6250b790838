"""An evaluation's records: its run directory and MLflow run with every knob as a param (a
child of a sweep's run when nested), how each candidate samples in its generator's words, and
with several models one child run per model under a one-model evaluation's metric names."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from m2d2m.evaluation.measurements import JERK_FPS, WINDOW
from m2d2m.generators.options import MULTI, SINGLE
from m2d2m.generators.protocol import MotionGenerator
from m2d2m.layout import relative_to_project
from orchestration.evaluate.settings import EVAL_STAGE, Candidate, EvalSettings
from orchestration.reports import GENERATED, GT_CONCAT, GT_SINGLE, RECONSTRUCTION, table_metrics
from orchestration.runs import new_run_dir, read_run_info, write_run_info
from orchestration.tracking import client as tracking_client
from orchestration.tracking import experiment_name, finishing, log_batch, start_run
from pipelines.testset import TestSet


@dataclass(frozen=True)
class ParentRun:
    """An MLflow run to nest an evaluation under (a sweep): its experiment, its id, the child's name."""

    experiment_id: str
    run_id: str
    child_name: str


@dataclass(frozen=True)
class Sampling:
    """How a candidate samples, in its generator's words: multi-action and (with ``single``) single-action."""

    multi: str
    single: str | None


def describe_sampling(settings: EvalSettings, generators: dict[str, MotionGenerator]) -> dict[str, Sampling]:
    samplings = {}
    for candidate in settings.candidates:
        generator = generators[candidate.model]
        preset = {"preset": MULTI, "method": candidate.methods[0]} if candidate.methods else {"preset": SINGLE}
        multi = generator.describe(generator.options(**preset, **candidate.options))
        single = generator.describe(generator.options(SINGLE, **candidate.options)) if settings.single else None
        samplings[candidate.model] = Sampling(multi, single)
    return samplings


def candidate_params(candidate: Candidate, sampling: Sampling) -> dict[str, Any]:
    return {
        "model": candidate.model,
        "checkpoint": candidate.checkpoint,
        "methods": ",".join(candidate.methods),
        **candidate.options,
        "sampling": sampling.multi,
        "single_sampling": sampling.single,
    }


def mlflow_params(settings: EvalSettings, samplings: dict[str, Sampling]) -> dict[str, Any]:
    """The MLflow params: the shared settings, and each candidate's — under their own names for
    one model, prefixed ``<model>.`` for several (each child run has them unprefixed)."""
    shared = {key: value for key, value in asdict(settings).items() if key != "candidates"}
    if len(settings.candidates) == 1:
        only = settings.candidates[0]
        return {**shared, **candidate_params(only, samplings[only.model])}
    prefixed = {
        f"{c.model}.{key}": value
        for c in settings.candidates
        for key, value in candidate_params(c, samplings[c.model]).items()
        if key != "model"
    }
    return {**shared, "model": ",".join(settings.models), **prefixed}


def start(
    settings: EvalSettings,
    dataset: str,
    samplings: dict[str, Sampling],
    testset: TestSet,
    rp_batch: int,
    parent: ParentRun | None = None,
) -> Path:
    """A new run directory and its MLflow run (experiment ``<dataset>/eval``, or a child run of
    ``parent`` in the parent's experiment) with every knob."""
    run_dir = new_run_dir(dataset, EVAL_STAGE)
    methods = ",".join(settings.row(c, m) for c, m in settings.rows())
    tags = {
        "dataset": dataset,
        "stage": EVAL_STAGE,
        "model": ",".join(settings.models),
        "methods": methods,
        "run_dir": relative_to_project(run_dir),
    }
    params = {
        **mlflow_params(settings, samplings),
        "n": testset.n,
        "instances": len(testset),
        "window": WINDOW,
        "jerk_fps": JERK_FPS,
        "r_precision_batch": rp_batch,
    }
    run_id = start_run(
        experiment_name(dataset, EVAL_STAGE),
        parent.child_name if parent else run_dir.name,
        tags,
        params,
        (parent.experiment_id, parent.run_id) if parent else None,
    )
    write_run_info(
        run_dir, stage=EVAL_STAGE, dataset=dataset, status="running", settings=asdict(settings), mlflow_run_id=run_id
    )
    return run_dir


def log_children(
    run_dir: Path, settings: EvalSettings, samplings: dict[str, Sampling], table: dict[str, Any], dataset: str
) -> None:
    """One child run per candidate, named by its model, holding its params and its rows' metrics
    as a one-model evaluation names them (``multi/<method>/<metric>``, ``single/<metric>``,
    ``edit/<task>/<text|no_text>/<metric>``, the ground-truth rows, its codec's reconstruction
    rows). A resumed run reuses its children."""
    info = read_run_info(run_dir)
    children = dict(info.get("children", {}))
    parent_id, experiment_id = (
        info["mlflow_run_id"],
        tracking_client().get_run(info["mlflow_run_id"]).info.experiment_id,
    )
    for candidate in settings.candidates:
        codec = table["codecs"].get(candidate.model)
        shared = {row: values for row, values in table["multi"].items() if row in (GT_SINGLE, GT_CONCAT)}
        one = {
            "multi": {
                **shared,
                **({RECONSTRUCTION: table["multi"][codec]} if codec else {}),
                **{
                    method: table["multi"][settings.row(candidate, method)]
                    for method in candidate.methods
                    if settings.multi
                },
            }
        }
        if "single" in table and candidate.methods:
            one["single"] = {
                GENERATED: table["single"][settings.single_row(candidate)],
                **({RECONSTRUCTION: table["single"][codec]} if codec else {}),
            }
        if "editing" in table:
            one["editing"] = {
                row.removeprefix(f"{candidate.model}/"): table["editing"][row]
                for _, _, row in settings.edit_rows(candidate)
            }
        if "regenerate" in table and candidate.methods:
            stem = settings.regenerate_row(candidate)
            one["regenerate"] = {
                row.removeprefix(f"{candidate.model}/"): values
                for row, values in table["regenerate"].items()
                if row.startswith(f"{stem}/")
            }
        if candidate.model not in children:
            tags = {
                "dataset": dataset,
                "stage": EVAL_STAGE,
                "model": candidate.model,
                "methods": ",".join(candidate.methods),
            }
            children[candidate.model] = start_run(
                experiment_name(dataset, EVAL_STAGE),
                candidate.model,
                tags,
                candidate_params(candidate, samplings[candidate.model]),
                (experiment_id, parent_id),
            )
            write_run_info(run_dir, children=children)
        with finishing(children[candidate.model]) as client:
            log_batch(client, children[candidate.model], metrics=table_metrics(one))
