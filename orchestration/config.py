"""Stage configs: a YAML file under ``configs/<stage>/`` plus ``--set key.sub=value`` overrides.

Every config is checked against its file's own keys, so a typo in an override is an error that
names the key instead of a setting that silently does nothing.
"""

from __future__ import annotations

import copy
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


def parse_override(text: str) -> tuple[list[str], Any]:
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise UserError(f"--set {text!r}: expected key.sub=value")
    try:
        parsed = yaml.safe_load(value) if value.strip() else ""
    except yaml.YAMLError as error:
        raise UserError(f"--set {text!r}: the value is not valid YAML ({yaml_problem(error)})") from error
    if isinstance(parsed, str):
        try:  # YAML 1.1 reads 1e-3 (no dot) as a string; people mean the number
            parsed = float(parsed)
        except ValueError:
            pass
    return key.strip().split("."), parsed


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


def rename_keys(config: dict[str, Any], renamed: dict[str, str], where: str) -> dict[str, Any]:
    """A copy of ``config`` with each old dotted key of ``renamed`` moved to its new name, so that
    configs written before a key was renamed still read; both names set is an error."""
    result = copy.deepcopy(config)
    for old, new in renamed.items():
        *section_path, key = old.split(".")
        section = result
        for name in section_path:
            section = section.get(name) if isinstance(section, dict) else None
        if not isinstance(section, dict) or key not in section:
            continue
        *new_path, new_key = new.split(".")
        target = result
        for name in new_path:
            target = target.setdefault(name, {})
        if new_key in target:
            raise UserError(f"{where}: both {old} and {new} are set; {new} replaces {old}, keep only it")
        target[new_key] = section.pop(key)
    return result


def load_config(
    stage: str,
    name_or_path: str,
    overrides: list[str] | None = None,
    defaults: dict[str, Any] | None = None,
    renamed: dict[str, str] | None = None,
) -> dict[str, Any]:
    """The resolved config of a stage: the YAML file, its keys of older names ``renamed`` (old
    dotted key → new), over ``defaults`` (settings every file of the stage may leave out, so an
    override can still name them), with the overrides applied."""
    path = resolve_config_path(stage, name_or_path)
    try:
        config = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as error:
        raise UserError(f"{path}: not valid YAML ({yaml_problem(error)})") from error
    if not isinstance(config, dict):
        raise UserError(f"{path}: expected a mapping of settings at the top level")
    config = rename_keys(config, renamed or {}, str(path))
    return apply_overrides(with_defaults(config, defaults or {}), overrides or [])


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
