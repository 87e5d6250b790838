"""Gaussian smoothing along time, the one filter behind heading estimation, the renderer's camera
path, the synthetic corpus's programs and the VQ-VAE's optional output low-pass."""

from __future__ import annotations

from functools import cache

import numpy as np


@cache
def gaussian_kernel(sigma: float, truncate: float = 4.0) -> np.ndarray:
    """Normalised weights of :func:`gaussian_smooth`'s filter, radius ``int(truncate·σ + 0.5)``
    (SciPy's); shared with the VQ-VAE's optional output low-pass."""
    radius = int(truncate * sigma + 0.5)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    weights = np.exp(-0.5 * (x / sigma) ** 2)
    return weights / weights.sum()


def gaussian_smooth(x: np.ndarray, sigma: float, truncate: float = 4.0) -> np.ndarray:
    """Gaussian filter along axis 0 with edge replication, as ``scipy.ndimage.gaussian_filter1d(
    x, sigma, axis=0, mode="nearest", truncate=truncate)`` computes it (kept here to avoid a SciPy
    dependency); ``sigma <= 0`` returns a copy."""
    if sigma <= 0:
        return np.array(x, copy=True)
    kernel = gaussian_kernel(float(sigma), float(truncate))
    radius = len(kernel) // 2
    padded = np.pad(x, [(radius, radius)] + [(0, 0)] * (x.ndim - 1), mode="edge")
    windows = np.lib.stride_tricks.sliding_window_view(padded, len(kernel), axis=0)
    return windows @ kernel
