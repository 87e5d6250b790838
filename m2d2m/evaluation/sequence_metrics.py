"""Columns of the multi-motion table that a plugin adds: a metric of one generated sequence (its
joints and the frames where its actions meet), averaged over a row's sequences as the Jerk column
is (docs/architecture.md, "How to add a metric").

A module registers its metric when imported (a plugin named in ``M2D2M_PLUGINS``); every
evaluation then measures it on each multi-motion row, generated, reconstructed and the
concatenated ground truth alike, and reports it in table.md, table.json and MLflow
(``multi/<row>/<name>``). The paper's own columns are computed in
:mod:`m2d2m.evaluation.measurements`, several of them over a row's embeddings at once, which a
per-sequence metric cannot express.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from m2d2m.motion.transforms.feet import skating_ratio

_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


@dataclass(frozen=True)
class SequenceMetric:
    """``measure(joints, boundaries, skeleton)``: one sequence's value from its joints (T, J, 3)
    in metres, the frames where its actions meet, and its skeleton; NaN where undefined (a
    row's value ignores NaNs)."""

    name: str  # the key in table.json and MLflow; lower case, digits and underscores
    title: str  # the column's title, with the arrow that says which way is better
    measure: Callable[[np.ndarray, Sequence[int], Any], float]


_REGISTERED: dict[str, SequenceMetric] = {}


def register_metric(metric: SequenceMetric) -> SequenceMetric:
    """Add (or replace) a metric; a plugin module calls this when it is imported."""
    if not _NAME.match(metric.name):
        raise ValueError(f"metric name {metric.name!r}: use lower case letters, digits and underscores")
    _REGISTERED[metric.name] = metric
    return metric


def sequence_metrics() -> tuple[SequenceMetric, ...]:
    """Every registered metric, in registration order."""
    return tuple(_REGISTERED.values())


def measure_sequences(sequences: Sequence[tuple[np.ndarray, Sequence[int]]], skeleton: Any) -> dict[str, list[float]]:
    """Each registered metric's value of each ``(joints, boundaries)``."""
    return {
        metric.name: [float(metric.measure(joints, boundaries, skeleton)) for joints, boundaries in sequences]
        for metric in sequence_metrics()
    }


def skating(joints: np.ndarray, boundaries: Sequence[int], skeleton: Any) -> float:
    """GMD's foot skating ratio at the skeleton's frame rate (:func:`m2d2m.motion.transforms.feet.skating_ratio`),
    registered here, not by a plugin, so that every evaluation reports how much each row's feet
    slide (docs/evaluation.md, "Feet that stay planted")."""
    return skating_ratio(joints, skeleton, skeleton.fps)


SKATING = register_metric(SequenceMetric("skating", "Skating ↓", skating))
