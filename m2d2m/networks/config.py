"""The base of every network's config: a frozen dataclass read from a run's YAML section and
written into model files, with the checks they all make named once."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import asdict, dataclass, fields
from typing import Any, Self


class ConfigError(ValueError):
    """A network setting no model can be built with: the user's to fix, said in one line."""


@dataclass(frozen=True)
class NetworkConfig:
    """Subclasses declare their fields with the paper's defaults and check them in ``__post_init__``."""

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> Self:
        """Build from a config mapping; unknown keys are an error so a typo never goes unnoticed."""
        unknown = sorted(set(values) - {f.name for f in fields(cls)})
        if unknown:
            raise ConfigError(f"unknown {cls.__name__} keys: {', '.join(unknown)}")
        return cls(**values)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def require_positive(self, *names: str) -> None:
        """Each field named must be an integer >= 1."""
        for name in names:
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ConfigError(f"{type(self).__name__}.{name} must be a positive integer, got {value!r}")

    def require_fraction(self, *names: str, open_low: bool = False) -> None:
        """Each field named must lie in [0, 1) — or (0, 1) with ``open_low``."""
        for name in names:
            value = getattr(self, name)
            if not (0.0 < value < 1.0 if open_low else 0.0 <= value < 1.0):
                raise ConfigError(
                    f"{type(self).__name__}.{name} must lie in {'(' if open_low else '['}0, 1), got {value!r}"
                )

    def require_choice(self, name: str, choices: Iterable[str]) -> None:
        """The field named must be one of ``choices``."""
        choices = tuple(choices)
        value = getattr(self, name)
        if value not in choices:
            raise ConfigError(f"{type(self).__name__}.{name} must be one of {', '.join(choices)}, got {value!r}")

    def require_divisible(self, name: str, by: str) -> None:
        """The field ``name`` must be a multiple of the field ``by`` (a width split into heads)."""
        if getattr(self, name) % getattr(self, by):
            raise ConfigError(
                f"{type(self).__name__}.{name} ({getattr(self, name)}) must be divisible by {by} ({getattr(self, by)})"
            )
