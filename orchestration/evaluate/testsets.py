"""The N-action test sets evaluation reads: building and recording one (`m2d2m testset`),
opening one that checks clean, the default one of a model's dataset, and the reference
measurements of its ground truth (and of each model's codec) that every table row is judged against."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from m2d2m.evaluation.evaluator import TextMotionEvaluator
from m2d2m.evaluation.measurements import Reference
from m2d2m.generators.protocol import MotionGenerator
from m2d2m.layout import MANIFEST, recorded_path
from orchestration.errors import UserError
from orchestration.project import require_project
from orchestration.tracking import experiment_name, log_batch, tracked_run
from pipelines.testset import (
    INSTANCES,
    MOTIONS,
    TestSet,
    build_testset,
    check_testset,
    describe,
    load_testset,
    source_dir,
    split_metas,
    testset_dir,
)

TESTSET_STAGE = "testset"
DEFAULT_N, DEFAULT_SEED = 4, 0  # the paper's N = 4; the test set `evaluate` builds when none is given


def make_testset(
    data_dir: str | Path | None,
    dataset: str,
    n: int = DEFAULT_N,
    seed: int = DEFAULT_SEED,
    mirrors: str = "same",
    force: bool = False,
    limit: int | None = None,
    split: str = "test",
) -> dict[str, Any]:
    """Build (or reuse) the N-action test set of a processed dataset and record it in MLflow
    (experiment ``<dataset>/testset``: its parameters, pool and instance counts, and its files,
    so an evaluation can name exactly what it ran on). Returns the summary with ``mlflow_run_id``.
    ``data_dir`` None: the project's ``data/<dataset>``."""
    if data_dir is None:
        require_project()
        data_dir = f"data/{dataset}"
    try:
        summary = build_testset(data_dir, n=n, seed=seed, mirrors=mirrors, force=force, limit=limit, split=split)
    except (FileNotFoundError, FileExistsError, ValueError) as error:
        raise UserError(str(error)) from error
    path, pool = Path(summary["path"]), summary["pool"]
    params = {
        "n": n,
        "seed": seed,
        "mirrors": mirrors,
        "limit": limit,
        "split": summary["split"],
        "min_frames": summary["min_frames"],
        "data": summary["source"]["dir"],
        "path": path,
    }
    tags = {"dataset": dataset, "stage": TESTSET_STAGE, "reused": str(summary["reused"])}
    with tracked_run(experiment_name(dataset, TESTSET_STAGE), path.name, tags, params) as (client, run_id):
        log_batch(
            client,
            run_id,
            metrics={
                "pool_captions": pool["entries"],
                "pool_motions": pool["motions"],
                "instances": summary["instances"],
            },
        )
        for name in (MANIFEST, INSTANCES, MOTIONS):
            client.log_artifact(run_id, str(path / name), artifact_path="testset")
    return {**summary, "mlflow_run_id": run_id}


def open_testset(path: str | Path) -> TestSet:
    """A test set that checks clean against its manifest, or a one-line error."""
    path = Path(path)
    if not (path / MANIFEST).exists():
        raise UserError(f"{path}: no test set there; build one with `m2d2m testset` (make testset)")
    problems = check_testset(path)
    if problems:
        raise UserError(f"{path}: {problems[0]} (rebuild it with `m2d2m testset --force`)")
    return load_testset(path)


def _caption_tokens(testset: TestSet) -> list[list[str]]:
    """Each item's caption as ``word/POS`` tokens, in item order, read from the test set's source
    dataset: the corpus's own tags are what the evaluator was trained on. (The test set's own
    shard reader is reused: importing training's would load Lightning, seconds for nothing.)"""
    try:
        metas = split_metas(source_dir(testset.path, testset.manifest), testset.manifest["split"])
    except (FileNotFoundError, ValueError) as error:  # a missing dataset, or shards that changed
        raise UserError(f"{error}; the captions' word/POS tokens come from the test set's source dataset") from error
    wanted = {(item.key, item.caption_index) for instance in testset for item in instance.items}
    tokens = {
        (meta["id"], index): caption["tokens"]
        for meta in metas
        for index, caption in enumerate(meta["captions"])
        if (meta["id"], index) in wanted
    }
    return [tokens[item.key, item.caption_index] for instance in testset for item in instance.items]


def measure_reference(
    testset: TestSet, evaluator: TextMotionEvaluator, generators: dict[str, MotionGenerator]
) -> tuple[Reference, dict[str, str]]:
    """The test set's measurements, its lengths in whole steps of every generator, and each
    generator's codec, if it has one, measured once per distinct codec; with the label each
    model's codec is measured under (models without a codec have none)."""
    segments = [[testset.features(instance.index, p) for p in range(len(instance.items))] for instance in testset]
    first = next(iter(generators.values()))
    reference = Reference.build(
        [instance.actions for instance in testset],
        segments,
        _caption_tokens(testset),
        evaluator,
        first.skeleton,
        math.lcm(*(g.frame_step for g in generators.values())),
    )
    codec_of = {
        name: reference.add_reconstruction(name, generator, evaluator) for name, generator in generators.items()
    }
    return reference, {name: label for name, label in codec_of.items() if label is not None}


def default_testset(generator: MotionGenerator, dataset: str) -> Path:
    """n4-seed0 of the dataset the model was trained on (data/<dataset> when it does not say),
    built and logged when missing."""
    data_dir = recorded_path(generator.data_dir, generator.source) if generator.data_dir else Path("data") / dataset
    path = testset_dir(data_dir, DEFAULT_N, DEFAULT_SEED)
    if not (path / MANIFEST).exists():
        print(describe(make_testset(data_dir, dataset)))
    return path
