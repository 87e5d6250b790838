"""An evaluation's settings: every knob that changes the numbers, resolved from an
:class:`~orchestration.evaluate.request.EvalRequest` to files when a run starts and fixed for it
(``--resume`` continues with exactly these), and read back from a run's record."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from m2d2m.layout import recorded_path, relative_to_project
from orchestration.errors import UserError
from orchestration.evaluate.options import assign_edits, assign_methods, assign_options, parse_checkpoints, split_list
from orchestration.evaluate.request import EvalRequest, given_flags
from orchestration.generate.loading import resolve_model_file
from orchestration.registry import model
from orchestration.reports import GENERATED
from orchestration.runs import EVALUATOR_FILE, EVALUATOR_STAGE, find_run, read_run_info, run_file

EVAL_STAGE = "eval"


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
    regenerate: int | None = None  # the timeline-editing table's action, counted from 1 (issue 41)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> EvalSettings:
        """Settings as run.json holds them (:func:`dataclasses.asdict` of them)."""
        values = dict(values)
        candidates = tuple(
            Candidate(**{**c, "methods": tuple(c["methods"]), "edits": tuple(c["edits"])})
            for c in values.pop("candidates")
        )
        return cls(candidates=candidates, **{**values, "editing": tuple(values["editing"])})

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

    def regenerate_row(self, candidate: Candidate) -> str:
        """The timeline-editing table's row stem of a candidate: ``<stem>/edit`` and ``<stem>/whole``."""
        owner = "" if len(self.candidates) == 1 else f"{candidate.model}/"
        return f"{owner}regenerate{self.regenerate}"

    def edit_rows(self, candidate: Candidate) -> list[tuple[str, bool, str]]:
        """The editing table's rows of a candidate: (task, with text, row)."""
        owner = "" if len(self.candidates) == 1 else f"{candidate.model}/"
        return [
            (task, text, f"{owner}{task}/{'text' if text else 'no_text'}")
            for task in candidate.edits
            for text in (True, False)
        ]


def new_settings(dataset: str, request: EvalRequest) -> EvalSettings:
    """The settings of a new evaluation of the models ``request`` names (``latest`` for a model
    whose checkpoint it does not name), with references resolved to files (so that a later
    ``latest`` cannot change what a resumed run measures). Defaults: each model's first method, its
    multi-action preset (the paper's T_s = 0.9·T, η = 0.25, s = 2 for M2D2M), 10 repeats.
    ``regenerate``: also the timeline-editing table, that action of each instance sampled again."""
    names = split_list(request.models)
    if not names:
        raise UserError("--model: no model given")
    generators = {name: model(name).load("generator") for name in names}
    if request.repeats < 1:
        raise UserError(f"--repeats must be at least 1, got {request.repeats}")
    tasks = tuple(split_list(request.editing))
    regenerate = request.regenerate
    if not (request.multi or request.single or tasks or regenerate):
        raise UserError("--no-multi leaves nothing to evaluate: add --single, --edit TASK or --regenerate K")
    if regenerate is not None and regenerate < 1:
        raise UserError(f"--regenerate counts actions from 1, got {regenerate}")
    chosen_edits = assign_edits(tasks, generators)
    checkpoints = parse_checkpoints(names, request.checkpoints)
    chosen_methods, chosen_options = (
        assign_methods(request.methods, generators),
        assign_options(dict(request.options), generators),
    )
    glove, meta = request.glove, request.meta
    if request.guo_evaluator is not None:
        if request.evaluator is not None:
            raise UserError("give --evaluator or --guo-evaluator, not both")
        if glove is None:
            raise UserError("--guo-evaluator needs --glove DIR (text-to-motion's glove/ directory)")
        evaluator_path = Path(request.guo_evaluator)
        meta = relative_to_project(meta or evaluator_path / "meta")
        glove = relative_to_project(glove)
    else:
        if glove is not None or meta is not None:
            raise UserError("--glove and --meta go with --guo-evaluator")
        evaluator_path = run_file(
            request.evaluator or "latest", dataset, EVALUATOR_STAGE, EVALUATOR_FILE, "make train-evaluator"
        )
    candidates = tuple(
        Candidate(
            name,
            relative_to_project(resolve_model_file(name, checkpoints[name], dataset)),
            chosen_methods[name],
            chosen_options[name],
            chosen_edits[name],
        )
        for name in names
    )
    return EvalSettings(
        candidates=candidates,
        testset=None if request.testset is None else relative_to_project(request.testset),
        evaluator=relative_to_project(evaluator_path),
        glove=glove,
        meta=meta,
        repeats=int(request.repeats),
        single=bool(request.single),
        editing=tasks,
        multi=bool(request.multi),
        regenerate=regenerate,
    )


def settings_to_run(
    dataset: str, given: Mapping[str, Any], resume: str | None = None
) -> tuple[Path | None, EvalSettings]:
    """What `m2d2m evaluate` runs: the run ``resume`` names with its own settings (an option given
    beside it is one line: it could not change them), or a new run's settings from the fields of an
    :class:`EvalRequest` given (``given``: only those), without a run directory yet."""
    if not resume:
        return None, new_settings(dataset, EvalRequest(**given))
    if given:
        raise UserError(f"--resume continues {resume} with its own settings; drop {', '.join(given_flags(given))}")
    return reopen(resume, dataset)


def reopen(reference: str, dataset: str) -> tuple[Path, EvalSettings]:
    """An earlier evaluation run (directory, name or MLflow id) and its settings, to resume."""
    run_dir = find_run(reference, dataset, EVAL_STAGE)
    settings = EvalSettings.from_dict(read_run_info(run_dir)["settings"])
    return run_dir, _located(settings, run_dir)


def _located(settings: EvalSettings, run_dir: Path) -> EvalSettings:
    """The files an evaluation run's settings name, found from its project
    (:func:`m2d2m.layout.recorded_path`), so that a moved project resumes its own runs."""

    def here(recorded: str | None) -> str | None:
        return None if recorded is None else str(recorded_path(recorded, run_dir))

    return replace(
        settings,
        candidates=tuple(replace(c, checkpoint=here(c.checkpoint)) for c in settings.candidates),
        testset=here(settings.testset),
        evaluator=here(settings.evaluator),
        glove=here(settings.glove),
        meta=here(settings.meta),
    )
