"""A clip made ready for an animation tool: resampled to the tool's frame rate, its horizontal root
motion kept, removed (in place) or its body put on the floor, and turned into a seamless loop.

Everything works on the rig's form of the clip (:mod:`m2d2m.motion.representation.pose`): rotations are
interpolated along the great arc (slerp; Shoemake 1985, "Animating rotation with quaternion
curves", SIGGRAPH), the root's position linearly, and forward kinematics rebuilds the joints, so
every bone keeps its length (blending joint positions linearly shortens a bone that turns).
Joints from :meth:`m2d2m.motion.clip.Motion.on_rigid_skeleton` come back unchanged at instants
both rates share; joints of a body whose bones stretch come back on the rig's bind pose (the
clip's mean bone lengths), as a BVH shows them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from m2d2m.motion.representation.pose import Pose, pose_of
from m2d2m.motion.representation.rotations import matrix_to_quat, qslerp, quat_to_matrix
from m2d2m.motion.representation.skeleton import Skeleton

FPS_RANGE = (1.0, 1000.0)  # frame rates a clip can be resampled from and to
ROOT_MODES = ("keep", "in-place", "ground")
LOOP_WINDOW_SECONDS = (0.25, 1.0)  # the cross-fade of a loop: long enough to hide, short enough to keep the clip
_WINDOW_STEPS_PER_SECOND = 20  # loop windows are tried 50 ms apart (a frame at 20 fps), however high the rate
_HORIZONTAL = np.array([1.0, 0.0, 1.0])
_SNAP = 1e-9  # frames: an instant this close to a source frame is that frame


def check_fps(fps: float, name: str = "fps") -> float:
    """``fps`` as a float, or a ValueError in one line when it is no frame rate a clip plays at."""
    low, high = FPS_RANGE
    if not low <= float(fps) <= high:  # NaN fails too
        raise ValueError(f"{name} must be a frame rate from {low:g} to {high:g} frames per second, got {fps!r}")
    return float(fps)


def frame_count(frames: int, fps: float, target_fps: float) -> int:
    """How many frames a clip of ``frames`` frames at ``fps`` has at ``target_fps``: the same
    length of time. A clip of T seconds at F frames per second has T·F frames, frame k at k / F
    seconds and standing until the next (as the models count an action's frames, and as an
    animation tool counts a clip's: 10 s at 30 fps is frames 1 to 300), so ``frames / fps``
    seconds are ``frames · target_fps / fps`` frames, rounded to the nearest (half up); at least one."""
    ratio = check_fps(target_fps, "target_fps") / check_fps(fps)
    return max(1, math.floor(frames * ratio + 0.5 + _SNAP))


def source_positions(frames: int, fps: float, target_fps: float) -> np.ndarray:
    """Where the instants ``k / target_fps`` of the :func:`frame_count` frames at ``target_fps``
    fall in a clip of ``frames`` frames at ``fps``, in (fractional) source frames. The instants
    after the last source frame (less than one source frame's time: the last frame stands until
    the clip ends) are that frame."""
    ratio = check_fps(fps) / check_fps(target_fps, "target_fps")
    positions = np.minimum(np.arange(frame_count(frames, fps, target_fps)) * ratio, frames - 1)
    nearest = np.round(positions)
    return np.where(np.abs(positions - nearest) < _SNAP, nearest, positions)


def resample_pose(pose: Pose, fps: float, target_fps: float) -> Pose:
    """``pose`` at ``target_fps``: each joint's rotation slerped and the root interpolated linearly
    between the two source frames around every new instant (no frame dropped; the last one held
    until the clip ends, :func:`source_positions`)."""
    frames = len(pose.root)
    positions = source_positions(frames, fps, target_fps)
    before = np.minimum(np.floor(positions).astype(np.int64), max(frames - 2, 0))
    after = np.minimum(before + 1, frames - 1)
    weight = positions - before
    quats = matrix_to_quat(pose.local)
    local = quat_to_matrix(qslerp(quats[before], quats[after], weight[:, None]))
    root = pose.root[before] + weight[:, None] * (pose.root[after] - pose.root[before])
    return replace(pose, root=root, local=local)


def resample(joints: np.ndarray, skeleton: Skeleton, fps: float, target_fps: float) -> np.ndarray:
    """Joints (T, J, 3) at ``fps`` resampled to ``target_fps`` (:func:`resample_pose`), rebuilt by
    forward kinematics so that bone lengths stay exact."""
    return resample_pose(pose_of(joints, skeleton), fps, target_fps).joints()


def resample_ranges(ranges: list[tuple[int, int]], fps: float, target_fps: float, frames: int) -> list[tuple[int, int]]:
    """Action frame ranges ``(first, end)`` (end exclusive) at ``fps`` mapped to a clip of
    ``frames`` frames at ``target_fps``: a range keeps the new frames whose instants fall in its
    own ``[first / fps, end / fps)``, so touching ranges stay touching; a range too short to hold
    a new frame gets one, and the ranges stay ordered, non-empty and within the clip."""
    ratio = check_fps(target_fps, "target_fps") / check_fps(fps)
    mapped: list[list[int]] = []
    previous_end = 0
    for first, end in ranges:
        start = max(math.ceil(first * ratio - _SNAP), previous_end)
        previous_end = max(math.ceil(end * ratio - _SNAP), start + 1)
        mapped.append([start, previous_end])
    limit = frames
    for span in reversed(mapped):  # the last ranges give way at the end of the clip
        span[1] = min(span[1], limit)
        span[0] = limit = min(span[0], span[1] - 1)
    if mapped and mapped[0][0] < 0:
        raise ValueError(f"{len(ranges)} actions do not fit in {frames} frames at {target_fps:g} fps")
    return [(first, end) for first, end in mapped]


def root_motion(joints: np.ndarray, mode: str) -> tuple[np.ndarray, np.ndarray | None]:
    """Joints (T, J, 3) with their root motion as ``mode`` says, and the root-motion track (T, 3)
    that was taken out of them, or None.

    ``keep``: unchanged. ``in-place``: the root's horizontal (x, z) path is subtracted from every
    joint, frame by frame, so the body stays over the origin and every pose relative to the root
    is kept; the track is that path (y = 0), which a game engine applies as root motion (adding it
    back gives the input; exactly so for float32 joints, whose differences float64 holds exactly).
    ``ground``: the path is kept and the whole clip moves up or down once so that its lowest joint,
    over all frames, is on y = 0 (HumanML3D's floor, ``process_file`` in its
    ``motion_representation.ipynb``): one shift for the clip keeps a jump in the air and a crouch
    low, where grounding each frame would pin every frame's lowest point to the floor, flattening
    jumps and making the body bob; the lowest joint rather than the feet alone keeps a lying or
    crawling body above the floor.
    """
    if mode not in ROOT_MODES:
        raise ValueError(f"root mode must be one of {', '.join(ROOT_MODES)}, got {mode!r}")
    joints = np.asarray(joints, dtype=np.float64)
    if mode == "keep":
        return joints, None
    if mode == "ground":
        return joints - np.array([0.0, joints[..., 1].min(), 0.0]), None
    track = joints[:, 0] * _HORIZONTAL
    return joints - track[:, None], track


@dataclass(frozen=True)
class Loop:
    """One cycle of a seamless loop: ``joints`` (L, J, 3) whose frame L − 1 runs on into frame 0
    moved by ``travel`` (3,), the horizontal distance (y = 0) the body covers in a cycle; made from
    the source frames ``span`` = (first, end), the frames before ``first`` blended into its end."""

    joints: np.ndarray
    travel: np.ndarray
    span: tuple[int, int]


def make_loop(joints: np.ndarray, fps: float, skeleton: Skeleton) -> Loop:
    """A seamless loop of joints (T, J, 3) at ``fps``.

    The loop plays source frames ``W`` to ``c − 1``; over its last ``W`` frames their poses are
    cross-faded into those of source frames 0 to ``W − 1`` (rotations by slerp, the root linearly),
    so that its last frame leads into source frame ``W``, its first, as in the clip itself.
    The weight is Perlin's smootherstep (2002, "Improving noise", SIGGRAPH), rising from 0 on the
    frame before the window to 1 on the frame after it (the loop's first frame, moved by the travel)
    with zero first and second derivatives at both ends: position, velocity and acceleration are
    continuous where the fade starts and at the seam. ``W`` (0.25 to 1 s) and the
    cut ``c`` (keeping at least half of the clip after the first ``W`` frames) are chosen by
    :func:`loop_cut`. The horizontal distance travelled in a cycle is kept (a walk walks on, as
    root motion does in an engine), returned as ``travel``: source frames 0 to ``W − 1`` are moved
    by it to meet the end; :func:`root_motion` with ``in-place`` makes an in-place loop of it.
    """
    joints = skeleton.check_joints(joints)
    window, cut = loop_cut(joints, check_fps(fps))
    tail = slice(cut - window, cut)
    travel = _travel(joints[tail], joints[:window])
    weight = smootherstep(np.arange(1, window + 1) / (window + 1))[:, None]
    pose = pose_of(joints, skeleton)
    quats = matrix_to_quat(pose.local)
    blended = qslerp(quats[tail], quats[:window], weight)
    root = pose.root[tail] + weight * (pose.root[:window] + travel - pose.root[tail])
    cycle = replace(
        pose,
        root=np.concatenate([pose.root[window : cut - window], root]),
        local=quat_to_matrix(np.concatenate([quats[window : cut - window], blended])),
    )
    return Loop(cycle.joints(), travel, (window, cut))


def loop_features(features: np.ndarray, span: tuple[int, int]) -> np.ndarray:
    """The features (L, D) of the cycle :func:`make_loop` cuts from ``span`` = (``W``, ``c``) of a
    clip's features (T, D): frames ``W`` to ``c − W − 1`` as they are, then frames ``c − W`` to
    ``c − 1`` cross-faded into frames 0 to ``W − 1`` with the same weights. HumanML3D's features
    are the body's own, turned to its heading and placed about its root, so the fade needs no
    travel. Why: a looped result's features and joints are the same frames, so that an edit, a
    pin and a copied pose address the frames the user sees (issue 53)."""
    window, cut = span
    weight = smootherstep(np.arange(1, window + 1) / (window + 1))[:, None]
    tail = features[cut - window : cut]
    faded = tail + weight * (features[:window] - tail)
    return np.concatenate([features[window : cut - window], faded]).astype(features.dtype)


def cycle_travel(joints: np.ndarray) -> np.ndarray:
    """(3,) how far a cycle's root moves horizontally from its first frame to the next cycle's,
    for joints (L, J, 3) already one cycle (an edit of a loop): its last step carried on once."""
    root = np.asarray(joints, dtype=np.float64)[:, 0]
    return (2.0 * root[-1] - root[-2] - root[0]) * _HORIZONTAL


def smootherstep(x: np.ndarray) -> np.ndarray:
    """``6x⁵ − 15x⁴ + 10x³`` on [0, 1]: 0 to 1 with zero first and second derivatives at both ends."""
    return x * x * x * (x * (6.0 * x - 15.0) + 10.0)


def loop_cut(joints: np.ndarray, fps: float) -> tuple[int, int]:
    """The cross-fade window ``W`` and cut ``c`` (frames) of :func:`make_loop` for joints (T, J, 3).

    Fading from ``A`` (source frames ``c − W`` to ``c − 1``) into ``B`` (frames 0 to ``W − 1``,
    moved by the travel) over ``τ = (W + 1) / fps`` seconds gives ``A + w·Δ`` with ``Δ = B − A``,
    whose jerk is the sources' own plus ``w'''Δ + 3w''Δ' + 3w'Δ''``; smootherstep's derivatives
    peak at 60/τ³, (10/√3)/τ² and (15/8)/τ. The pair with the smallest bound on that added jerk
    (the largest Δ, Δ' and Δ'' over joints and frames) wins: the poses and velocities of the two
    windows match best relative to how long the fade has to hide what differs (Kovar et al.
    2002, "Motion graphs", also compare windows of poses to find where a clip can be cut).
    """
    frames = len(joints)
    low, high = (max(round(seconds * fps), 3) for seconds in LOOP_WINDOW_SECONDS)  # Δ'' needs 3 frames
    step = max(1, round(fps / _WINDOW_STEPS_PER_SECOND))
    windows = [w for w in range(low, high + 1, step) if 3 * w <= frames]
    if not windows:
        raise ValueError(f"a loop needs at least {3 * low} frames ({3 * low / fps:g} s), got {frames}")
    best = (np.inf, 0, 0)
    for window in windows:
        cuts = np.arange(window + math.ceil((frames - window) / 2), frames + 1)
        tails = np.stack([joints[cut - window : cut] for cut in cuts])  # (C, W, J, 3)
        travel = _travel(tails, joints[:window])  # (C, 3)
        delta = joints[None, :window] + travel[:, None, None] - tails
        tau = (window + 1) / fps
        bound = (
            60.0 / tau**3 * _peak(delta)
            + 3.0 * (10.0 / math.sqrt(3.0)) / tau**2 * _peak(np.diff(delta, axis=1) * fps)
            + 3.0 * (15.0 / 8.0) / tau * _peak(np.diff(delta, 2, axis=1) * fps**2)
        )
        choice = int(np.argmin(bound))
        if bound[choice] < best[0]:
            best = (bound[choice], window, int(cuts[choice]))
    return best[1], best[2]


def _peak(vectors: np.ndarray) -> np.ndarray:
    """The longest of the vectors (C, ..., 3) of each candidate: (C,)."""
    return np.linalg.norm(vectors, axis=-1).reshape(len(vectors), -1).max(axis=1)


def _travel(tail: np.ndarray, head: np.ndarray) -> np.ndarray:
    """How far the root moves horizontally in one cycle: the mean offset of the root in the fade's
    end window ``tail`` (..., W, J, 3) from the clip's first frames ``head`` (W, J, 3), which the
    fade moves onto it."""
    return (tail[..., 0, :] - head[:, 0]).mean(axis=-2) * _HORIZONTAL
