"""`m2d2m evaluate`: one run of the paper's multi-motion table (§5.2, Tables 1–2), its
single-motion table (§5.3, Table 3), the editing table (MMM Table 3) and Fig. 5, for one or
several models on one N-action test set: its checks, its jobs with a progress bar, a result file
each, and at the end the table and the MLflow record rebuilt from those files."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from m2d2m.evaluation.evaluator import TextMotionEvaluator, load_evaluator, load_guo_checkpoint
from m2d2m.evaluation.measurements import MM_GENERATIONS, MM_PROMPTS, Evaluation
from m2d2m.generators.options import MULTI
from m2d2m.generators.protocol import MotionGenerator
from m2d2m.layout import relative_to_project
from m2d2m.progress import progress as progress_bar
from orchestration.errors import UserError
from orchestration.evaluate.jobs import RESULTS, KeptBatches, jobs, result_file
from orchestration.evaluate.records import ParentRun, describe_sampling, log_children, start
from orchestration.evaluate.settings import EvalSettings
from orchestration.evaluate.table import build_table
from orchestration.evaluate.testsets import default_testset, measure_reference, open_testset
from orchestration.generate.loading import load_generator
from orchestration.reports import FIGURE, TABLE_JSON, TABLE_MD, table_metrics
from orchestration.runs import mark_latest, read_run_info, run_in_use, write_run_info
from orchestration.tracking import finishing, log_batch
from pipelines.shards import write_json_atomically
from pipelines.testset import TestSet


def _load_evaluator(settings: EvalSettings, device: torch.device) -> TextMotionEvaluator:
    try:
        if settings.glove is not None:
            return load_guo_checkpoint(settings.evaluator, settings.glove, settings.meta, map_location=device)
        return load_evaluator(settings.evaluator, map_location=device)
    except (FileNotFoundError, ValueError, KeyError) as error:
        raise UserError(str(error)) from error


def _check(
    settings: EvalSettings, generators: dict[str, MotionGenerator], testset: TestSet, evaluator: TextMotionEvaluator
) -> None:
    """Refuse, before anything runs, what cannot give a table."""
    dims = {
        f"the model {name}" if len(generators) > 1 else "the model": g.feature_dim for name, g in generators.items()
    }
    for owner, dim in {**dims, "the evaluator": evaluator.config.feature_dim}.items():
        if testset.manifest.get("feature_dim") != dim:
            raise UserError(
                f"{testset.path} holds {testset.manifest.get('feature_dim')}-d features but {owner} "
                f"works on {dim}-d ones: use a test set of the same dataset"
            )
    skeletons = {name: g.skeleton.name for name, g in generators.items()}
    if len(set(skeletons.values())) > 1:
        raise UserError(
            "the models are on different skeletons ("
            + ", ".join(f"{n}: {s}" for n, s in skeletons.items())
            + "); judge models of one dataset together"
        )
    if settings.regenerate is not None and settings.regenerate > testset.n:
        raise UserError(f"--regenerate {settings.regenerate}: {testset.path}'s instances have {testset.n} actions")
    if testset.n < 2 or len(testset) < 2:
        raise UserError(
            f"{testset.path}: multi-motion evaluation needs N >= 2 actions and at least 2 instances "
            f"(it has N = {testset.n}, {len(testset)} instances)"
        )
    try:
        for candidate, method in settings.rows():
            generators[candidate.model].options(MULTI, method=method, **candidate.options)
    except ValueError as error:
        raise UserError(str(error)) from error


def evaluate(
    settings: EvalSettings,
    dataset: str = "synthetic",
    run_dir: Path | None = None,
    batch_size: int = 64,
    parent: ParentRun | None = None,
    progress: bool = True,
) -> tuple[Path, dict[str, Any]]:
    """Run (or, given ``run_dir``, finish) an evaluation; returns the run directory and the table.
    ``parent`` nests its MLflow run under a sweep's.

    Only the (candidate, method, repeat) triples without a result file are computed, so a killed
    run resumes where it stopped and a finished one only rewrites its table, figure and MLflow
    record. With several models, each also gets a child MLflow run with its rows under the
    metric names of a one-model evaluation, so the MLflow UI compares the models column by column.
    """
    generators = {c.model: load_generator(c.model, c.checkpoint, dataset) for c in settings.candidates}
    if settings.testset is None:
        first = generators[settings.candidates[0].model]
        settings = replace(settings, testset=relative_to_project(default_testset(first, dataset)))
    testset = open_testset(settings.testset)
    evaluator = _load_evaluator(settings, next(iter(generators.values())).device)
    _check(settings, generators, testset, evaluator)
    reference, codec_of = measure_reference(testset, evaluator, generators)
    samplings = describe_sampling(settings, generators)
    if run_dir is None:
        run_dir = start(settings, dataset, samplings, testset, reference.rp_batch, parent)
    with run_in_use(run_dir, "evaluate"):  # a second --resume of this run refuses in one line
        (run_dir / RESULTS).mkdir(exist_ok=True)
        pending = [job for job in jobs(settings) if not result_file(run_dir, job).exists()]
        run_id = read_run_info(run_dir)["mlflow_run_id"]
        batches = {
            "multi": -(-len(reference.actions) // batch_size),
            "items": -(-reference.items // batch_size),
            "single": -(-reference.items // batch_size)
            + -(-min(MM_PROMPTS, reference.items) * MM_GENERATIONS // batch_size),
            "regenerate": 3 * -(-len(reference.actions) // batch_size),  # the sources, the edits, the wholes
        }
        try:
            with finishing(run_id) as client:
                with progress_bar(
                    total=sum(batches[job.batches] for job in pending), unit="batch", disable=not progress
                ) as bar:

                    def advance(label: str) -> None:
                        bar.set_description(label)
                        bar.update()

                    evaluations = {
                        c.model: Evaluation(generators[c.model], evaluator, reference, c.options, batch_size, advance)
                        for c in settings.candidates
                    }
                    for job in pending:
                        evaluation = evaluations[job.candidate.model]
                        evaluation.finished = kept = KeptBatches(run_dir, job)
                        result = (
                            evaluation.multi(job.method, job.repeat)
                            if job.table == "multi"
                            else evaluation.single(job.repeat)
                            if job.table == "single"
                            else evaluation.regenerate(
                                job.method,
                                generators[job.candidate.model].edit_method or job.method,
                                settings.regenerate,
                                job.repeat,
                            )
                            if job.table == "regenerate"
                            else evaluation.edit(job.task, job.text, job.repeat)
                        )
                        write_json_atomically(result_file(run_dir, job), result)
                        kept.discard()
                table = build_table(run_dir, settings, testset, reference, codec_of, samplings)
                log_batch(client, run_id, metrics=table_metrics(table))
                for name in (TABLE_MD, TABLE_JSON, FIGURE):
                    client.log_artifact(run_id, str(run_dir / name))
                client.log_artifacts(run_id, str(run_dir / RESULTS), artifact_path=RESULTS)
                if len(settings.candidates) > 1:
                    log_children(run_dir, settings, samplings, table, dataset)
        except BaseException:
            write_run_info(run_dir, status="failed")
            raise
        write_run_info(run_dir, status="finished")
        mark_latest(run_dir)
        return run_dir, table
