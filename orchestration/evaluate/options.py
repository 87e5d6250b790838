"""`m2d2m evaluate`'s model-related options read for several models at once: checkpoints as
``REF`` or ``MODEL=REF``, methods as ``method`` or ``model:method``, sampling options as ``knob``
or ``model.knob``, editing tasks; each checked against what the models' generators declare."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from m2d2m.evaluation.measurements import EDITS
from m2d2m.generators.protocol import MotionGenerator
from orchestration.errors import UserError
from orchestration.registry import model, models


def _given(values: Sequence[str] | str | None) -> list[str]:
    """An option's values as a list: one string, repeated options, or none."""
    return [values] if isinstance(values, str) else list(values or [])


def split_list(values: Sequence[str] | str | None) -> list[str]:
    """Repeated options and/or comma lists, in order, without repeats."""
    return list(dict.fromkeys(v.strip() for value in _given(values) for v in value.split(",") if v.strip()))


def _qualified(entry: str, names: Sequence[str], separators: str) -> tuple[str | None, str]:
    """``model<sep>rest`` → (model, rest) when ``model`` is one of ``names``; else (None, entry)."""
    for separator in separators:
        head, found, rest = entry.partition(separator)
        if found and head in names:
            return head, rest
    return None, entry


def parse_checkpoints(names: Sequence[str], values: Sequence[str] | str | None) -> dict[str, str]:
    """Each model's checkpoint reference (default ``latest``) from ``REF`` (one model) or
    ``MODEL=REF`` entries."""
    given = {}
    for value in _given(values):
        owner, reference = _qualified(value, names, "=")
        if owner is None:
            if len(names) > 1:
                raise UserError(
                    f"--checkpoint {value}: with several models say whose, as MODEL=REF (models: {', '.join(names)})"
                )
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


def _assign(
    entries: dict[str, Any], generators: dict[str, type[MotionGenerator]], of: str, separators: str
) -> dict[str, dict[str, Any]]:
    """Method or knob (``of``) entries to the models they belong to: an entry ``name`` to every
    model that has it, ``model<separator>name`` to that model alone."""
    chosen: dict[str, dict[str, Any]] = {model_name: {} for model_name in generators}
    for entry, value in entries.items():
        owner, name = _qualified(entry, list(generators), separators)
        has = {model_name: name in _named(g, of) for model_name, g in generators.items()}
        owners = [owner] if owner else [model_name for model_name, yes in has.items() if yes]
        if not owners or not has[owners[0]]:
            whose = owner or " or ".join(generators)
            raise UserError(
                f"unknown method {name!r} for {whose}; choose from {_choices(generators, of)}"
                if of == "methods"
                else f"{whose} has no sampling option {name!r}; its options: {_choices(generators, of)}"
            )
        for model_name in owners:
            chosen[model_name][name] = value
    return chosen


def assign_methods(
    values: Sequence[str] | None, generators: dict[str, type[MotionGenerator]]
) -> dict[str, tuple[str, ...]]:
    """Each model's methods from ``method`` entries (every model that has it) and ``model:method``
    or ``model/method`` ones (that model); a model named by no entry gets its default method, an
    editor none (it cannot generate from text alone)."""
    makers = {name: g for name, g in generators.items() if g.needs_keep is None}
    entries = split_list(values)
    for entry in entries:
        owner, _ = _qualified(entry, list(generators), ":/")
        if owner is not None and owner not in makers:
            raise UserError(f"{owner} edits motions and has no multi-action method; {generators[owner].needs_keep}")
    chosen = _assign(dict.fromkeys(entries), makers, "methods", ":/") if makers else {}
    return {
        name: tuple(chosen[name] or generators[name].sampling.methods[:1]) if name in makers else ()
        for name in generators
    }


def assign_edits(tasks: tuple[str, ...], generators: dict[str, type[MotionGenerator]]) -> dict[str, tuple[str, ...]]:
    """Each model's tasks of the editing table: those it can do."""
    unknown = sorted(set(tasks) - set(EDITS))
    if unknown:
        raise UserError(f"unknown editing task {unknown[0]!r}; choose from {', '.join(EDITS)}")
    chosen = {name: tuple(task for task in tasks if task in g.edits) for name, g in generators.items()}
    for task in tasks:
        if not any(task in edits for edits in chosen.values()):
            able = [name for name in models() if task in model(name).load("generator").edits]
            raise UserError(
                f"no model given can do the editing task {task!r}; "
                + (f"{', '.join(able)} can" if able else "no registered model can")
            )
    for name, g in generators.items():
        if g.needs_keep is not None and not chosen[name]:
            raise UserError(
                f"{name} edits motions and cannot generate from text alone, which the multi-motion "
                f"table asks for; judge it in the editing table: --edit {', '.join(g.edits)}"
            )
    return chosen


def assign_options(options: dict[str, Any], generators: dict[str, type[MotionGenerator]]) -> dict[str, dict[str, Any]]:
    """Each model's sampling options from ``knob`` entries (every model that has the knob) and
    ``model.knob`` ones (that model)."""
    return _assign(options, generators, "knobs", ".")
