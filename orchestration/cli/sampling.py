"""The sampling options of `m2d2m generate` and `m2d2m evaluate`, as the models declare them
(m2d2m.generators.options): ``--option KEY=VALUE`` for any knob, the shortcuts a model's entry
names, and the help that lists every model's methods and knobs.
"""

from __future__ import annotations

import argparse
from typing import Any

from orchestration.cli.arguments import escaped
from orchestration.registry import models


def _option(text: str) -> tuple[str, Any]:
    """``KEY=VALUE`` of a sampling option, the value read as YAML (numbers, null, lists); a
    malformed one is argparse's one line, read as it is given, before anything loads."""
    from orchestration.config import read_override

    try:
        path, value = read_override(text)
    except ValueError as error:
        raise argparse.ArgumentTypeError(f"{error}, got {text!r}") from None
    return ".".join(path), value


_SHORTCUT = "knob_"  # a shortcut's attribute: --eta is args.knob_eta, clear of every other option
_KINDS = {"int": int, "float": float, "str": str}


def _knob_line(knob: Any, preset: Any) -> str:
    """One knob of the sampling help: its name, kind, bounds, the multi-action preset's value and what it does."""
    bounds = f", {knob.bounds}" if knob.bounds else ""
    value = getattr(preset, knob.name)
    return f"    {knob.name} ({knob.kind}{bounds}; preset {'none' if value is None else value}): {knob.help}"


def sampling_help() -> str:
    """Every model's methods and knobs, as the models declare them (m2d2m.generators.options):
    the closing section of ``generate --help`` and ``evaluate --help``."""
    from m2d2m.generators.options import MULTI

    lines = [
        "sampling options by model (--option KEY=VALUE). An unset one keeps the model's default: the",
        "multi-action preset shown here (the paper's), unless the model file chose its own (M2D2M: its",
        "config's sampling section); `m2d2m models` shows each trained model's own defaults.",
    ]
    for entry in models().values():
        sampling = entry.load("sampling")
        preset = sampling.presets[MULTI]
        lines.append(f"  {entry.name}: methods {', '.join(sampling.methods)} (default {preset.method})")
        lines += [_knob_line(knob, preset) for knob in sampling.knobs()]
    return "\n".join(lines)


def add_sampling_knobs(parser: argparse.ArgumentParser) -> None:
    """``--option KEY=VALUE`` for any model's knob, and the flags the models' entries declare as
    shortcuts (M2D2M's ``--ts``, ``--eta``, ``--guidance``, ``--truncation``), each typed and
    explained as its knob declares it."""
    parser.add_argument(
        "--option",
        type=_option,
        action="append",
        metavar="KEY=VALUE",
        help="any sampling option of the model, e.g. --option steps=25 (repeatable; listed below)",
    )
    owners: dict[str, list[tuple[str, Any]]] = {}
    for name, entry in models().items():
        sampling = entry.load("sampling")
        for knob in entry.shortcuts:
            owners.setdefault(knob, []).append((name, sampling.knob(knob)))
    for name, declared in owners.items():
        explained = "; ".join(f"{model}: {knob.help}" for model, knob in declared)
        kind = declared[0][1].kind
        parser.add_argument(
            f"--{name.replace('_', '-')}",
            dest=_SHORTCUT + name,
            type=_KINDS[kind],
            metavar=kind.upper(),
            help=escaped(f"{explained}; short for --option {name}=…"),
        )
    parser.set_defaults(shortcuts=tuple(owners))


def sampling_options(args: argparse.Namespace) -> dict[str, Any]:
    """The sampling knobs given on the command line: every ``--option`` and the shortcuts."""
    options = dict(args.option or [])
    for name in args.shortcuts:
        if getattr(args, _SHORTCUT + name) is not None:
            options[name] = getattr(args, _SHORTCUT + name)
    return options
