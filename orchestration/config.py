"""Stage configs: a YAML file under ``configs/<stage>/`` plus ``--set key.sub=value`` overrides.

A file is checked against the stage's other configs in ``configs/<stage>/`` (a key none of them
has is a typo, a key all of them have is required), and every override against the file's own
keys, so a typo is an error that names the key before any work starts, never a setting that
silently does nothing or a ``KeyError`` mid-run (docs/training.md, "Configs").
"""

from __future__ import annotations

import copy
import difflib
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import yaml

from orchestration.errors import NotInProject, UserError

CONFIG_ROOT = Path("configs")


def resolve_config_path(stage: str, name_or_path: str) -> Path:
    """``demo`` → ``configs/<stage>/demo.yaml``; an existing path is taken as it is."""
    path = Path(name_or_path)
    if path.suffix in (".yaml", ".yml") and path.exists():
        return path
    candidate = CONFIG_ROOT / stage / f"{name_or_path}.yaml"
    if candidate.exists():
        return candidate
    available = sorted(p.stem for p in (CONFIG_ROOT / stage).glob("*.yaml"))
    raise NotInProject(f"no config {name_or_path!r} for {stage}; available: {', '.join(available) or 'none'}")


def yaml_problem(error: yaml.YAMLError) -> str:
    """PyYAML's several-line message as one line: what is wrong and where."""
    mark = getattr(error, "problem_mark", None)
    problem = getattr(error, "problem", None) or str(error).splitlines()[0]
    return f"{problem} at line {mark.line + 1}, column {mark.column + 1}" if mark else problem


def read_override(text: str) -> tuple[list[str], Any]:
    """``key.sub=value`` as its key path and its value read as YAML; a malformed one is a
    ValueError saying what is wrong, for the flag that reads it to report (``--set``, ``--option``)."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise ValueError("expected key.sub=value")
    try:
        parsed = yaml.safe_load(value) if value.strip() else ""
    except yaml.YAMLError as error:
        raise ValueError(f"the value is not valid YAML ({yaml_problem(error)})") from error
    if isinstance(parsed, str):
        try:  # YAML 1.1 reads 1e-3 (no dot) as a string; people mean the number
            parsed = float(parsed)
        except ValueError:
            pass
    return key.strip().split("."), parsed


def parse_override(text: str) -> tuple[list[str], Any]:
    """``--set key.sub=value`` (:func:`read_override`); a malformed one is one line naming it."""
    try:
        return read_override(text)
    except ValueError as error:
        raise UserError(f"--set {text!r}: {error}") from error


def is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _kind_mismatch(current: Any, value: Any) -> str | None:
    """What ``value`` should have been to replace ``current`` (the file's value), or None when it
    fits: a number stays a number (or null), a switch a switch, a list a list; a null or a text in
    the file takes anything (``devices: auto`` may become 2)."""
    if isinstance(current, bool):
        return None if isinstance(value, bool) else "true or false"
    if is_number(current):
        return None if value is None or is_number(value) else "a number"
    if isinstance(current, list):
        return None if isinstance(value, list) else "a list, e.g. [1, 2]"
    return None


def apply_overrides(config: dict[str, Any], overrides: list[str]) -> dict[str, Any]:
    """A copy of ``config`` with each ``key.sub=value`` applied; unknown keys, and values of another
    kind than the file's (``optim.lr=abc``), are errors before anything starts."""
    result = copy.deepcopy(config)
    for text in overrides:
        path, value = parse_override(text)
        node = result
        for depth, key in enumerate(path):
            if not isinstance(node, dict) or key not in node:
                where = ".".join(path[:depth]) or "the top level"
                known = ", ".join(sorted(node)) if isinstance(node, dict) else "none (not a section)"
                raise UserError(f"--set {text!r}: no key {key!r} in {where}; known keys: {known}")
            if depth == len(path) - 1:
                if isinstance(node[key], dict):
                    raise UserError(f"--set {text!r}: {'.'.join(path)} is a section; set one of its keys")
                wanted = _kind_mismatch(node[key], value)
                if wanted:
                    raise UserError(f"--set {text!r}: {'.'.join(path)} takes {wanted}, got {value!r}")
                node[key] = value
            else:
                node = node[key]
    return result


def with_defaults(config: dict[str, Any], defaults: dict[str, Any]) -> dict[str, Any]:
    """``config`` with every key of ``defaults`` it lacks, section by section (its own values win)."""
    merged = copy.deepcopy(defaults)
    for key, value in config.items():
        merged[key] = (
            with_defaults(value, merged[key])
            if isinstance(value, dict) and isinstance(merged.get(key), dict)
            else value
        )
    return merged


def _read_mapping(path: Path) -> dict[str, Any]:
    try:
        config = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as error:
        raise UserError(f"{path}: not valid YAML ({yaml_problem(error)})") from error
    if not isinstance(config, dict):
        raise UserError(f"{path}: expected a mapping of settings at the top level")
    return config


def _sibling_configs(stage: str, path: Path) -> list[dict[str, Any]]:
    """The configs of ``configs/<stage>/`` other than ``path``: what a config of the stage is read against."""
    siblings = sorted((CONFIG_ROOT / stage).glob("*.yaml"))
    return [_read_mapping(p) for p in siblings if p.resolve() != path.resolve()]


def _closest(key: str, known: set[str]) -> str:
    match = difflib.get_close_matches(key, known, n=1, cutoff=0.75)
    return f" (did you mean {match[0]}?)" if match else ""


def check_keys(
    config: dict[str, Any],
    references: list[dict[str, Any]],
    where: str,
    optional: Iterable[str] = (),
    free: tuple[str, ...] = (),
) -> None:
    """Refuse, in one line, a config with a key none of ``references`` has (a typo) or without a key
    all of them have (a truncated file). The dotted keys ``optional`` may be given or left out; the sections named
    in ``free`` hold keys of the user's choosing (a sweep's search space) and are not looked into.
    With no references (a folder without the stage's configs) there is nothing to check against."""
    if not references:
        return
    keys = [_keys(reference, free) for reference in references]
    optional_keys = set(optional)
    known, required = set.union(*keys) | optional_keys, set.intersection(*keys) - optional_keys
    given = _keys(config, free)
    unknown = sorted(key for key in given - known if not _under_a_leaf(key, known))
    problems = [f"unknown key {key}{_closest(key, known)}" for key in unknown]
    if required - given:
        problems.append(f"missing {_sections(sorted(required - given), config)}")
    if problems:
        raise UserError(f"{where}: {'; '.join(problems)}")


def _keys(config: dict[str, Any], free: tuple[str, ...]) -> set[str]:
    """The dotted keys of ``config``, a ``free`` section counted as one key."""
    return {key.split(".")[0] if key.split(".")[0] in free else key for key in flatten(config)}


def _under_a_leaf(key: str, known: set[str]) -> bool:
    """``a.b`` where the references hold ``a`` as one value (a null a mapping may replace)."""
    parts = key.split(".")
    return any(".".join(parts[:depth]) in known for depth in range(1, len(parts)))


def _sections(missing: list[str], config: dict[str, Any]) -> str:
    """``model (the whole section), data.window``: a section the config lacks altogether is named once."""
    named: list[str] = []
    for key in missing:
        section = key.split(".")[0]
        if "." in key and section not in config:
            entry = f"{section} (the whole section)"
            if entry not in named:
                named.append(entry)
        else:
            named.append(key)
    return ", ".join(named)


def load_config(
    stage: str,
    name_or_path: str,
    overrides: list[str] | None = None,
    defaults: dict[str, Any] | None = None,
    optional: Iterable[str] = (),
    free: tuple[str, ...] = (),
) -> dict[str, Any]:
    """The resolved config of a stage: the YAML file, checked against the stage's other configs (:func:`check_keys`: the dotted
    keys ``optional`` may be left out, ``free`` sections hold keys of the user's choosing), over
    ``defaults`` (settings every file of the stage may leave out, so an override can still name
    them), with the overrides applied."""
    path = resolve_config_path(stage, name_or_path)
    config = _read_mapping(path)
    optional = {*optional, *flatten(defaults or {})}
    check_keys(config, _sibling_configs(stage, path), str(path), optional, free)
    return follow_dataset(config, apply_overrides(with_defaults(config, defaults or {}), overrides or []))


def follow_dataset(written: dict[str, Any], resolved: dict[str, Any]) -> dict[str, Any]:
    """``resolved`` with its data directory moved to ``data/<dataset>`` where an override chose
    another dataset and left the file's ``data/<its dataset>`` in place: ``--set
    dataset=humanml3d-public`` trains a humanml3d config on that corpus's data (docs/data.md)."""
    before, after = written.get("dataset"), resolved.get("dataset")
    data = resolved.get("data")
    if before != after and isinstance(data, dict) and data.get("dir") == f"data/{before}":
        return {**resolved, "data": {**data, "dir": f"data/{after}"}}
    return resolved


def flatten(config: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"a": {"b": 1}}`` → ``{"a.b": 1}``: one MLflow param per knob."""
    flat: dict[str, Any] = {}
    for key, value in config.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(flatten(value, f"{name}."))
        else:
            flat[name] = value
    return flat
