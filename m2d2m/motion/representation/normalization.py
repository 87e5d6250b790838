"""Feature statistics and the one normalisation used by the VQ-VAE, the denoiser and the evaluator.

HumanML3D's statistics: a per-dimension mean over all frames, and a population std that is then
replaced by its average within each feature group (root yaw, root velocity, root height, RIC
positions, rotations, velocities, contacts). Models trained on HumanML3D additionally divide the
std of the root (dims 0:4) and contact (last 4) groups by ``feat_bias`` (default 5) so that those
few dimensions weigh more (EricGuo5513/text-to-motion, ``data/dataset.py``; docs/representation.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from m2d2m.motion.representation.skeleton import Skeleton

DEFAULT_FEAT_BIAS = 5.0


def feature_groups(skeleton: Skeleton) -> list[slice]:
    """The seven groups whose std HumanML3D averages, in feature order."""
    j = skeleton.num_joints
    sizes = [1, 2, 1, 3 * (j - 1), 6 * (j - 1), 3 * j, 4]
    edges = np.cumsum([0] + sizes)
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


class RunningMoments:
    """Per-dimension sums over frames, accumulated clip by clip in float64 (and mergeable, so
    partial sums from parallel workers combine exactly)."""

    def __init__(self, dim: int) -> None:
        self.count = 0
        self.total = np.zeros(dim)
        self.total_sq = np.zeros(dim)

    def add(self, features: np.ndarray) -> None:
        values = np.asarray(features, dtype=np.float64)
        self.count += len(values)
        self.total += values.sum(0)
        self.total_sq += (values * values).sum(0)

    def merge(self, other: RunningMoments) -> None:
        self.count += other.count
        self.total += other.total
        self.total_sq += other.total_sq

    def state(self) -> list:
        """JSON-able sums, to send partial statistics from a worker to the driver."""
        return [self.count, self.total.tolist(), self.total_sq.tolist()]

    @classmethod
    def from_state(cls, state: list) -> RunningMoments:
        moments = cls(len(state[1]))
        moments.count, moments.total, moments.total_sq = state[0], np.array(state[1]), np.array(state[2])
        return moments

    def mean(self) -> np.ndarray:
        return self.total / self.count

    def std(self) -> np.ndarray:
        """Population std (ddof 0), as HumanML3D computes it."""
        mean = self.mean()
        return np.sqrt(np.maximum(self.total_sq / self.count - mean * mean, 0.0))


def group_averaged_std(std: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """Each group's std replaced by its mean, so every dimension of a group is scaled alike."""
    averaged = np.array(std, dtype=np.float64)
    for group in feature_groups(skeleton):
        averaged[group] = averaged[group].mean()
    return averaged


@dataclass(frozen=True)
class Normalizer:
    """``(x − mean) / std'`` where std' is ``std`` with the root and contact groups divided by
    ``feat_bias``. Stored in ``stats.npz`` beside the shards and inside every checkpoint."""

    mean: np.ndarray
    std: np.ndarray
    feat_bias: float = DEFAULT_FEAT_BIAS

    @property
    def scale(self) -> np.ndarray:
        scale = np.array(self.std, dtype=np.float32)
        scale[:4] /= self.feat_bias
        scale[-4:] /= self.feat_bias
        return scale

    def normalize(self, features, dims: np.ndarray | None = None):
        """Works on NumPy arrays and on torch tensors (statistics are moved to their device);
        ``dims``: the features are only these dimensions of the full width (a body part's)."""
        mean, scale = self._like(features, dims)
        return (features - mean) / scale

    def denormalize(self, features, dims: np.ndarray | None = None):
        mean, scale = self._like(features, dims)
        return features * scale + mean

    def _like(self, features, dims: np.ndarray | None):
        mean, scale = np.asarray(self.mean, dtype=np.float32), self.scale
        if dims is not None:
            mean, scale = mean[..., dims], scale[..., dims]
        if isinstance(features, np.ndarray):
            return mean, scale
        return (
            torch.as_tensor(mean, device=features.device, dtype=features.dtype),
            torch.as_tensor(scale, device=features.device, dtype=features.dtype),
        )

    def save(self, path: str | Path) -> None:
        np.savez(
            path,
            mean=np.asarray(self.mean, np.float32),
            std=np.asarray(self.std, np.float32),
            feat_bias=np.float32(self.feat_bias),
        )

    @classmethod
    def load(cls, path: str | Path) -> Normalizer:
        with np.load(path) as stats:
            return cls(stats["mean"], stats["std"], float(stats["feat_bias"]))
