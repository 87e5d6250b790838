"""Quaternion and rotation helpers used by the motion representation, BVH export and synthesis.

Conventions (HumanML3D's): quaternions are ``(w, x, y, z)`` in the last axis, rotations act on
column vectors (``qrot(q, v) = q v q⁻¹``) and every function broadcasts over leading axes.
Everything here is NumPy: these functions run in data pipelines, one clip at a time, where a
vectorised NumPy expression over all frames and joints is the fast path.
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-12


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the last axis; several times faster than ``np.cross`` on small arrays."""
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    bx, by, bz = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx], axis=-1)


def dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Inner product over a short last axis (3 or 4), summed component by component because a
    NumPy reduction over a length-3 axis is several times slower."""
    result = a[..., 0] * b[..., 0]
    for i in range(1, a.shape[-1]):
        result = result + a[..., i] * b[..., i]
    return result


def normalize(v: np.ndarray) -> np.ndarray:
    """``v`` scaled to unit length along the last axis (zero vectors stay zero)."""
    return v / np.maximum(np.sqrt(dot(v, v)), _EPS)[..., None]


def qnormalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternion with the same direction as ``q``."""
    return normalize(q)


def qinv(q: np.ndarray) -> np.ndarray:
    """Conjugate, which is the inverse for unit quaternions."""
    return q * np.array([1.0, -1.0, -1.0, -1.0], dtype=q.dtype)


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` (apply ``b`` first, then ``a``)."""
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def qrot(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v`` (..., 3) by unit quaternions ``q`` (..., 4)."""
    w = q[..., :1]
    u = q[..., 1:]
    uv = cross(u, v)
    return v + 2.0 * (w * uv + cross(u, uv))


def qbetween(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Shortest-arc rotation taking direction ``u`` onto direction ``v``.

    HumanML3D's formula ``normalise([|u||v| + u·v, u × v])``; for exactly opposite vectors that
    formula is 0/0, so a half turn about an axis perpendicular to ``u`` is returned instead.
    """
    u, v = np.broadcast_arrays(u, v)
    w = np.sqrt(dot(u, u) * dot(v, v)) + dot(u, v)
    q = np.concatenate([w[..., None], cross(u, v)], axis=-1)
    norm = np.sqrt(dot(q, q))
    degenerate = norm < 1e-9
    if np.any(degenerate):
        ud = u[degenerate]
        helper = np.where(np.abs(ud[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        q = q.copy()
        q[degenerate] = np.concatenate([np.zeros((len(ud), 1)), normalize(cross(ud, helper))], -1)
        norm = np.sqrt(dot(q, q))
    return q / norm[..., None]


def qslerp(a: np.ndarray, b: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """Spherical interpolation from unit quaternions ``a`` to ``b`` at ``weight`` (0 → a, 1 → b),
    along the shorter arc; nearly equal rotations fall back to normalised linear interpolation."""
    weight = np.asarray(weight, dtype=np.float64)[..., None]
    cosine = dot(a, b)[..., None]
    b = np.where(cosine < 0.0, -b, b)  # q and −q are one rotation: take the short way
    cosine = np.abs(cosine)
    angle = np.arccos(np.clip(cosine, -1.0, 1.0))
    sine = np.sin(angle)
    close = sine < 1e-6
    safe = np.where(close, 1.0, sine)
    wa = np.where(close, 1.0 - weight, np.sin((1.0 - weight) * angle) / safe)
    wb = np.where(close, weight, np.sin(weight * angle) / safe)
    return qnormalize(wa * a + wb * b)


def quat_from_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotation by ``angle`` radians about the unit ``axis`` (broadcast against each other)."""
    axis = np.asarray(axis, dtype=np.float64)
    half = 0.5 * np.asarray(angle, dtype=np.float64)[..., None]
    return np.concatenate([np.cos(half), np.sin(half) * axis], axis=-1)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    rows = [
        [1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy)],
        [2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx)],
        [2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)],
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=-2)


def matrix_to_quat(matrices: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(w, x, y, z)`` (..., 4) of rotation matrices (..., 3, 3), by Shepperd's
    method (1978, "Quaternion from rotation matrix", J. Guidance and Control 1(3)): the largest
    component comes from the diagonal and the others from sums and differences of the off-diagonal
    terms divided by it, so nothing is divided by a number near zero."""
    m = matrices
    trace = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    diagonal = [1.0 + trace] + [1.0 + 2.0 * m[..., i, i] - trace for i in range(3)]  # 4w², 4x², 4y², 4z²
    wx, wy, wz = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]  # 4w·(x, y, z)
    xy, xz, yz = m[..., 1, 0] + m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 2, 1] + m[..., 1, 2]  # 4xy, 4xz, 4yz
    candidates = np.stack(  # row i is 4·q_i·q: the quaternion up to the scale 4·q_i
        [
            np.stack([diagonal[0], wx, wy, wz], axis=-1),
            np.stack([wx, diagonal[1], xy, xz], axis=-1),
            np.stack([wy, xy, diagonal[2], yz], axis=-1),
            np.stack([wz, xz, yz, diagonal[3]], axis=-1),
        ],
        axis=-2,
    )
    largest = np.argmax(np.stack(diagonal, axis=-1), axis=-1)[..., None, None]
    return qnormalize(np.take_along_axis(candidates, largest, axis=-2)[..., 0, :])


def quat_to_cont6d(q: np.ndarray) -> np.ndarray:
    """Continuous 6D rotation: the first two columns of the rotation matrix, ``[c0, c1]``."""
    m = quat_to_matrix(q)
    return np.concatenate([m[..., :, 0], m[..., :, 1]], axis=-1)


def cont6d_to_matrix(c6: np.ndarray) -> np.ndarray:
    """Rotation matrices from 6D by Gram–Schmidt, as HumanML3D decodes them."""
    x = normalize(c6[..., 0:3])
    z = normalize(cross(x, c6[..., 3:6]))
    y = cross(z, x)
    return np.stack([x, y, z], axis=-1)


def matrix_to_euler(m: np.ndarray, order: str = "ZYX") -> np.ndarray:
    """Euler angles in radians, ``angles[..., i]`` about axis ``order[i]``, with
    ``R = R_order[0](a0) · R_order[1](a1) · R_order[2](a2)`` — the convention of BVH channels
    listed in that order. Only Tait–Bryan orders (three distinct axes) are supported.
    """
    axes = ["XYZ".index(a) for a in order.upper()]
    if sorted(axes) != [0, 1, 2]:
        raise ValueError(f"unsupported Euler order {order!r}: use three distinct axes")
    i, j, k = axes
    # Parity of the permutation decides the signs of the off-diagonal terms.
    sign = 1.0 if (j - i) % 3 == 1 else -1.0
    middle = np.arcsin(np.clip(sign * m[..., i, k], -1.0, 1.0))
    first = np.arctan2(-sign * m[..., j, k], m[..., k, k])
    last = np.arctan2(-sign * m[..., i, j], m[..., i, i])
    # Gimbal lock: cos(middle) ≈ 0, the first and last axes coincide; put it all on the first.
    locked = np.abs(m[..., i, k]) > 1.0 - 1e-9
    if np.any(locked):
        first = np.where(locked, np.arctan2(sign * m[..., k, j], m[..., j, j]), first)
        last = np.where(locked, 0.0, last)
    return np.stack([first, middle, last], axis=-1)


def euler_to_matrix(angles: np.ndarray, order: str = "ZYX") -> np.ndarray:
    """Inverse of :func:`matrix_to_euler`: ``R = R_order[0](a0) · R_order[1](a1) · R_order[2](a2)``."""
    unit = np.eye(3)
    result = None
    for n, axis in enumerate(order.upper()):
        q = quat_from_axis_angle(unit["XYZ".index(axis)], angles[..., n])
        r = quat_to_matrix(q)
        result = r if result is None else result @ r
    return result
