"""Plugins: modules outside this repository that register a model, a metric or a corpus when
imported (docs/architecture.md, "How to add a model", "... a metric", "... a corpus"). They are
named in ``M2D2M_PLUGINS`` (comma-separated) and imported once per process. Processes that work for another (Ray
trials, Ray Train workers, the data pipeline's Ray tasks) import the same ones from
:func:`plugins_for_workers`, which also says where to find them."""

from __future__ import annotations

import importlib
import os
import sys
from collections.abc import Sequence
from pathlib import Path

PLUGINS_VARIABLE = "M2D2M_PLUGINS"

_imported: list[str] = []


def named_plugins() -> list[str]:
    """The plugin modules the environment names, in order, each once."""
    named = os.environ.get(PLUGINS_VARIABLE, "")
    return list(dict.fromkeys(module.strip() for module in named.split(",") if module.strip()))


def import_plugins(modules: Sequence[str] | None = None, paths: Sequence[str] = ()) -> list[str]:
    """Import the plugin modules (default: :func:`named_plugins`) not imported yet, looking in
    ``paths`` too; returns every plugin imported so far. ImportError names the module."""
    sys.path.extend(path for path in paths if path not in sys.path)
    for name in named_plugins() if modules is None else modules:
        if name in _imported:
            continue
        try:
            importlib.import_module(name)
        except ImportError as error:
            raise ImportError(f"{PLUGINS_VARIABLE}: cannot import the plugin {name!r} ({error})") from error
        _imported.append(name)
    return list(_imported)


def plugins_for_workers() -> dict[str, list[str]]:
    """What another process needs to import this process's plugins: ``import_plugins(**it)``
    there registers the same models, metrics and corpora."""
    modules = import_plugins()
    paths = []
    for name in modules:
        origin = Path(sys.modules[name].__file__).resolve()
        paths.append(str(origin.parents[name.count(".") + (origin.name == "__init__.py")]))
    return {"modules": modules, "paths": list(dict.fromkeys(paths))}
