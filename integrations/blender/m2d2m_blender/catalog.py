"""The server's models and methods as the panel's menus offer them: fetched by "Fetch models"
(``GET /api/models``) and kept here, since Blender reads a menu's items from a function each time it
draws it (and needs their strings kept alive while they are shown)."""

from __future__ import annotations

from typing import Any

DEFAULT_MODEL = "m2d2m"  # the API's default model, offered before the server's list is fetched
DEFAULT_METHOD = "default"  # the model's own default method: no method sent

_models: list[dict[str, Any]] = []
_items: dict[str, list[tuple[str, str, str]]] = {}  # the lists last handed to Blender, kept alive


def keep(models: list[dict[str, Any]]) -> None:
    """The models ``GET /api/models`` answered, for the menus."""
    _models[:] = models


def model_items(_settings: Any = None, _context: Any = None) -> list[tuple[str, str, str]]:
    """The model menu: every served model (its summary as the tooltip), or the API's default."""
    items = [(model["name"], model["name"], model.get("summary") or "") for model in _models]
    _items["models"] = items or [(DEFAULT_MODEL, DEFAULT_MODEL, "press Fetch models for the server's list")]
    return _items["models"]


def method_items(settings: Any = None, _context: Any = None) -> list[tuple[str, str, str]]:
    """The method menu of the chosen model: its default first, then each method by its name for people."""
    chosen = getattr(settings, "model", None)
    model = next((model for model in _models if model["name"] == chosen), None)
    items = [(DEFAULT_METHOD, "Model's default", "the method the model's run samples with by default")]
    if model is not None:
        labels = model.get("method_labels") or {}
        items += [(method, labels.get(method, method), method) for method in model.get("methods", [])]
    _items["methods"] = items
    return items
