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
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from m2d2m.evaluation.evaluator import TextMotionEvaluator, load_evaluator, load_guo_checkpoint
from m2d2m.evaluation.measurements import (EDITS, JERK_FPS, MM_GENERATIONS, MM_PROMPTS, WINDOW, Evaluation,
                                           Reference, mean_profile)
from m2d2m.generators.options import MULTI, SINGLE
from m2d2m.generators.protocol import MotionGenerator
from m2d2m.layout import MANIFEST
from orchestration.errors import UserError
from orchestration.generate import load_generator, resolve_model_file
from orchestration.registry import DEFAULT_MODEL, model, models
from orchestration.reports import (EDIT_TITLES, FIGURE, GENERATED, GT_CONCAT, GT_SINGLE, RECONSTRUCTION, ROW_TITLES,
                                   SINGLE_COLUMNS, TABLE_JSON, TABLE_MD, notes, plot_fig5, render_table, summarize_rows,
                                   table_metrics)
from orchestration.runs import find_run, mark_latest, new_run_dir, read_run_info, run_file, write_run_info
from orchestration.tracking import client as tracking_client
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
                 mirrors: str = "same", force: bool = False, limit: int | None = None,
                 split: str = "test") -> dict[str, Any]:
    """Build (or reuse) the N-action test set of a processed dataset and record it in MLflow
    (experiment ``<dataset>/testset``: its parameters, pool and instance counts, and its files,
    so an evaluation can name exactly what it ran on). Returns the summary with ``mlflow_run_id``."""
    try:
        summary = build_testset(data_dir, n=n, seed=seed, mirrors=mirrors, force=force, limit=limit, split=split)
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


def _reference(testset: TestSet, evaluator: TextMotionEvaluator,
               generators: dict[str, MotionGenerator]) -> tuple[Reference, dict[str, str]]:
    """The test set's measurements, its lengths in whole steps of every generator, and each
    generator's codec, if it has one, measured once per distinct codec; with the label each
    model's codec is measured under (models without a codec have none)."""
    segments = [[testset.features(instance.index, p) for p in range(len(instance.items))] for instance in testset]
    first = next(iter(generators.values()))
    reference = Reference.build([instance.actions for instance in testset], segments, _caption_tokens(testset),
                                evaluator, first.skeleton, math.lcm(*(g.frame_step for g in generators.values())))
    codec_of = {name: reference.add_reconstruction(name, generator, evaluator) for name, generator in generators.items()}
    return reference, {name: label for name, label in codec_of.items() if label is not None}


# ----------------------------------------------------------------------------------- settings
@dataclass(frozen=True)
class Candidate:
    """One model file under evaluation and the rows it contributes: its multi-action methods,
    sampled with its multi-action preset changed by ``options`` (for M2D2M: ts, eta, ...)."""

    model: str
    checkpoint: str
    methods: tuple[str, ...]  # none for an editor (a model that needs something to keep)
    options: dict[str, Any]
    edits: tuple[str, ...] = ()  # its tasks of the editing table


@dataclass(frozen=True)
class EvalSettings:
    """Every knob that changes the numbers. Recorded in run.json, table.json and the MLflow
    params, and fixed for a run: ``--resume`` continues with exactly these. One evaluation may
    judge several models (``candidates``) on the same test set with the same evaluator and seeds."""

    candidates: tuple[Candidate, ...]
    testset: str | None  # None: the default test set of the first model's dataset, resolved by evaluate
    evaluator: str
    glove: str | None  # Guo's published evaluator: its GloVe and meta directories
    meta: str | None
    repeats: int
    single: bool
    editing: tuple[str, ...] = ()  # tasks of the editing table (MMM Table 3), each with and without text
    multi: bool = True  # the multi-motion table's generated rows (False: single-motion or editing only)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "EvalSettings":
        """Settings as run.json holds them. Runs recorded with one model at the top level (and,
        before the model registry, the default model's knobs there too) read as one candidate."""
        values = dict(values)
        if "candidates" not in values:
            if "model" not in values:
                values["model"] = DEFAULT_MODEL
                knobs = model(DEFAULT_MODEL).load("sampling").names()
                values["options"] = {key: values.pop(key) for key in knobs if values.get(key) is not None}
            values["candidates"] = [{key: values.pop(key) for key in ("model", "checkpoint", "methods", "options")}]
        candidates = tuple(Candidate(**{**c, "methods": tuple(c["methods"]), "edits": tuple(c.get("edits", ()))})
                           for c in values.pop("candidates"))
        return cls(candidates=candidates, **{**values, "editing": tuple(values.get("editing", ()))})

    @property
    def models(self) -> tuple[str, ...]:
        return tuple(c.model for c in self.candidates)

    def row(self, candidate: Candidate, method: str) -> str:
        """The table row of a candidate's method: the method's name when one model is judged,
        ``<model>/<method>`` when several are."""
        return method if len(self.candidates) == 1 else f"{candidate.model}/{method}"

    def rows(self) -> list[tuple[Candidate, str]]:
        """Every (candidate, method) of the multi-motion table, in order."""
        return [(candidate, method) for candidate in self.candidates for method in candidate.methods]

    def single_row(self, candidate: Candidate) -> str:
        """The single-motion table's row of a candidate's generations."""
        return GENERATED if len(self.candidates) == 1 else f"{GENERATED}/{candidate.model}"

    def edit_rows(self, candidate: Candidate) -> list[tuple[str, bool, str]]:
        """The editing table's rows of a candidate: (task, with text, row)."""
        owner = "" if len(self.candidates) == 1 else f"{candidate.model}/"
        return [(task, text, f"{owner}{task}/{'text' if text else 'no_text'}")
                for task in candidate.edits for text in (True, False)]


# the settings given as options of their own (the models and sampling options are given apart)
KNOBS = ("checkpoint", "testset", "evaluator", "guo_evaluator", "glove", "meta", "methods", "repeats", "single",
         "editing", "multi")


def _given(values: Sequence[str] | str | None) -> list[str]:
    """An option's values as a list: one string, repeated options, or none."""
    return [values] if isinstance(values, str) else list(values or [])


def _split(values: Sequence[str] | str | None) -> list[str]:
    """Repeated options and/or comma lists, in order, without repeats."""
    return list(dict.fromkeys(v.strip() for value in _given(values) for v in value.split(",") if v.strip()))


def _qualified(entry: str, names: Sequence[str], separators: str) -> tuple[str | None, str]:
    """``model<sep>rest`` → (model, rest) when ``model`` is one of ``names``; else (None, entry)."""
    for separator in separators:
        head, found, rest = entry.partition(separator)
        if found and head in names:
            return head, rest
    return None, entry


def _checkpoints(names: Sequence[str], values: Sequence[str] | str | None) -> dict[str, str]:
    """Each model's checkpoint reference (default ``latest``) from ``REF`` (one model) or
    ``MODEL=REF`` entries."""
    given = {}
    for value in _given(values):
        owner, reference = _qualified(value, names, "=")
        if owner is None:
            if len(names) > 1:
                raise UserError(f"--checkpoint {value}: with several models say whose, as MODEL=REF "
                                f"(models: {', '.join(names)})")
            owner = names[0]
        if owner in given:
            raise UserError(f"--checkpoint: {owner} given twice")
        given[owner] = reference
    return {name: given.get(name, "latest") for name in names}


def _named(generator: type[MotionGenerator], of: str) -> tuple[str, ...]:
    """A generator's methods or knobs (``of``)."""
    return generator.sampling.methods if of == "methods" else generator.sampling.names()


def _choices(generators: dict[str, type[MotionGenerator]], of: str) -> str:
    """The methods or knobs (``of``) there are: a list for one model, per model for several."""
    listed = {name: ", ".join(_named(g, of)) for name, g in generators.items()}
    return next(iter(listed.values())) if len(listed) == 1 else "; ".join(f"{n}: {c}" for n, c in listed.items())


def _assign(entries: dict[str, Any], generators: dict[str, type[MotionGenerator]], of: str,
            separators: str) -> dict[str, dict[str, Any]]:
    """Method or knob (``of``) entries to the models they belong to: an entry ``name`` to every
    model that has it, ``model<separator>name`` to that model alone."""
    chosen: dict[str, dict[str, Any]] = {model_name: {} for model_name in generators}
    for entry, value in entries.items():
        owner, name = _qualified(entry, list(generators), separators)
        has = {model_name: name in _named(g, of) for model_name, g in generators.items()}
        owners = [owner] if owner else [model_name for model_name, yes in has.items() if yes]
        if not owners or not has[owners[0]]:
            whose = owner or " or ".join(generators)
            raise UserError(f"unknown method {name!r} for {whose}; choose from {_choices(generators, of)}"
                            if of == "methods" else
                            f"{whose} has no sampling option {name!r}; its options: {_choices(generators, of)}")
        for model_name in owners:
            chosen[model_name][name] = value
    return chosen


def _methods(values: Sequence[str] | None, generators: dict[str, type[MotionGenerator]]) -> dict[str, tuple[str, ...]]:
    """Each model's methods from ``method`` entries (every model that has it) and ``model:method``
    or ``model/method`` ones (that model); a model named by no entry gets its default method, an
    editor none (it cannot generate from text alone)."""
    makers = {name: g for name, g in generators.items() if g.needs_keep is None}
    entries = _split(values)
    for entry in entries:
        owner, _ = _qualified(entry, list(generators), ":/")
        if owner is not None and owner not in makers:
            raise UserError(f"{owner} edits motions and has no multi-action method; {generators[owner].needs_keep}")
    chosen = _assign(dict.fromkeys(entries), makers, "methods", ":/") if makers else {}
    return {name: tuple(chosen[name] or generators[name].sampling.methods[:1]) if name in makers else ()
            for name in generators}


def _edits(tasks: tuple[str, ...], generators: dict[str, type[MotionGenerator]]) -> dict[str, tuple[str, ...]]:
    """Each model's tasks of the editing table: those it can do."""
    unknown = sorted(set(tasks) - set(EDITS))
    if unknown:
        raise UserError(f"unknown editing task {unknown[0]!r}; choose from {', '.join(EDITS)}")
    chosen = {name: tuple(task for task in tasks if task in g.edits) for name, g in generators.items()}
    for task in tasks:
        if not any(task in edits for edits in chosen.values()):
            able = [name for name in models() if task in model(name).load("generator").edits]
            raise UserError(f"no model given can do the editing task {task!r}; "
                            + (f"{', '.join(able)} can" if able else "no registered model can"))
    for name, g in generators.items():
        if g.needs_keep is not None and not chosen[name]:
            raise UserError(f"{name} edits motions and cannot generate from text alone, which the multi-motion "
                            f"table asks for; judge it in the editing table: --edit {', '.join(g.edits)}")
    return chosen


def _options(options: dict[str, Any], generators: dict[str, type[MotionGenerator]]) -> dict[str, dict[str, Any]]:
    """Each model's sampling options from ``knob`` entries (every model that has the knob) and
    ``model.knob`` ones (that model)."""
    return _assign(options, generators, "knobs", ".")


def new_settings(dataset: str, model_name: str | Sequence[str] = DEFAULT_MODEL,
                 checkpoint: str | Sequence[str] | None = None, testset: str | None = None,
                 evaluator: str | None = None, guo_evaluator: str | None = None, glove: str | None = None,
                 meta: str | None = None, methods: Sequence[str] | None = None, options: dict[str, Any] | None = None,
                 repeats: int = 10, single: bool = False, editing: Sequence[str] | None = None,
                 multi: bool = True) -> EvalSettings:
    """The settings of a new evaluation of one model or several (``model_name``: a name, a
    comma list or a list; ``checkpoint``: ``REF`` or ``MODEL=REF`` entries, ``latest`` for a
    model not named), with references resolved to files (so that a later ``latest``
    cannot change what a resumed run measures). Defaults: each model's first method, its
    multi-action preset (the paper's T_s = 0.9·T, η = 0.25, s = 2 for M2D2M), 10 repeats."""
    names = _split(model_name)
    if not names:
        raise UserError("--model: no model given")
    generators = {name: model(name).load("generator") for name in names}
    if repeats < 1:
        raise UserError(f"--repeats must be at least 1, got {repeats}")
    tasks = tuple(_split(editing))
    if not (multi or single or tasks):
        raise UserError("--no-multi leaves nothing to evaluate: add --single or --edit TASK")
    chosen_edits = _edits(tasks, generators)
    checkpoints = _checkpoints(names, checkpoint)
    chosen_methods, chosen_options = _methods(methods, generators), _options(dict(options or {}), generators)
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
    candidates = tuple(Candidate(name, str(resolve_model_file(name, checkpoints[name], dataset).resolve()),
                                 chosen_methods[name], chosen_options[name], chosen_edits[name]) for name in names)
    return EvalSettings(candidates=candidates, testset=None if testset is None else str(Path(testset).resolve()),
                        evaluator=str(evaluator_path), glove=glove, meta=meta, repeats=int(repeats),
                        single=bool(single), editing=tasks, multi=bool(multi))


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
@dataclass(frozen=True)
class Job:
    """One result file's worth of work: a candidate's row of one table in one repeat."""

    candidate: Candidate
    table: str  # "multi", "single" or "editing"
    row: str  # the table's row (the candidate's only one in the single-motion table)
    repeat: int
    method: str | None = None  # multi: the method
    task: str | None = None  # editing: the task and whether with text
    text: bool = True

    @property
    def batches(self) -> str:
        """Which batch count of :func:`evaluate`'s progress bar a job advances by."""
        return "multi" if self.table == "multi" else "items" if self.table == "editing" else "single"


def _jobs(settings: EvalSettings) -> list[Job]:
    jobs = [Job(c, "multi", settings.row(c, m), r, method=m) for c, m in settings.rows() for r in range(settings.repeats)
            if settings.multi]
    if settings.single:
        jobs += [Job(c, "single", settings.single_row(c), r) for c in settings.candidates if c.methods
                 for r in range(settings.repeats)]
    return jobs + [Job(c, "editing", row, r, task=task, text=text) for c in settings.candidates
                   for task, text, row in settings.edit_rows(c) for r in range(settings.repeats)]


def _result_file(run_dir: Path, job: Job) -> Path:
    """results/multi-<row>-r<repeat>.json, single-[<model>-]r<repeat>.json, edit-<row>-r<repeat>.json."""
    if job.table == "single":
        owner = "" if job.row == GENERATED else f"{job.candidate.model}-"
        return run_dir / RESULTS / f"single-{owner}r{job.repeat}.json"
    prefix = "edit" if job.table == "editing" else "multi"
    return run_dir / RESULTS / f"{prefix}-{job.row.replace('/', '-')}-r{job.repeat}.json"


def _read(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text(encoding="utf-8"))


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


def _sampling(settings: EvalSettings, generators: dict[str, MotionGenerator]) -> dict[str, Sampling]:
    samplings = {}
    for candidate in settings.candidates:
        generator = generators[candidate.model]
        preset = {"preset": MULTI, "method": candidate.methods[0]} if candidate.methods else {"preset": SINGLE}
        multi = generator.describe(generator.options(**preset, **candidate.options))
        single = generator.describe(generator.options(SINGLE, **candidate.options)) if settings.single else None
        samplings[candidate.model] = Sampling(multi, single)
    return samplings


def _candidate_params(candidate: Candidate, sampling: Sampling) -> dict[str, Any]:
    return {"model": candidate.model, "checkpoint": candidate.checkpoint, "methods": ",".join(candidate.methods),
            **candidate.options, "sampling": sampling.multi, "single_sampling": sampling.single}


def _params(settings: EvalSettings, samplings: dict[str, Sampling]) -> dict[str, Any]:
    """The MLflow params: the shared settings, and each candidate's — under their own names for
    one model, prefixed ``<model>.`` for several (each child run has them unprefixed)."""
    shared = {key: value for key, value in asdict(settings).items() if key != "candidates"}
    if len(settings.candidates) == 1:
        only = settings.candidates[0]
        return {**shared, **_candidate_params(only, samplings[only.model])}
    prefixed = {f"{c.model}.{key}": value for c in settings.candidates
                for key, value in _candidate_params(c, samplings[c.model]).items() if key != "model"}
    return {**shared, "model": ",".join(settings.models), **prefixed}


def _start(settings: EvalSettings, dataset: str, samplings: dict[str, Sampling], testset: TestSet, rp_batch: int,
           parent: ParentRun | None = None) -> Path:
    """A new run directory and its MLflow run (experiment ``<dataset>/eval``, or a child run of
    ``parent`` in the parent's experiment) with every knob."""
    run_dir = new_run_dir(dataset, EVAL_STAGE)
    methods = ",".join(settings.row(c, m) for c, m in settings.rows())
    tags = {"dataset": dataset, "stage": EVAL_STAGE, "model": ",".join(settings.models), "methods": methods,
            "run_dir": str(run_dir.resolve())}
    params = {**_params(settings, samplings), "n": testset.n, "instances": len(testset), "window": WINDOW,
              "jerk_fps": JERK_FPS, "r_precision_batch": rp_batch}
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


def _check(settings: EvalSettings, generators: dict[str, MotionGenerator], testset: TestSet,
           evaluator: TextMotionEvaluator) -> None:
    """Refuse, before anything runs, what cannot give a table."""
    dims = {f"the model {name}" if len(generators) > 1 else "the model": g.feature_dim for name, g in generators.items()}
    for owner, dim in {**dims, "the evaluator": evaluator.config.feature_dim}.items():
        if testset.manifest.get("feature_dim") != dim:
            raise UserError(f"{testset.path} holds {testset.manifest.get('feature_dim')}-d features but {owner} "
                            f"works on {dim}-d ones: use a test set of the same dataset")
    skeletons = {name: g.skeleton.name for name, g in generators.items()}
    if len(set(skeletons.values())) > 1:
        raise UserError("the models are on different skeletons (" + ", ".join(f"{n}: {s}" for n, s in skeletons.items())
                        + "); judge models of one dataset together")
    if testset.n < 2 or len(testset) < 2:
        raise UserError(f"{testset.path}: multi-motion evaluation needs N >= 2 actions and at least 2 instances "
                        f"(it has N = {testset.n}, {len(testset)} instances)")
    try:
        for candidate, method in settings.rows():
            generators[candidate.model].options(MULTI, method=method, **candidate.options)
    except ValueError as error:
        raise UserError(str(error)) from error


def evaluate(settings: EvalSettings, dataset: str = "synthetic", run_dir: Path | None = None,
             batch_size: int = 64, parent: ParentRun | None = None,
             progress: bool = True) -> tuple[Path, dict[str, Any]]:
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
        settings = replace(settings, testset=str(_default_testset(first, dataset).resolve()))
    testset = _open_testset(settings.testset)
    evaluator = _load_evaluator(settings, next(iter(generators.values())).device)
    _check(settings, generators, testset, evaluator)
    reference, codec_of = _reference(testset, evaluator, generators)
    samplings = _sampling(settings, generators)
    if run_dir is None:
        run_dir = _start(settings, dataset, samplings, testset, reference.rp_batch, parent)
    (run_dir / RESULTS).mkdir(exist_ok=True)
    pending = [job for job in _jobs(settings) if not _result_file(run_dir, job).exists()]
    run_id = read_run_info(run_dir)["mlflow_run_id"]
    batches = {"multi": -(-len(reference.actions) // batch_size), "items": -(-reference.items // batch_size),
               "single": -(-reference.items // batch_size)
               + -(-min(MM_PROMPTS, reference.items) * MM_GENERATIONS // batch_size)}
    try:
        with finishing(run_id) as client:
            with tqdm(total=sum(batches[job.batches] for job in pending), unit="batch",
                      disable=not progress) as bar:
                def advance(label: str) -> None:
                    bar.set_description(label)
                    bar.update()

                evaluations = {c.model: Evaluation(generators[c.model], evaluator, reference, c.options, batch_size,
                                                   advance) for c in settings.candidates}
                for job in pending:
                    evaluation = evaluations[job.candidate.model]
                    result = (evaluation.multi(job.method, job.repeat) if job.table == "multi" else
                              evaluation.single(job.repeat) if job.table == "single" else
                              evaluation.edit(job.task, job.text, job.repeat))
                    write_json_atomically(_result_file(run_dir, job), result)
            table = _finish(run_dir, settings, testset, reference, codec_of, samplings)
            log_batch(client, run_id, metrics=table_metrics(table))
            for name in (TABLE_MD, TABLE_JSON, FIGURE):
                client.log_artifact(run_id, str(run_dir / name))
            client.log_artifacts(run_id, str(run_dir / RESULTS), artifact_path=RESULTS)
            if len(settings.candidates) > 1:
                _log_children(run_dir, settings, samplings, table, dataset)
    except BaseException:
        write_run_info(run_dir, status="failed")
        raise
    write_run_info(run_dir, status="finished")
    mark_latest(run_dir)
    return run_dir, table


def _log_children(run_dir: Path, settings: EvalSettings, samplings: dict[str, Sampling], table: dict[str, Any],
                  dataset: str) -> None:
    """One child run per candidate, named by its model, holding its params and its rows' metrics
    as a one-model evaluation names them (``multi/<method>/<metric>``, ``single/<metric>``,
    ``edit/<task>/<text|no_text>/<metric>``, the ground-truth rows, its codec's reconstruction
    rows). A resumed run reuses its children."""
    info = read_run_info(run_dir)
    children = dict(info.get("children", {}))
    parent_id, experiment_id = info["mlflow_run_id"], tracking_client().get_run(info["mlflow_run_id"]).info.experiment_id
    for candidate in settings.candidates:
        codec = table["codecs"].get(candidate.model)
        shared = {row: values for row, values in table["multi"].items() if row in (GT_SINGLE, GT_CONCAT)}
        one = {"multi": {**shared, **({RECONSTRUCTION: table["multi"][codec]} if codec else {}),
                         **{method: table["multi"][settings.row(candidate, method)] for method in candidate.methods
                            if settings.multi}}}
        if "single" in table and candidate.methods:
            one["single"] = {GENERATED: table["single"][settings.single_row(candidate)],
                             **({RECONSTRUCTION: table["single"][codec]} if codec else {})}
        if "editing" in table:
            one["editing"] = {row.removeprefix(f"{candidate.model}/"): table["editing"][row]
                              for _, _, row in settings.edit_rows(candidate)}
        if candidate.model not in children:
            tags = {"dataset": dataset, "stage": EVAL_STAGE, "model": candidate.model,
                    "methods": ",".join(candidate.methods)}
            children[candidate.model] = start_run(experiment_name(dataset, EVAL_STAGE), candidate.model, tags,
                                                  _candidate_params(candidate, samplings[candidate.model]),
                                                  (experiment_id, parent_id))
            write_run_info(run_dir, children=children)
        with finishing(children[candidate.model]) as client:
            log_batch(client, children[candidate.model], metrics=table_metrics(one))


def _titles(settings: EvalSettings, codec_rows: dict[str, str]) -> dict[str, str]:
    """Row titles beyond :data:`ROW_TITLES`: editing rows, and with several models each row's model."""
    several = len(settings.candidates) > 1
    owner = {c.model: f"{c.model} " if several else "" for c in settings.candidates}
    titles = {row: f"{owner[c.model]}{EDIT_TITLES[task]} ({'w/' if text else 'w/o'} text)"
              for c in settings.candidates for task, text, row in settings.edit_rows(c)}
    if several:
        titles |= {settings.row(c, m): f"{c.model} {m}" for c, m in settings.rows()}
        titles |= {settings.single_row(c): f"{c.model} (single action)" for c in settings.candidates}
        titles |= {row: f"{ROW_TITLES[RECONSTRUCTION]} ({', '.join(m for m, r in codec_rows.items() if r == row)})"
                   for row in set(codec_rows.values())}
    return titles


def _finish(run_dir: Path, settings: EvalSettings, testset: TestSet, reference: Reference, codec_of: dict[str, str],
            samplings: dict[str, Sampling]) -> dict[str, Any]:
    """table.json, table.md and fig5.png from the run's result files."""
    several = len(settings.candidates) > 1
    results: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for job in _jobs(settings):
        results.setdefault((job.table, job.row), []).append(_read(_result_file(run_dir, job)))
    metrics = {key: [result["metrics"] for result in found] for key, found in results.items()}
    codecs = {label: [reference.reconstruction_rows(label, r) for r in range(settings.repeats)]
              for label in reference.reconstructions}
    codec_row = {label: f"{RECONSTRUCTION}/{label}" if len(codecs) > 1 else RECONSTRUCTION for label in codecs}
    owners = {name: codec_row[label] for name, label in codec_of.items()}
    titles = _titles(settings, owners)
    gt_single = [reference.measure(r) for r in range(settings.repeats)]
    columns = {metric for metric, _ in SINGLE_COLUMNS}
    gt_items = [{k: v for k, v in m.items() if k in columns} for m in gt_single]
    items_through_codecs = {codec_row[label]: [rows[1] for rows in repeats] for label, repeats in codecs.items()}
    sampling_note = "; ".join(f"{name}: {s.multi}" if several else s.multi for name, s in samplings.items())
    single_note = "; ".join(f"{name}: {s.single}" if several else str(s.single) for name, s in samplings.items())
    table: dict[str, Any] = {
        "settings": asdict(settings),
        "testset": {"path": str(testset.path), "n": testset.n, "instances": len(testset), "items": reference.items},
        "r_precision_batch": reference.rp_batch, "window": WINDOW, "jerk_fps": JERK_FPS,
        "notes": notes(sampling_note, single_note if settings.single else None, reference),
        "titles": titles, "codecs": owners,
        "multi": summarize_rows({GT_SINGLE: gt_single, GT_CONCAT: [reference.concat_row()] * settings.repeats,
                                 **{codec_row[label]: [rows[0] for rows in repeats] for label, repeats in codecs.items()},
                                 **{row: found for (kind, row), found in metrics.items() if kind == "multi"}})}
    for kind in ("single", "editing"):
        rows = {row: found for (owner, row), found in metrics.items() if owner == kind}
        if rows:
            table[kind] = summarize_rows({GT_SINGLE: gt_items, **items_through_codecs, **rows})
    write_json_atomically(run_dir / TABLE_JSON, table)
    (run_dir / TABLE_MD).write_text(render_table(table), encoding="utf-8")
    curves = {titles.get(row, row): mean_profile([(np.asarray(r["profile"]["velocity"]), np.asarray(r["profile"]["jerk"]))
                                                  for r in found if r["profile"]["windows"]])
              for (kind, row), found in results.items() if kind == "multi"}
    reconstructed = {titles.get(codec_row[label], ROW_TITLES[RECONSTRUCTION]): mean_profile(codec.measures.profiles)
                     for label, codec in reference.reconstructions.items()}
    plot_fig5(run_dir / FIGURE, {ROW_TITLES[GT_CONCAT]: reference.concat_profile, **reconstructed, **curves})
    return table
