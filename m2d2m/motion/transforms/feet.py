"""Feet that stay planted: where a clip's feet touch the ground, a fix that keeps them from
sliding there, and a measure of how much they slide (docs/evaluation.md, "Feet that stay planted").

- :func:`foot_contacts`: where each foot joint touches the ground. What the clip says (a model's
  own contact channels, else HumanML3D's rule on the joints: EricGuo5513/HumanML3D
  ``motion_representation.py``, ``foot_detect`` with ``feet_thre = 0.002``, velocity only) is
  checked against the joints: a joint above the ground, or faster than a foot that touches it,
  is not in contact whatever was said; one on the ground and still is, whatever was said.
- :func:`plant_feet`: what a foot slides in each contact (:func:`slide_path`: the shortest step
  of its touching heel, ball or toe tip, so a pivot is no slide), less what a real foot creeps,
  held within a few centimetres of where the foot stands (:func:`pinning`); the whole foot moved
  by that one horizontal offset and the leg solved with analytic two-bone IK
  (:func:`two_bone_ik`). Recorded motion comes out within a centimetre (docs/evaluation.md has
  the measurements).
- :func:`fix_feet`: the two as a delivery and the evaluation's planted rows run them.
- :func:`skating_ratio`: GMD's foot skating ratio (Karunratanakul et al., "Guided Motion Diffusion
  for Controllable Human Motion Synthesis", ICCV 2023, §6.1 "Evaluation metrics";
  korrawe/guided-motion-diffusion ``data_loaders/humanml/utils/metrics.py``,
  ``calculate_skating_ratio``).

Everything is NumPy, vectorised over frames; positions are in the skeleton's units, +Y up.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m2d2m.motion.representation.features import foot_contacts as stepwise_contacts
from m2d2m.motion.representation.rotations import dot, normalize
from m2d2m.motion.representation.skeleton import Skeleton

# GMD §6.1: "the proportion of frames in which either foot skids more than a certain distance
# (2.5 cm) while maintaining contact with the ground (foot height < 5 cm)"; its code measures the
# toes (T2M joints 10 and 11), 2.5 cm per frame at 20 fps as 0.5 m/s, on the frame's horizontal
# speed and on that speed averaged over 5 frames.
SKATING_HEIGHT_M = 0.05
SKATING_SPEED_M_S = 0.5
SKATING_WINDOW = 5

# What touches the ground (foot_contacts). A foot joint touches only within GMD's 5 cm of the
# lowest that joint (either foot's) gets in the clip, a capture's own floor, and within LIFT_M of
# its own lowest over LOCAL_SECONDS either side: a real foot that steps lifts its toe 1.5-4 cm off
# where it stood, slowly enough for HumanML3D's rule (clip 012314 shuffles such steps at
# 0.3-0.9 m/s), and a contact spanning the step made the fix drag it.
LIFT_M = 0.015
LOCAL_SECONDS = 0.5
# ... and slower than HumanML3D's contact speed (0.002 m² a frame at 20 fps) on both steps around
# the frame: a foot that slides is, a swing (2.8-5 m/s in clip 012314) is not, however low.
CONTACT_SPEED_M_S = float(np.sqrt(0.002) * 20.0)
STILL_SPEED_M_S = 0.25  # a joint on the ground this slow touches it, whatever its channel says
# A channel that calls a foot planted while its step is faster than CONTACT_SPEED_M_S (faster than
# HumanML3D's rule lets a contact be, so never so in recorded motion, whose channels the rule made)
# is a model's foot sliding: believed up to this speed wherever the foot is near the floor, lifted
# a little or not. The Bandai Namco models' skating steps are 88 % such (median 0.9 m/s), where the
# ground truth's are swings (channel off in 88 %, median 3.7 m/s) (docs/evaluation.md).
SLIDE_SPEED_M_S = 2.0
HOLD_SECONDS = 0.2  # a contact is held on this long at most while its joint could still touch

# How a foot is kept from sliding (plant_feet). Real feet are not still in contact: they settle,
# creep and swivel; the fix leaves the slide slower than FREE_SPEED_M_S and, in a run of
# SETTLE_SECONDS or longer, SLIDE_TOLERANCE_M either way of where the foot stands (less in a
# shorter run, where a real foot has no time to stray: a running stance is 3-4 frames).
FREE_SPEED_M_S = 0.15
SLIDE_TOLERANCE_M = 0.02
SETTLE_SECONDS = 0.5
TOES = 0.4  # the toes' tip beyond the ball (the T2M toe joint), a share of the heel–ball length
BLEND_SECONDS = 0.2  # how long a correction takes to fade in before a contact and out after it
_EPS = 1e-9


def foot_contacts(joints: np.ndarray, skeleton: Skeleton, fps: float, features: np.ndarray | None = None) -> np.ndarray:
    """(T, 4) contact flags of the feature layout's order (left ankle, left toe, right ankle, right
    toe).

    What the clip says comes from the features' own contact channels when given (a model's output
    rounded at 0.5), else from HumanML3D's rule on the joints (a displacement to the next frame
    under its threshold, the threshold's speed at any ``fps``; the last frame repeats the one
    before it). The joints then decide: a joint off the ground (:func:`on_ground`) or faster than
    :data:`CONTACT_SPEED_M_S` on either step around the frame does not touch; one on the ground
    and slower than :data:`STILL_SPEED_M_S` does. Each run is held on for up to
    :data:`HOLD_SECONDS` while its joint could still touch (:func:`hold_while_grounded`)."""
    joints = skeleton.check_joints(joints)
    if features is not None:
        features = np.asarray(features)
        if features.shape != (len(joints), skeleton.feature_dim):
            raise ValueError(
                f"expected features of shape ({len(joints)}, {skeleton.feature_dim}) for {len(joints)} frames, "
                f"got {features.shape}"
            )
    if len(joints) < 2:
        return np.zeros((len(joints), 4), dtype=bool)
    if features is not None:
        said = features[:, -4:] > 0.5
    else:
        flags = stepwise_contacts(joints * (fps / skeleton.fps), skeleton) > 0.5
        said = np.concatenate([flags, flags[-1:]])
    feet = joints[:, list(skeleton.feet_left + skeleton.feet_right)] * skeleton.metres_per_unit
    low, floor = on_ground(feet, fps), near_floor(feet)
    speed = _speeds(feet, fps)
    possible = low & (speed < CONTACT_SPEED_M_S)
    outgoing = step_speeds(feet, fps)
    sliding = (
        said & floor & (np.concatenate([outgoing, outgoing[-1:]]) >= CONTACT_SPEED_M_S) & (speed < SLIDE_SPEED_M_S)
    )
    seeds = (said & possible) | sliding | (low & (speed < STILL_SPEED_M_S))
    hold = int(round(HOLD_SECONDS * fps))
    return np.stack([hold_while_grounded(seeds[:, k], possible[:, k], hold) for k in range(4)], axis=1)


def near_floor(feet: np.ndarray) -> np.ndarray:
    """(T, 4) whether each joint of ``feet`` (T, 4, 3), metres, in :func:`foot_contacts`' order,
    is within :data:`SKATING_HEIGHT_M` of the lowest height that joint, on either foot, has in
    the clip: the floor is the clip's own (a capture need not stand at y = 0)."""
    height = feet[..., 1]
    lowest = np.minimum(height[:, [0, 1]].min(axis=0), height[:, [2, 3]].min(axis=0))[[0, 1, 0, 1]]
    return height - lowest < SKATING_HEIGHT_M


def on_ground(feet: np.ndarray, fps: float) -> np.ndarray:
    """(T, 4) whether each joint of ``feet`` (T, 4, 3), metres, is low enough to touch the
    ground: :func:`near_floor`, and within :data:`LIFT_M` of its own lowest over
    :data:`LOCAL_SECONDS` either side, which tells a foot that stands from one that has lifted to
    step."""
    height = feet[..., 1]
    reach = max(1, int(round(LOCAL_SECONDS * fps)))
    padded = np.pad(height, [(reach, reach), (0, 0)], mode="edge")
    local = np.lib.stride_tricks.sliding_window_view(padded, 2 * reach + 1, axis=0).min(axis=-1)
    return near_floor(feet) & (height - local < LIFT_M)


def two_bone_ik(
    hip: np.ndarray, knee: np.ndarray, ankle: np.ndarray, target: np.ndarray, pole: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """New (knee, ankle), each (..., 3), putting the ankle at ``target`` with the hip where it is.

    The thigh and shin keep their lengths in ``hip, knee, ankle`` exactly. A target out of reach
    (farther than thigh + shin, or nearer than their difference) gives the nearest reachable point,
    on the line from the hip to the target. The knee stays on its side of that line, in the plane
    of the line and the original knee; a straight leg, which has no such side, bends towards
    ``pole`` (any perpendicular when not given). Law of cosines: the knee is at angle α from the
    hip–ankle line with cos α = (thigh² + d² − shin²) / (2·thigh·d).
    """
    thigh = np.sqrt(dot(knee - hip, knee - hip))
    shin = np.sqrt(dot(ankle - knee, ankle - knee))
    reach = target - hip
    far = np.sqrt(dot(reach, reach))
    direction = np.where((far > _EPS)[..., None], reach, ankle - hip)
    direction = normalize(direction)
    distance = np.clip(far, np.abs(thigh - shin), thigh + shin)
    cos = np.clip((thigh**2 + distance**2 - shin**2) / (2.0 * thigh * np.maximum(distance, _EPS)), -1.0, 1.0)
    side = _perpendicular(knee - hip, direction)
    if pole is not None:
        side = np.where((dot(side, side) > _EPS)[..., None], side, _perpendicular(pole, direction))
    helper = np.where(np.abs(direction[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    side = normalize(np.where((dot(side, side) > _EPS)[..., None], side, _perpendicular(helper, direction)))
    new_knee = hip + thigh[..., None] * (cos[..., None] * direction + np.sqrt(1.0 - cos**2)[..., None] * side)
    return new_knee, hip + distance[..., None] * direction


def _perpendicular(vector: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The part of ``vector`` perpendicular to the unit ``axis``."""
    return vector - dot(vector, axis)[..., None] * axis


def _smoothstep(x: np.ndarray) -> np.ndarray:
    return x * x * (3.0 - 2.0 * x)


def contact_runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """(first, end) frames of each run of True in ``flags`` (T,), end exclusive."""
    padded = np.concatenate([[False], np.asarray(flags, dtype=bool), [False]])
    edges = np.flatnonzero(padded[1:] != padded[:-1])
    return [(int(first), int(end)) for first, end in zip(edges[::2], edges[1::2])]


def hold_while_grounded(flags: np.ndarray, grounded: np.ndarray, limit: int) -> np.ndarray:
    """``flags`` (T,) with each run of True grown, before and after, over the next frames in which
    ``grounded`` (T,) holds, ``limit`` frames at most each way; two runs whose gap is grounded
    throughout and at most ``2 * limit`` frames long become one.

    Why: a model's contact flags often end while the foot is still on the ground (lift-off), begin
    after it is (touch-down), or flicker off for a frame or two in the middle of a stance (the
    demo's MotionDiffuse: 3,182 one-frame gaps in 32 sequences). Fading a lock out over such frames
    makes the foot catch up with its generated path while it still touches the ground, which is
    the very slide the fix is for; held on until the foot leaves the ground, the catching up
    happens in the air, and a foot that never left the ground between two contacts is one contact.
    """
    flags = np.asarray(flags, dtype=bool)
    held = flags.copy()
    for first, end in contact_runs(flags):
        for frames in (range(end, min(len(flags), end + limit)), range(first - 1, max(-1, first - 1 - limit), -1)):
            for frame in frames:
                if not grounded[frame]:
                    break
                held[frame] = True
    return held


def slide_path(positions: np.ndarray, contacts: np.ndarray, free: float = 0.0, toes: float = TOES) -> np.ndarray:
    """(T, 3) how far a foot has slid over the ground, from ``positions`` (T, 2, 3) of its contact
    joints (ankle, toe) and their ``contacts`` (T, 2); ``free``: how far a step may creep
    unheeded (the skeleton's units a frame).

    A foot can hold the ground at its heel (the ankle joint), its ball (the toe joint) or the tip
    of its toes, ``toes`` of the ankle–ball length ahead of the ball over the ground. In a step in
    which a joint touches at both ends, its points may hold (the heel; the ball and the tip), and
    the foot slides by the shortest step any of them takes, less ``free``; in other steps it does
    not slide. Why: a foot that pivots keeps one point still, the heel (a turn, a heel strike),
    the ball (a heel rolling up) or the tip (a dancer's swivel), however far its joints sweep; a
    sliding foot moves every point. The tip lies along the foot's heading at a fixed length, so
    a heel rising about the ball moves it as the ball, not back."""
    flat = positions * np.array([1.0, 0.0, 1.0])
    bone = positions[:, 1] - positions[:, 0]
    ahead = toes * np.sqrt(dot(bone, bone))[:, None] * normalize(flat[:, 1] - flat[:, 0])
    points = np.stack([flat[:, 0], flat[:, 1], flat[:, 1] + ahead], axis=1)
    step = np.diff(points, axis=0)  # (T − 1, 3, 3): the heel's, the ball's and the tip's
    touching = contacts[:-1] & contacts[1:]  # (T − 1, 2)
    holding = touching[:, [0, 1, 1]]
    length = np.where(holding, np.sqrt(dot(step, step)), np.inf)
    slid = np.take_along_axis(step, np.argmin(length, axis=1)[:, None, None], axis=1)[:, 0]
    slid[~holding.any(axis=1)] = 0.0
    slid *= np.maximum(0.0, 1.0 - free / np.maximum(np.sqrt(dot(slid, slid)), _EPS))[:, None]
    return np.concatenate([np.zeros((1, 3)), np.cumsum(slid, axis=0)])


def pinning(
    slid: np.ndarray,
    flags: np.ndarray,
    blend_frames: int,
    tolerance: float,
    settle_frames: int,
    held: np.ndarray | None = None,
    held_offset: np.ndarray | None = None,
) -> np.ndarray:
    """(T, 3) the horizontal offset that keeps a foot from sliding, from how far it has slid
    (:func:`slide_path`) and where it touches the ground (``flags``, T).

    Within a contact run the foot is kept within a tolerance of where it stands in the run, the
    median of its slide there: a frame nearer is left where it is, a farther one is brought in to
    that distance. The tolerance is ``tolerance`` (the skeleton's units) in a run of
    ``settle_frames`` steps or more, proportionally less in a shorter one. Why not hold the foot at
    one point: a real foot is never that still, and moving every frame of a real run to its mean
    position moved a real knee 17 cm. The offset a run needs at its first and last frames fades
    over ``blend_frames`` frames before and after it (smoothstep), when the foot is in the air;
    between two near runs their fading offsets are averaged by weight, so no frame moves further
    than either asks.

    ``held`` (T,) frames keep ``held_offset`` (T, 3) whatever the rest asks (an edit's kept frames,
    planted as its source delivered them: :class:`KeptFrames`). A run that crosses into them is
    held within the tolerance of where the foot stands on its held frames at the crossing (the
    lock position the source gave it), not of its own median, which the new frames would move; a
    held stretch's offset fades into the free frames beside it as a run's does."""
    count = len(slid)
    held = np.zeros(count, dtype=bool) if held is None else np.asarray(held, dtype=bool)
    held_offset = np.zeros_like(slid) if held_offset is None else held_offset
    offset_sum = np.zeros_like(slid)
    weight_sum = np.zeros(count)
    ramp = _smoothstep(1.0 - np.arange(1, blend_frames + 1) / (blend_frames + 1))

    def fade(edge: np.ndarray, frames: np.ndarray) -> None:
        """``edge`` faded over ``frames`` (nearest first), up to the first held frame or the clip's end."""
        inside = frames[(frames >= 0) & (frames < count)]
        inside = inside[np.cumprod(~held[inside]).astype(bool)]
        offset_sum[inside] += ramp[: len(inside), None] * edge
        weight_sum[inside] += ramp[: len(inside)]

    runs = contact_runs(flags & ~held)
    needed = []
    for first, end in runs:
        whole_first, whole_end = _run_around(flags, first, end)
        before, after = first - 1, end  # a held frame of the same run on either side: the lock position
        anchors = [
            (frame, slid[frame] + held_offset[frame])
            for frame in (before, after)
            if whole_first <= frame < whole_end and held[frame]
        ]
        if anchors:
            share = (np.arange(first, end) - before)[:, None] / (end - before)
            start, stop = anchors[0][1], anchors[-1][1]
            stray = slid[first:end] - (start + share * (stop - start))
        else:
            stray = slid[first:end] - np.median(slid[first:end], axis=0)
        distance = np.sqrt(dot(stray, stray))
        allowed = tolerance * min(1.0, (whole_end - whole_first - 1) / max(settle_frames, 1))
        needed.append((np.minimum(1.0, allowed / np.maximum(distance, _EPS)) - 1.0)[:, None] * stray)
        fade(needed[-1][0], np.arange(first - 1, first - blend_frames - 1, -1))
        fade(needed[-1][-1], np.arange(end, end + blend_frames))
    for first, end in contact_runs(held):
        fade(held_offset[first], np.arange(first - 1, first - blend_frames - 1, -1))
        fade(held_offset[end - 1], np.arange(end, end + blend_frames))
    offset = offset_sum / np.maximum(weight_sum, 1.0)[:, None]
    for (first, end), inside in zip(runs, needed):
        offset[first:end] = inside
    offset[held] = held_offset[held]
    return offset


def _run_around(flags: np.ndarray, first: int, end: int) -> tuple[int, int]:
    """The whole run of True in ``flags`` that holds frames ``first`` to ``end``."""
    while first > 0 and flags[first - 1]:
        first -= 1
    while end < len(flags) and flags[end]:
        end += 1
    return first, end


@dataclass(frozen=True)
class KeptFrames:
    """Frames a foot fix leaves as they are: ``frames`` (T,) True where the clip's ``joints``
    (T, J, 3; read only there) are final. An edit's kept frames, as its source delivered them
    (``orchestration/editing.py``): fixed again with the new frames around them, a contact run
    crossing an edit's margin moved them by up to 4 cm (issue 53)."""

    frames: np.ndarray
    joints: np.ndarray


def leg_of(skeleton: Skeleton, pair: tuple[int, int]) -> tuple[int, ...]:
    """The chain from the root through the foot joints ``pair``: root, hip, knee, ankle, foot...
    (T2M: 0, 1, 4, 7, 10 for the left pair (7, 10); KIT: 0, 16, 17, 18, 19, 20 for (19, 20))."""
    for chain in skeleton.chains:
        if set(pair) <= set(chain[3:]) and chain[0] == 0:
            return chain
    raise ValueError(f"skeleton {skeleton.name!r} has no leg chain ending in joints {pair}")


def plant_feet(
    joints: np.ndarray,
    skeleton: Skeleton,
    fps: float,
    contacts: np.ndarray | None = None,
    blend: float = BLEND_SECONDS,
    tolerance: float = SLIDE_TOLERANCE_M,
    free: float = FREE_SPEED_M_S,
    kept: KeptFrames | None = None,
) -> np.ndarray:
    """The clip (T, J, 3) with each foot kept from sliding where it touches the ground, and the
    legs solved to reach.

    ``contacts`` (T, 4) in :func:`foot_contacts`' order (from the joints when not given); per foot,
    its slide (:func:`slide_path`, less ``free`` m/s) is held within ``tolerance`` metres of where
    it stands in each contact run (:func:`pinning`, ``blend`` seconds of fading at a run's edges).
    The whole foot moves by that one horizontal offset, so a heel rolling up about the ball keeps
    rolling and the height stays the clip's; :func:`two_bone_ik` brings the ankle there from the
    unmoved hip. A frame whose foot needs no offset is the input's, bit for bit; in the others
    only the knee and the joints below it change, every bone keeping its length. ``kept`` frames
    come out as its joints give them; their feet's offsets from ours hold the contact runs that
    cross into them (:func:`pinning`)."""
    joints = skeleton.check_joints(joints)
    contacts = foot_contacts(joints, skeleton, fps) if contacts is None else np.asarray(contacts, dtype=bool)
    if contacts.shape != (len(joints), 4):
        raise ValueError(f"expected contacts of shape ({len(joints)}, 4), got {contacts.shape}")
    metres = skeleton.metres_per_unit
    blend_frames, settle_frames = int(round(blend * fps)), int(round(SETTLE_SECONDS * fps))
    held = np.zeros(len(joints), dtype=bool) if kept is None else np.asarray(kept.frames, dtype=bool)
    planted = joints.copy()
    for side, pair in enumerate((skeleton.feet_left, skeleton.feet_right)):
        chain = leg_of(skeleton, pair)
        hip, knee, ankle, foot = chain[1], chain[2], chain[3], list(chain[3:])
        touching = contacts[:, 2 * side : 2 * side + 2]
        slid = slide_path(joints[:, list(pair)], touching, free / fps / metres)
        held_offset = np.zeros_like(slid)
        if kept is not None:
            held_offset[held] = (kept.joints[held, ankle] - joints[held, ankle]) * np.array([1.0, 0.0, 1.0])
        offset = pinning(slid, touching.any(axis=1), blend_frames, tolerance / metres, settle_frames, held, held_offset)
        moved = np.flatnonzero((np.abs(offset).max(axis=1) > 0) & ~held)
        if not len(moved):
            continue
        legs = joints[moved]
        new_knee, new_ankle = two_bone_ik(
            legs[:, hip],
            legs[:, knee],
            legs[:, ankle],
            legs[:, ankle] + offset[moved],
            pole=legs[:, pair[1]] - legs[:, pair[0]],
        )
        planted[moved[:, None], foot] = legs[:, foot] + (new_ankle - legs[:, ankle])[:, None]
        planted[moved, knee] = new_knee
    if kept is not None:
        planted[held] = kept.joints[held]
    return planted


def fix_feet(
    joints: np.ndarray,
    skeleton: Skeleton,
    fps: float,
    features: np.ndarray | None = None,
    kept: KeptFrames | None = None,
) -> np.ndarray:
    """:func:`plant_feet` with the contacts :func:`foot_contacts` finds, the features' channels
    heard when they are a clip's own (one row a frame of ``skeleton``'s width; a motion known only
    by its joints has none), ``kept`` frames left as given: the one fix that a delivery and the
    evaluation's planted rows run."""
    own = features is not None and np.shape(features) == (len(joints), skeleton.feature_dim)
    contacts = foot_contacts(joints, skeleton, fps, features if own else None)
    return plant_feet(joints, skeleton, fps, contacts, kept=kept)


def step_speeds(positions: np.ndarray, fps: float) -> np.ndarray:
    """(T − 1, ...) the horizontal speed of each step between frames of ``positions`` (T, ..., 3),
    in their units per second."""
    step = np.diff(positions[..., [0, 2]], axis=0)
    return np.sqrt(dot(step, step)) * fps


def _speeds(positions: np.ndarray, fps: float) -> np.ndarray:
    """(T, ...) each frame's horizontal speed, the faster of the steps into and out of it, for
    ``positions`` (T, ..., 3) in metres: m/s."""
    speed = step_speeds(positions, fps)
    return np.maximum(np.concatenate([speed[:1], speed]), np.concatenate([speed, speed[-1:]]))


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Mean over ``window`` samples centred on each one along the last axis, zeros beyond the ends
    (GMD's ``uniform_filter1d(size=5, mode="constant")``)."""
    before = window // 2
    padded = np.pad(values, [(0, 0)] * (values.ndim - 1) + [(before, window - 1 - before)])
    return np.lib.stride_tricks.sliding_window_view(padded, window, axis=-1).mean(axis=-1)


def skating_ratio(
    joints: np.ndarray,
    skeleton: Skeleton,
    fps: float,
    height: float = SKATING_HEIGHT_M,
    speed: float = SKATING_SPEED_M_S,
    window: int = SKATING_WINDOW,
) -> float:
    """GMD's foot skating ratio of one clip: the share of its T − 1 frame steps in which a toe
    below ``height`` metres in both frames moves horizontally faster than ``speed`` m/s, both in
    that step and on average over ``window`` steps around it; NaN for a clip of one frame.

    The toes are the second joint of each foot pair (T2M 10 and 11, GMD's); heights are above
    y = 0, HumanML3D's floor. GMD's function divides by its batch's padded length − 1; here each
    clip is measured over its own steps.
    """
    joints = skeleton.check_joints(joints)
    if len(joints) < 2:
        return float("nan")
    toes = joints[:, [skeleton.feet_left[1], skeleton.feet_right[1]]] * skeleton.metres_per_unit
    horizontal = step_speeds(toes, fps).T  # (2, T − 1) m/s
    low = toes[..., 1].T < height
    skating = (low[:, :-1] & low[:, 1:]) & (horizontal > speed) & (moving_average(horizontal, window) > speed)
    return float(skating.any(axis=0).mean())
