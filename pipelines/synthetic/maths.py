"""Small maths of the procedural motion: easing, key-framed curves, headings as vectors, the
body frame, analytic two-bone IK and Euler rotations."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from m2d2m.motion.representation.rotations import dot, euler_to_matrix, normalize

UP = np.array([0.0, 1.0, 0.0])


def ease(u: np.ndarray | float) -> np.ndarray:
    """Quintic smoothstep: 0→1 with zero velocity and acceleration at both ends."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * u * (u * (6.0 * u - 15.0) + 10.0)


def keyframes(frames: int, keys: Sequence[tuple[float, object]]) -> np.ndarray:
    """Curve (frames, ...) through ``(frame, value)`` keys, eased between consecutive keys and held
    before the first and after the last; the way an animator blocks a pose-to-pose motion."""
    t = np.arange(frames, dtype=np.float64)
    values = np.array([np.asarray(v, dtype=np.float64) for _, v in keys])
    out = np.empty((frames,) + values.shape[1:])
    out[:] = values[0]
    shape = (-1,) + (1,) * (values.ndim - 1)
    for (t0, v0), (t1, v1) in zip(keys[:-1], keys[1:]):
        after = t >= t0
        w = ease((t[after] - t0) / max(t1 - t0, 1e-9)).reshape(shape)
        out[after] = np.asarray(v0) + (np.asarray(v1) - np.asarray(v0)) * w
    return out


def smooth_cover(x: np.ndarray, radius: int) -> np.ndarray:
    """A smooth curve that is never below ``x``: a running maximum, then an average over a window
    no wider than the maximum's, so every averaged value is ≥ the original at the centre."""
    padded = np.pad(x, radius, mode="edge")
    dilated = np.lib.stride_tricks.sliding_window_view(padded, 2 * radius + 1).max(axis=-1)
    padded = np.pad(dilated, radius, mode="edge")
    kernel = np.hanning(2 * radius + 3)[1:-1]
    return np.lib.stride_tricks.sliding_window_view(padded, 2 * radius + 1) @ (kernel / kernel.sum())


def forward_direction(yaw: np.ndarray | float) -> np.ndarray:
    """Horizontal unit vector a body with heading ``yaw`` faces (yaw 0 faces +z, +yaw turns left)."""
    yaw = np.asarray(yaw, dtype=np.float64)
    return np.stack([np.sin(yaw), np.zeros_like(yaw), np.cos(yaw)], axis=-1)


def leftward(yaw: np.ndarray | float) -> np.ndarray:
    """Horizontal unit vector to the body's left."""
    yaw = np.asarray(yaw, dtype=np.float64)
    return np.stack([np.cos(yaw), np.zeros_like(yaw), -np.sin(yaw)], axis=-1)


def to_world(yaw: np.ndarray | float, local: np.ndarray) -> np.ndarray:
    """Body-frame vectors (x left, y up, z forward) to world vectors for heading ``yaw``."""
    local = np.asarray(local, dtype=np.float64)
    return local[..., 0:1] * leftward(yaw) + local[..., 1:2] * UP + local[..., 2:3] * forward_direction(yaw)


def foot_direction(yaw: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """Unit ankle→toe direction of a foot turned to ``yaw`` and pitched ``pitch`` toes-down."""
    return np.cos(pitch)[..., None] * forward_direction(yaw) - np.sin(pitch)[..., None] * UP


def two_bone(
    root: np.ndarray, target: np.ndarray, pole: np.ndarray, upper: float, lower: float
) -> tuple[np.ndarray, np.ndarray]:
    """Analytic two-bone IK: middle joint and end positions (T, 3) reaching for ``target`` with
    the middle joint pushed toward ``pole``; targets out of reach are approached along the line."""
    delta = target - root
    distance = np.sqrt(dot(delta, delta))
    axis = delta / np.maximum(distance, 1e-9)[:, None]
    reach = np.clip(distance, abs(upper - lower) + 1e-3, (upper + lower) * (1.0 - 1e-4))
    cos_a = (upper**2 + reach**2 - lower**2) / (2.0 * upper * reach)
    sin_a = np.sqrt(np.clip(1.0 - cos_a**2, 0.0, 1.0))
    side = normalize(pole - dot(pole, axis)[:, None] * axis)
    middle = root + upper * (cos_a[:, None] * axis + sin_a[:, None] * side)
    return middle, root + reach[:, None] * axis


def rotation(angles: np.ndarray) -> np.ndarray:
    """Rotation matrices of (yaw-like twist about y, flexion about x, bend about −z) angles."""
    return euler_to_matrix(angles, "YXZ")
