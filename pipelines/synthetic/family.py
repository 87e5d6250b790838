"""An action family as one object: its motion, how its parameters are drawn, and its phrases."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from pipelines.synthetic.body import Body, State
from pipelines.synthetic.program import Program


@dataclass(frozen=True)
class ActionFamily:
    """One action family, whole: its motion (a program from the body, the state the previous
    action left and its parameters, and the state it ends in), how its parameters are drawn, the
    tagged phrases that say it with those parameters, and the posture it needs and leaves (actions
    only chain where the posture matches)."""

    name: str
    motion: Callable[[Body, State, dict, np.random.Generator], tuple[Program, State]]
    draw: Callable[[np.random.Generator], dict]
    phrases: Callable[[dict, np.random.Generator], list[str]]
    seated_before: bool = False
    seated_after: bool = False


def draw_choice(rng: np.random.Generator, options: Sequence, weights: Sequence[float] | None = None):
    """One option, as a plain Python value (JSON-friendly)."""
    index = int(rng.choice(len(options), p=None if weights is None else np.asarray(weights) / sum(weights)))
    return options[index]


def draw_count(rng: np.random.Generator, low: int, high: int) -> int:
    return int(rng.integers(low, high + 1))
