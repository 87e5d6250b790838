"""A metric registered from outside the framework as a plugin (``M2D2M_PLUGINS=tests.fake_metric``):
how far the root travels over the ground. If evaluation or its reports knew their columns only
from the paper, it could not appear in them."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from m2d2m.evaluation.sequence_metrics import SequenceMetric, register_metric


def root_travel(joints: np.ndarray, boundaries: Sequence[int], skeleton: Any) -> float:
    """Metres the root joint moves over the ground plane (x, z), summed over frames."""
    return float(np.linalg.norm(np.diff(joints[:, 0, [0, 2]], axis=0), axis=1).sum())


ROOT_TRAVEL = register_metric(SequenceMetric("root_travel", "Root travel (m)", root_travel))
