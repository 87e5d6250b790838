"""What `m2d2m evaluate` is asked, declared once: each field of :class:`EvalRequest` is one option
of the command line (its :class:`Flag`, from which the command line builds the option) and one
input of :func:`orchestration.evaluate.settings.new_settings`, which resolves them into the run's
settings. This module loads without torch: the command line builds its parser from it."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

from orchestration.registry import DEFAULT_MODEL, methods_of_models, models

FLAG = "flag"  # the metadata key of a field's Flag
DEFAULT_REPEATS = 10


@dataclass(frozen=True)
class Flag:
    """A field of :class:`EvalRequest` as a command-line option."""

    name: str
    help: str | Callable[[], str]  # a function where the text lists the models registered (plugins included)
    metavar: str | None = None  # None: the field's name in capitals
    positive: bool = False  # refused below 1 when the command line is read, before anything loads

    def text(self) -> str:
        """The help as shown."""
        return self.help() if callable(self.help) else self.help


def _flag(name: str, help: str | Callable[[], str], metavar: str | None = None, positive: bool = False) -> dict:
    return {FLAG: Flag(name, help, metavar, positive)}


@dataclass(frozen=True)
class EvalRequest:
    """The models to judge and everything that changes their numbers, as the user gives them:
    lists as repeated options and/or comma lists, checkpoints as ``REF`` or ``MODEL=REF``, methods as
    ``method`` or ``model:method``, sampling options as ``knob`` or ``model.knob`` (docs/evaluation.md).
    A field not given keeps its default. ``options`` has no flag of its own: the sampling options'
    flags (``--option KEY=VALUE`` and the models' shortcuts) fill it."""

    models: Sequence[str] = field(
        default=(DEFAULT_MODEL,),
        metadata=_flag(
            "--model",
            lambda: (
                f"registered models to judge side by side in one table: {', '.join(models())}; "
                f"repeatable or a comma list (default {DEFAULT_MODEL})"
            ),
            "MODEL",
        ),
    )
    checkpoints: Sequence[str] = field(
        default=(),
        metadata=_flag(
            "--checkpoint",
            "the model's file, a run directory or name, or an MLflow run id (default: latest); "
            "with several models MODEL=REF, once per model",
            "REF",
        ),
    )
    testset: str | None = field(
        default=None,
        metadata=_flag(
            "--testset",
            "test set directory (default: n4-seed0 of the model's dataset, "
            "data/<dataset>/testsets/n4-seed0, built if missing)",
        ),
    )
    evaluator: str | None = field(
        default=None,
        metadata=_flag(
            "--evaluator",
            "evaluator.pt, or an evaluator run directory, name or MLflow run id "
            "(default: latest; `make train-evaluator` makes one)",
        ),
    )
    guo_evaluator: str | None = field(
        default=None,
        metadata=_flag(
            "--guo-evaluator",
            "Guo et al.'s published evaluator (text_mot_match/), for published-comparable numbers",
            "CKPT_DIR",
        ),
    )
    glove: str | None = field(
        default=None, metadata=_flag("--glove", "Guo's glove/ directory (with --guo-evaluator)", "DIR")
    )
    meta: str | None = field(
        default=None, metadata=_flag("--meta", "the evaluator's mean.npy/std.npy (default CKPT_DIR/meta)", "DIR")
    )
    methods: Sequence[str] = field(
        default=(),
        metadata=_flag(
            "--method",
            lambda: (
                f"multi-action methods ({methods_of_models()}), each for every model that has it, or "
                "MODEL:METHOD for one; repeatable or a comma list (default: each model's first)"
            ),
            "METHOD",
        ),
    )
    options: Mapping[str, Any] = field(default_factory=dict)
    repeats: int = field(
        default=DEFAULT_REPEATS,
        metadata=_flag("--repeats", f"evaluations to average, seeds 0..R-1 (default {DEFAULT_REPEATS})"),
    )
    multi: bool = field(
        default=True,
        metadata=_flag(
            "--multi",
            "the multi-motion table's generated rows (default on; --no-multi with --single "
            "judges single actions alone, as a learning curve does)",
        ),
    )
    single: bool = field(
        default=False,
        metadata=_flag(
            "--single",
            "also the single-motion table (paper Table 3; the model's single-action preset, for m2d2m s = 4, η = 0.5)",
        ),
    )
    editing: Sequence[str] = field(
        default=(),
        metadata=_flag(
            "--edit",
            "also the editing table (MMM Table 3) for these tasks, each with and without text: "
            "inbetween (the middle 50 % given the first and last 25 %), upper (the upper body "
            "given the lower; mmm-body); repeatable or a comma list",
            "TASK",
        ),
    )
    regenerate: int | None = field(
        default=None,
        metadata=_flag(
            "--regenerate",
            "also the timeline-editing table: action K of every instance sampled again by an edit that keeps "
            "the rest, against the whole sequence sampled again (R-Top3, FID, transition FID, Jerk)",
            "K",
            positive=True,
        ),
    )


def given_flags(given: Mapping[str, Any]) -> list[str]:
    """The options that gave these fields of a request, in the request's order (a sampling
    option as ``--<knob>``)."""
    flags = []
    for declared in fields(EvalRequest):
        if declared.name not in given:
            continue
        if FLAG in declared.metadata:
            flags.append(declared.metadata[FLAG].name)
        else:
            flags += ["--" + knob.replace("_", "-") for knob in given[declared.name]]
    return flags
