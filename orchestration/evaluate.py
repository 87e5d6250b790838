"""`m2d2m testset` and `m2d2m evaluate`: the paper's multi-motion table (§5.2, Tables 1–2), its
single-motion table (§5.3, Table 3) and its Fig. 5, for one model file of any registered model
on one N-action test set.

The measurements are the library's (:mod:`m2d2m.evaluation.measurements`), the reports
:mod:`orchestration.reports`'; this module holds what makes it a run: the settings, fixed for
the run; the test set and evaluator it reads; the run directory and its MLflow run. Each
finished (method, repeat) is a JSON file under the run's ``results/``, so ``--resume``
recomputes nothing that is done; the table, the figure and the MLflow run are rebuilt from those
files at the end.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from m2d2m.evaluation.evaluator import TextMotionEvaluator, load_evaluator, load_guo_checkpoint
from m2d2m.evaluation.measurements import (JERK_FPS, MM_GENERATIONS, MM_PROMPTS, WINDOW, Evaluation, Reference,
                                           mean_profile)
from m2d2m.generators.protocol import MULTI, SINGLE, MotionGenerator
from m2d2m.layout import MANIFEST
from orchestration.errors import UserError
from orchestration.generate import load_generator, resolve_model_file
from orchestration.registry import model
from orchestration.reports import (FIGURE, GENERATED, GT_CONCAT, GT_SINGLE, RECONSTRUCTION, ROW_TITLES, SINGLE_COLUMNS,
                                   TABLE_JSON, TABLE_MD, notes, plot_fig5, render_table, summarize_rows, table_metrics)
from orchestration.runs import find_run, mark_latest, new_run_dir, read_run_info, run_file, write_run_info
from orchestration.tracking import experiment_name, finishing, log_batch, start_run, tracked_run
from orchestration.train import EVALUATOR_FILE, EVALUATOR_STAGE
from pipelines.shards import write_json_atomically
from pipelines.testset import (INSTANCES, MOTIONS, TestSet, build_testset, check_testset, describe, load_testset,
                               split_metas, testset_dir)

EVAL_STAGE = "eval"
TESTSET_STAGE = "testset"
DEFAULT_N, DEFAULT_SEED = 4, 0  # the paper's N = 4; the test set `evaluate` builds when none is given
RESULTS = "results"


# ---------------------------------------------------------------------------------- test sets
def make_testset(data_dir: str | Path, dataset: str, n: int = DEFAULT_N, seed: int = DEFAULT_SEED,
                 mirrors: str = "same", force: bool = False, limit: int | None = None) -> dict[str, Any]:
    """Build (or reuse) the N-action test set of a processed dataset and record it in MLflow
    (experiment ``<dataset>/testset``: its parameters, pool and instance counts, and its files,
    so an evaluation can name exactly what it ran on). Returns the summary with ``mlflow_run_id``."""
    try:
        summary = build_testset(data_dir, n=n, seed=seed, mirrors=mirrors, force=force, limit=limit)
    except (FileNotFoundError, FileExistsError, ValueError) as error:
        raise UserError(str(error)) from error
    path, pool = Path(summary["path"]), summary["pool"]
    params = {"n": n, "seed": seed, "mirrors": mirrors, "limit": limit, "split": summary["split"],
              "min_frames": summary["min_frames"], "data": summary["source"]["dir"], "path": path}
    tags = {"dataset": dataset, "stage": TESTSET_STAGE, "reused": str(summary["reused"])}
    with tracked_run(experiment_name(dataset, TESTSET_STAGE), path.name, tags, params) as (client, run_id):
        log_batch(client, run_id, metrics={"pool_captions": pool["entries"], "pool_motions": pool["motions"],
                                           "instances": summary["instances"]})
        for name in (MANIFEST, INSTANCES, MOTIONS):
            client.log_artifact(run_id, str(path / name), artifact_path="testset")
    return {**summary, "mlflow_run_id": run_id}


def _open_testset(path: str | Path) -> TestSet:
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
        metas = split_metas(Path(testset.manifest["source"]["dir"]), testset.manifest["split"])
    except (FileNotFoundError, ValueError) as error:  # a missing dataset, or shards that changed
        raise UserError(f"{error}; the captions' word/POS tokens come from the test set's source dataset") from error
    wanted = {(item.key, item.caption_index) for instance in testset for item in instance.items}
    tokens = {(meta["id"], index): caption["tokens"] for meta in metas
              for index, caption in enumerate(meta["captions"]) if (meta["id"], index) in wanted}
    return [tokens[item.key, item.caption_index] for instance in testset for item in instance.items]


def _reference(testset: TestSet, evaluator: TextMotionEvaluator, generator: MotionGenerator) -> Reference:
    segments = [[testset.features(instance.index, p) for p in range(len(instance.items))] for instance in testset]
    return Reference.build([instance.actions for instance in testset], segments, _caption_tokens(testset),
                           evaluator, generator)


# ----------------------------------------------------------------------------------- settings
@dataclass(frozen=True)
class EvalSettings:
    """Every knob that changes the numbers. Recorded in run.json, table.json and the MLflow
    params, and fixed for a run: ``--resume`` continues with exactly these. ``options`` are the
    sampling knobs that differ from the model's multi-action preset (for M2D2M: ts, eta, ...)."""

    model: str
    checkpoint: str
    testset: str | None  # None: the default test set of the checkpoint's dataset, resolved by evaluate
    evaluator: str
    glove: str | None  # Guo's published evaluator: its GloVe and meta directories
    meta: str | None
    methods: tuple[str, ...]
    options: dict[str, Any]
    repeats: int
    single: bool

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "EvalSettings":
        """Settings as run.json holds them; runs recorded before the model registry (no ``model``,
        M2D2M's ts / eta / guidance at the top level) read as M2D2M runs."""
        values = dict(values)
        if "model" not in values:
            values["model"] = "m2d2m"
            values["options"] = {key: values.pop(key) for key in ("ts", "eta", "guidance")
                                 if values.get(key) is not None}
        return cls(**{**values, "methods": tuple(values["methods"])})


# the settings given as options of their own (the model and sampling options are given apart)
KNOBS = tuple(f.name for f in fields(EvalSettings) if f.name not in ("model", "options")) + ("guo_evaluator",)


def _methods(values: Sequence[str], generator_type: type[MotionGenerator]) -> tuple[str, ...]:
    """Methods given as repeated options and/or comma lists, in order, without repeats."""
    methods = [m.strip() for value in values for m in value.split(",") if m.strip()]
    unknown = [m for m in methods if m not in generator_type.methods]
    if unknown or not methods:
        problem = f"unknown method {unknown[0]!r}" if unknown else "no method given"
        raise UserError(f"{problem} for {generator_type.model}; choose from {', '.join(generator_type.methods)}")
    return tuple(dict.fromkeys(methods))


def new_settings(dataset: str, model_name: str = "m2d2m", checkpoint: str = "latest", testset: str | None = None,
                 evaluator: str | None = None, guo_evaluator: str | None = None, glove: str | None = None,
                 meta: str | None = None, methods: Sequence[str] | None = None, options: dict[str, Any] | None = None,
                 repeats: int = 10, single: bool = False) -> EvalSettings:
    """The settings of a new evaluation, with references resolved to files (so that a later
    ``latest`` cannot change what a resumed run measures). Defaults: the model's first method,
    its multi-action preset (the paper's T_s = 0.9·T, η = 0.25, s = 2 for M2D2M), 10 repeats."""
    generator_type = model(model_name).load("generator")
    if repeats < 1:
        raise UserError(f"--repeats must be at least 1, got {repeats}")
    options = dict(options or {})
    unknown = sorted(set(options) - set(generator_type.knobs()))
    if unknown:
        raise UserError(f"{model_name} has no sampling option {unknown[0]!r}; its options: "
                        f"{', '.join(generator_type.knobs())}")
    if guo_evaluator is not None:
        if evaluator is not None:
            raise UserError("give --evaluator or --guo-evaluator, not both")
        if glove is None:
            raise UserError("--guo-evaluator needs --glove DIR (text-to-motion's glove/ directory)")
        evaluator_path = Path(guo_evaluator).resolve()
        meta = str(Path(meta or evaluator_path / "meta").resolve())
        glove = str(Path(glove).resolve())
    else:
        if glove is not None or meta is not None:
            raise UserError("--glove and --meta go with --guo-evaluator")
        evaluator_path = run_file(evaluator or "latest", dataset, EVALUATOR_STAGE, EVALUATOR_FILE,
                                  "make train-evaluator").resolve()
    return EvalSettings(
        model=model_name, checkpoint=str(resolve_model_file(model_name, checkpoint, dataset).resolve()),
        testset=None if testset is None else str(Path(testset).resolve()),
        evaluator=str(evaluator_path), glove=glove, meta=meta,
        methods=_methods(methods or generator_type.methods[:1], generator_type), options=options,
        repeats=int(repeats), single=bool(single))


def reopen(reference: str, dataset: str) -> tuple[Path, EvalSettings]:
    """An earlier evaluation run (directory, name or MLflow id) and its settings, to resume."""
    run_dir = find_run(reference, dataset, EVAL_STAGE)
    return run_dir, EvalSettings.from_dict(read_run_info(run_dir)["settings"])


def _load_evaluator(settings: EvalSettings, device: torch.device) -> TextMotionEvaluator:
    try:
        if settings.glove is not None:
            return load_guo_checkpoint(settings.evaluator, settings.glove, settings.meta, map_location=device)
        return load_evaluator(settings.evaluator, map_location=device)
    except (FileNotFoundError, ValueError, KeyError) as error:
        raise UserError(str(error)) from error


# ------------------------------------------------------------------------------------ the run
def _result_file(run_dir: Path, method: str | None, repeat: int) -> Path:
    return run_dir / RESULTS / (f"multi-{method}-r{repeat}.json" if method else f"single-r{repeat}.json")


def _read(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text(encoding="utf-8"))


@dataclass(frozen=True)
class ParentRun:
    """An MLflow run to nest an evaluation under (a sweep): its experiment, its id, the child's name."""

    experiment_id: str
    run_id: str
    child_name: str


def _sampling(settings: EvalSettings, generator: MotionGenerator) -> tuple[str, str | None]:
    """The multi-action and (with ``single``) single-action sampling, in the generator's words."""
    multi = generator.describe(generator.options(MULTI, method=settings.methods[0], **settings.options))
    return multi, generator.describe(generator.options(SINGLE)) if settings.single else None


def _start(settings: EvalSettings, dataset: str, generator: MotionGenerator, testset: TestSet, rp_batch: int,
           parent: ParentRun | None = None) -> Path:
    """A new run directory and its MLflow run (experiment ``<dataset>/eval``, or a child run of
    ``parent`` in the parent's experiment) with every knob."""
    run_dir = new_run_dir(dataset, EVAL_STAGE)
    tags = {"dataset": dataset, "stage": EVAL_STAGE, "model": settings.model, "methods": ",".join(settings.methods),
            "run_dir": str(run_dir.resolve())}
    multi, single = _sampling(settings, generator)
    recorded = {key: value for key, value in asdict(settings).items() if key != "options"}
    params = {**recorded, **settings.options, "methods": ",".join(settings.methods), "sampling": multi, "single_sampling": single, "n": testset.n, "instances": len(testset),
              "window": WINDOW, "jerk_fps": JERK_FPS, "r_precision_batch": rp_batch}
    run_id = start_run(experiment_name(dataset, EVAL_STAGE), parent.child_name if parent else run_dir.name, tags,
                       params, (parent.experiment_id, parent.run_id) if parent else None)
    write_run_info(run_dir, stage=EVAL_STAGE, dataset=dataset, status="running", settings=asdict(settings),
                   mlflow_run_id=run_id)
    return run_dir


def _default_testset(generator: MotionGenerator, dataset: str) -> Path:
    """n4-seed0 of the dataset the model was trained on (data/<dataset> when it does not say),
    built and logged when missing."""
    data_dir = generator.data_dir or Path("data") / dataset
    path = testset_dir(data_dir, DEFAULT_N, DEFAULT_SEED)
    if not (path / MANIFEST).exists():
        print(describe(make_testset(data_dir, dataset)))
    return path


def _check(settings: EvalSettings, generator: MotionGenerator, testset: TestSet,
           evaluator: TextMotionEvaluator) -> None:
    """Refuse, before anything runs, what cannot give a table."""
    if generator.needs_keep is not None:
        raise UserError(f"{generator.model} edits motions and cannot generate from text alone, which evaluation "
                        f"asks for; {generator.needs_keep}")
    dims = {"the model": generator.feature_dim, "the evaluator": evaluator.config.feature_dim}
    for owner, dim in dims.items():
        if testset.manifest.get("feature_dim") != dim:
            raise UserError(f"{testset.path} holds {testset.manifest.get('feature_dim')}-d features but {owner} "
                            f"works on {dim}-d ones: use a test set of the same dataset")
    if testset.n < 2 or len(testset) < 2:
        raise UserError(f"{testset.path}: multi-motion evaluation needs N >= 2 actions and at least 2 instances "
                        f"(it has N = {testset.n}, {len(testset)} instances)")
    try:
        for method in settings.methods:
            generator.options(MULTI, method=method, **settings.options)
    except ValueError as error:
        raise UserError(str(error)) from error


def evaluate(settings: EvalSettings, dataset: str = "synthetic", run_dir: Path | None = None,
             batch_size: int = 64, parent: ParentRun | None = None,
             progress: bool = True) -> tuple[Path, dict[str, Any]]:
    """Run (or, given ``run_dir``, finish) an evaluation; returns the run directory and the table.
    ``parent`` nests its MLflow run under a sweep's.

    Only the (method, repeat) pairs without a result file are computed, so a killed run resumes
    where it stopped and a finished one only rewrites its table, figure and MLflow record.
    """
    generator = load_generator(settings.model, settings.checkpoint, dataset)
    if settings.testset is None:
        settings = replace(settings, testset=str(_default_testset(generator, dataset).resolve()))
    testset = _open_testset(settings.testset)
    evaluator = _load_evaluator(settings, generator.device)
    _check(settings, generator, testset, evaluator)
    reference = _reference(testset, evaluator, generator)
    if run_dir is None:
        run_dir = _start(settings, dataset, generator, testset, reference.rp_batch, parent)
    (run_dir / RESULTS).mkdir(exist_ok=True)
    jobs: list[tuple[str | None, int]] = [(m, r) for m in settings.methods for r in range(settings.repeats)]
    jobs += [(None, r) for r in range(settings.repeats)] if settings.single else []
    pending = [job for job in jobs if not _result_file(run_dir, *job).exists()]
    run_id = read_run_info(run_dir)["mlflow_run_id"]
    batches = {"multi": -(-len(reference.actions) // batch_size),
               "single": -(-reference.items // batch_size)
               + -(-min(MM_PROMPTS, reference.items) * MM_GENERATIONS // batch_size)}
    try:
        with finishing(run_id) as client:
            with tqdm(total=sum(batches["multi" if m else "single"] for m, _ in pending), unit="batch",
                      disable=not progress) as bar:
                def advance(label: str) -> None:
                    bar.set_description(label)
                    bar.update()

                evaluation = Evaluation(generator, evaluator, reference, settings.options, batch_size, advance)
                for method, repeat in pending:
                    result = evaluation.multi(method, repeat) if method else evaluation.single(repeat)
                    write_json_atomically(_result_file(run_dir, method, repeat), result)
            table = _finish(run_dir, settings, testset, reference, _sampling(settings, generator))
            log_batch(client, run_id, metrics=table_metrics(table))
            for name in (TABLE_MD, TABLE_JSON, FIGURE):
                client.log_artifact(run_id, str(run_dir / name))
            client.log_artifacts(run_id, str(run_dir / RESULTS), artifact_path=RESULTS)
    except BaseException:
        write_run_info(run_dir, status="failed")
        raise
    write_run_info(run_dir, status="finished")
    mark_latest(run_dir)
    return run_dir, table


def _finish(run_dir: Path, settings: EvalSettings, testset: TestSet, reference: Reference,
            sampling: tuple[str, str | None]) -> dict[str, Any]:
    """table.json, table.md and fig5.png from the run's result files."""
    multi = {m: [_read(_result_file(run_dir, m, r)) for r in range(settings.repeats)] for m in settings.methods}
    gt_single = [reference.measure(r) for r in range(settings.repeats)]
    reconstructed = [reference.reconstruction_rows(r) for r in range(settings.repeats)]
    codec = {RECONSTRUCTION: [rows[0] for rows in reconstructed]} if reconstructed[0] else {}
    per_row = {GT_SINGLE: gt_single, GT_CONCAT: [reference.concat_row()] * settings.repeats, **codec,
               **{m: [result["metrics"] for result in results] for m, results in multi.items()}}
    table: dict[str, Any] = {
        "settings": asdict(settings),
        "testset": {"path": str(testset.path), "n": testset.n, "instances": len(testset), "items": reference.items},
        "r_precision_batch": reference.rp_batch, "window": WINDOW, "jerk_fps": JERK_FPS,
        "notes": notes(*sampling, reference), "multi": summarize_rows(per_row)}
    if settings.single:
        single = [_read(_result_file(run_dir, None, r))["metrics"] for r in range(settings.repeats)]
        columns = {metric for metric, _ in SINGLE_COLUMNS}
        codec = {RECONSTRUCTION: [rows[1] for rows in reconstructed]} if reconstructed[0] else {}
        table["single"] = summarize_rows({GT_SINGLE: [{k: v for k, v in m.items() if k in columns} for m in gt_single],
                                          **codec, GENERATED: single})
    write_json_atomically(run_dir / TABLE_JSON, table)
    (run_dir / TABLE_MD).write_text(render_table(table), encoding="utf-8")
    curves = {m: mean_profile([(np.asarray(r["profile"]["velocity"]), np.asarray(r["profile"]["jerk"]))
                               for r in results if r["profile"]["windows"]]) for m, results in multi.items()}
    if reference.reconstruction is not None:
        curves = {ROW_TITLES[RECONSTRUCTION]: mean_profile(reference.reconstruction.profiles), **curves}
    plot_fig5(run_dir / FIGURE, {ROW_TITLES[GT_CONCAT]: reference.concat_profile, **curves})
    return table
