"""A model's sampling knobs, declared once: their kinds, bounds, choices and help, its
multi-action methods and its presets. The command line builds its help and shortcuts from this,
sweeps and evaluation check knob names against it, the web page and the API list it, and the
generator checks every request's options with it (docs/architecture.md, "The generator protocol").

This module imports neither torch nor NumPy, so a declaration (one ``<model>_options.py`` per
model) can be read without loading a model: listing the models' knobs costs milliseconds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import Field, dataclass, field, fields, replace
from typing import Any

SINGLE, MULTI = "single", "multi"  # the presets every generator has
# torch.compile (m2d2m/compiling.py) for a sampler's passes or a training step: never, on CUDA only, everywhere
COMPILE = ("off", "auto", "on")


def knob(
    default: Any,
    help: str,
    *,
    label: str = "",
    methods: tuple[str, ...] | None = None,
    minimum: float | None = None,
    above: float | None = None,
    maximum: float | None = None,
    choices: tuple[str, ...] | None = None,
) -> Any:
    """A field of an options dataclass with what a user is told about it: ``label`` its name for
    people (the page shows it, with ``help`` under it), ``methods`` the multi-action methods it
    matters for (None: every one; the page hides it for the others), ``minimum`` and ``maximum``
    inclusive bounds, ``above`` an exclusive lower one, ``choices`` the values a text knob may take.
    Bounds that depend on the loaded model (steps ≤ the trained T) stay in the generator's
    ``check_options``."""
    return field(
        default=default,
        metadata={
            "help": help,
            "label": label,
            "methods": methods,
            "minimum": minimum,
            "above": above,
            "maximum": maximum,
            "choices": choices,
        },
    )


def _bounds(minimum: float | None, above: float | None, maximum: float | None) -> str:
    low = f"[{minimum:g}" if minimum is not None else f"({above:g}" if above is not None else ""
    if low and maximum is not None:
        return f"{low}, {maximum:g}]"
    if low:
        return f">= {minimum:g}" if minimum is not None else f"> {above:g}"
    return f"<= {maximum:g}" if maximum is not None else ""


@dataclass(frozen=True)
class Knob:
    """One sampling knob as a user, a page or an API client sees it."""

    name: str
    kind: str  # int, float or str
    optional: bool  # whether None is allowed: the model decides (M2D2M's T_s = 0.9·T)
    help: str
    minimum: float | None = None
    above: float | None = None
    maximum: float | None = None
    choices: tuple[str, ...] | None = None
    label: str = ""  # its name for people; its own name where none was declared
    methods: tuple[str, ...] | None = None  # the methods it matters for; None: every one

    @classmethod
    def of(cls, declared: Field) -> Knob:
        annotation = str(declared.type)
        meta = declared.metadata
        methods = meta.get("methods")
        return cls(
            declared.name,
            annotation.split("|")[0].strip(),
            "None" in annotation,
            meta.get("help", ""),
            meta.get("minimum"),
            meta.get("above"),
            meta.get("maximum"),
            tuple(meta["choices"]) if meta.get("choices") else None,
            meta.get("label") or declared.name,
            None if methods is None else tuple(methods),
        )

    @property
    def bounds(self) -> str:
        """The allowed values in words: ``[0, 1]``, ``> 0``, ``one of cosine, linear``, or empty."""
        if self.choices:
            return f"one of {', '.join(self.choices)}"
        return _bounds(self.minimum, self.above, self.maximum)

    def check(self, value: Any) -> Any:
        """``value`` as this knob takes it (an int given as 2.0 becomes 2), or ValueError in one
        sentence: a knob given as text, NaN or out of bounds fails here, not deep inside sampling."""
        if value is None:
            if not self.optional:
                raise ValueError(f"option {self.name} cannot be empty")
            return None
        if self.kind == "str":
            if not isinstance(value, str):
                raise ValueError(f"option {self.name} must be text, got {value!r}")
            if self.choices and value not in self.choices:
                raise ValueError(f"unknown {self.name} {value!r}: choose one of {', '.join(self.choices)}")
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ValueError(f"option {self.name} must be a finite number, got {value!r}")
        if self.kind == "int":
            if value != int(value):
                raise ValueError(f"option {self.name} must be a whole number, got {value!r}")
            value = int(value)
        else:
            value = float(value)
        if (
            (self.minimum is not None and value < self.minimum)
            or (self.above is not None and value <= self.above)
            or (self.maximum is not None and value > self.maximum)
        ):
            raise ValueError(f"option {self.name} must be {self.bounds}, got {value:g}")
        return value


def check_knobs(options: Any) -> None:
    """Raise ValueError for the first field of ``options`` (a dataclass of :func:`knob` fields) that
    its knob refuses: for options built in code rather than through :meth:`Sampling.changed`."""
    for declared in fields(options):
        Knob.of(declared).check(getattr(options, declared.name))


@dataclass(frozen=True)
class Sampling:
    """What a model's sampling takes: ``options_type``, a frozen dataclass of :func:`knob` fields
    whose ``method`` field lists the multi-action methods as its choices (the first the default),
    the :data:`SINGLE` and :data:`MULTI` presets, the paper's settings, and ``method_labels``, each
    method's name for people (the page's; a method without one is shown by its own name)."""

    model: str  # the registry's name of the model
    options_type: type
    presets: Mapping[str, Any]
    method_labels: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        name = self.options_type.__name__
        missing = {SINGLE, MULTI} - set(self.presets)
        if missing:
            raise TypeError(f"{name}: no {' or '.join(sorted(missing))} preset")
        if "method" not in self.names(with_method=True) or not self.knob("method").choices:
            raise TypeError(f"{name}: a method knob with its choices is needed")
        # a misspelt method would silently hide a knob, or label nothing, on the page
        for owner, named in [("method_labels", self.method_labels), *((k.name, k.methods) for k in self.knobs())]:
            unknown = sorted(set(named or ()) - set(self.methods))
            if unknown:
                raise TypeError(f"{name}: {owner} names unknown methods {', '.join(unknown)}")

    def names(self, with_method: bool = False) -> tuple[str, ...]:
        return tuple(f.name for f in fields(self.options_type) if with_method or f.name != "method")

    def knob(self, name: str) -> Knob:
        return next(Knob.of(f) for f in fields(self.options_type) if f.name == name)

    def knobs(self) -> tuple[Knob, ...]:
        """Every knob a user or a sweep may set: all but the method."""
        return tuple(Knob.of(f) for f in fields(self.options_type) if f.name != "method")

    @property
    def methods(self) -> tuple[str, ...]:
        """The multi-action methods, the first the default."""
        return self.knob("method").choices or ()

    def defaults(self, preset: str = MULTI, chosen: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """A preset's value of every knob, the method included, with the values a model file chose
        for every preset (``chosen``: M2D2M's ``sampling`` section) in their place: what a
        generation with nothing set samples with."""
        values = {name: getattr(self.presets[preset], name) for name in self.names(with_method=True)}
        return {**values, **{name: value for name, value in (chosen or {}).items() if name in values}}

    def changed(self, base: Any, **changes: Any) -> Any:
        """``base`` options with ``changes``, each checked by its knob; ValueError in one sentence
        for an unknown knob or method, a value of the wrong kind or out of bounds."""
        for name in changes:
            if name not in self.names(with_method=True):
                raise ValueError(
                    f"{self.model} has no sampling option {name!r}; its options: {', '.join(self.names())}"
                )
        if "method" in changes and changes["method"] not in self.methods:
            raise ValueError(
                f"unknown method {changes['method']!r} for {self.model}: choose one of {', '.join(self.methods)}"
            )
        return replace(base, **{name: self.knob(name).check(value) for name, value in changes.items()})
