"""Feet that stay planted: where a clip's feet touch the ground, a fix that keeps them still there,
and a measure of how much they slide (docs/evaluation.md, "Feet that stay planted").

- :func:`foot_contacts`: HumanML3D's contact flags, from the clip's own 263/251-d features when it
  has them, else from its joints with HumanML3D's rule (EricGuo5513/HumanML3D
  ``motion_representation.py``, ``foot_detect`` with ``feet_thre = 0.002``: a foot joint touches
  when its squared displacement to the next frame is below the threshold; the height test that
  ``foot_detect`` also defines is commented out there, so contacts are velocity only).
- :func:`plant_feet`: each contact run of an ankle or toe held still over the ground (at the
  run's mean horizontal position), and held on while the foot has not yet left the ground, low
  and slower than a swing (:func:`hold_while_grounded`), the leg solved with analytic two-bone
  IK (:func:`two_bone_ik`), blended in and out at the run's edges.
- :func:`skating_ratio`: GMD's foot skating ratio (Karunratanakul et al., "Guided Motion Diffusion
  for Controllable Human Motion Synthesis", ICCV 2023, §6.1 "Evaluation metrics";
  korrawe/guided-motion-diffusion ``data_loaders/humanml/utils/metrics.py``,
  ``calculate_skating_ratio``).

Everything is NumPy, vectorised over frames; positions are in the skeleton's units, +Y up.
"""

from __future__ import annotations

import numpy as np

from m2d2m.motion.representation import foot_contacts as stepwise_contacts
from m2d2m.motion.rotations import dot, normalize, qbetween, qrot
from m2d2m.motion.skeleton import Skeleton

# GMD §6.1: "the proportion of frames in which either foot skids more than a certain distance
# (2.5 cm) while maintaining contact with the ground (foot height < 5 cm)"; its code measures the
# toes (T2M joints 10 and 11), 2.5 cm per frame at 20 fps as 0.5 m/s, on the frame's horizontal
# speed and on that speed averaged over 5 frames.
SKATING_HEIGHT_M = 0.05
SKATING_SPEED_M_S = 0.5
SKATING_WINDOW = 5
BLEND_SECONDS = 0.2  # how long a correction takes to fade in before a contact and out after it
HOLD_SECONDS = 0.2  # how long a contact is held on at most while its foot's toe is still near the ground
# ... and moving slower than this: a foot faster is swinging, not on the ground, however low (the
# sample clip's low swings run at 2.8-4.5 m/s; a walking foot's swing averages about twice the
# walking speed of 1.2-1.4 m/s). Holding such a foot drags it after the body (its leg cannot reach).
HOLD_SPEED_M_S = 2.0
_EPS = 1e-9


def foot_contacts(joints: np.ndarray, skeleton: Skeleton, fps: float, features: np.ndarray | None = None) -> np.ndarray:
    """(T, 4) contact flags of the feature layout's order (left ankle, left toe, right ankle, right
    toe): the features' own contact channels when given (a model's output rounded at 0.5), else
    HumanML3D's rule on the joints. A flag is about the step to the next frame, so the last frame
    repeats the one before it. The rule's threshold holds at the corpus's frame rate; at another
    ``fps`` the same speed is the threshold (displacements are rescaled to the corpus's rate)."""
    joints = skeleton.check_joints(joints)
    if features is not None:
        features = np.asarray(features)
        if features.shape != (len(joints), skeleton.feature_dim):
            raise ValueError(
                f"expected features of shape ({len(joints)}, {skeleton.feature_dim}) for {len(joints)} frames, "
                f"got {features.shape}"
            )
        return features[:, -4:] > 0.5
    if len(joints) < 2:
        return np.zeros((len(joints), 4), dtype=bool)
    flags = stepwise_contacts(joints * (fps / skeleton.fps), skeleton) > 0.5
    return np.concatenate([flags, flags[-1:]])


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


def planting(positions: np.ndarray, flags: np.ndarray, blend_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Where one joint should move: per frame a horizontal offset (T, 3) and how planted the joint
    is (T,), in [0, 1].

    Within a contact run the joint goes to the run's mean position over the ground, so it stops
    sliding; its height stays the clip's (a heel still rises, a foot still sets down, and no frame
    is pulled under GMD's 5 cm that was not there). The offset a run needs at its first and last
    frames fades over ``blend_frames`` frames before and after it (smoothstep); between two near
    runs their fading offsets are averaged by weight, so no frame moves further than either asks.
    """
    ground = positions * np.array([1.0, 0.0, 1.0])
    offset_sum = np.zeros_like(ground)
    weight_sum = np.zeros(len(ground))
    ramp = _smoothstep(1.0 - np.arange(1, blend_frames + 1) / (blend_frames + 1))
    runs = contact_runs(flags)
    locks = [ground[first:end].mean(axis=0) for first, end in runs]
    for (first, end), lock in zip(runs, locks):
        before = np.arange(first - 1, first - blend_frames - 1, -1)
        after = np.arange(end, end + blend_frames)
        for frames, edge in ((before, first), (after, end - 1)):
            kept = (frames >= 0) & (frames < len(ground))
            offset_sum[frames[kept]] += ramp[kept, None] * (lock - ground[edge])
            weight_sum[frames[kept]] += ramp[kept]
    offset = offset_sum / np.maximum(weight_sum, 1.0)[:, None]
    weight = np.minimum(weight_sum, 1.0)
    for (first, end), lock in zip(runs, locks):
        offset[first:end] = lock - ground[first:end]
        weight[first:end] = 1.0
    return offset, weight


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
    hold: float = HOLD_SECONDS,
    ground: float = SKATING_HEIGHT_M,
    hold_speed: float = HOLD_SPEED_M_S,
) -> np.ndarray:
    """The clip (T, J, 3) with each contact's foot joint kept from sliding and the legs solved to
    reach.

    ``contacts`` (T, 4) in :func:`foot_contacts`'s order (computed from the joints when not
    given); ``blend`` seconds of fading at a run's edges; a foot's contacts are held on for up to
    ``hold`` seconds while its toe stays below ``ground`` metres (GMD's height of a foot near the
    ground) and slower than ``hold_speed`` m/s (:data:`HOLD_SPEED_M_S`) by
    :func:`hold_while_grounded`. Per foot, the two contact joints (ankle,
    toe) get their targets from :func:`planting`; the segment between them keeps its length,
    anchored between the two targets by how planted each is (all on the ankle when only the heel
    is planted, all on the toe when only the toe is); the rest of the foot turns rigidly with it;
    :func:`two_bone_ik` brings the ankle there from the unmoved hip. Only the knee and the joints
    below it change, and only in frames that a contact or its blend reaches: every bone keeps its
    length in every frame, the rest of the body is the input's, bit for bit.
    """
    joints = skeleton.check_joints(joints)
    contacts = foot_contacts(joints, skeleton, fps) if contacts is None else np.asarray(contacts, dtype=bool)
    if contacts.shape != (len(joints), 4):
        raise ValueError(f"expected contacts of shape ({len(joints)}, 4), got {contacts.shape}")
    blend_frames, hold_frames = int(round(blend * fps)), int(round(hold * fps))
    planted = joints.copy()
    for side, pair in enumerate((skeleton.feet_left, skeleton.feet_right)):
        chain = leg_of(skeleton, pair)
        hip, knee, ankle, foot = chain[1], chain[2], chain[3], list(chain[3:])
        heel, toe = joints[:, pair[0]], joints[:, pair[1]]
        grounded = (toe[:, 1] * skeleton.metres_per_unit < ground) & (_speeds(toe, skeleton, fps) < hold_speed)
        heel_flags, toe_flags = (hold_while_grounded(contacts[:, 2 * side + k], grounded, hold_frames) for k in (0, 1))
        heel_offset, heel_weight = planting(heel, heel_flags, blend_frames)
        toe_offset, toe_weight = planting(toe, toe_flags, blend_frames)
        moved = heel_weight + toe_weight > 0
        if not moved.any():
            continue
        legs, heel_at, toe_at = joints[moved], heel[moved], toe[moved]
        heel_goal, toe_goal = heel_at + heel_offset[moved], toe_at + toe_offset[moved]
        length = np.sqrt(dot(toe_at - heel_at, toe_at - heel_at))[:, None]
        along = normalize(toe_goal - heel_goal)
        anchor = (toe_weight[moved] / (heel_weight[moved] + toe_weight[moved]))[:, None]
        new_heel = (1.0 - anchor) * heel_goal + anchor * toe_goal - anchor * length * along
        turn = qbetween(toe_at - heel_at, along)[:, None]
        new_foot = new_heel[:, None] + qrot(turn, legs[:, foot] - heel_at[:, None])
        new_knee, new_ankle = two_bone_ik(legs[:, hip], legs[:, knee], legs[:, ankle], new_foot[:, 0], pole=along)
        planted[np.flatnonzero(moved)[:, None], foot] = new_foot + (new_ankle - new_foot[:, 0])[:, None]
        planted[moved, knee] = new_knee
    return planted


def step_speeds(positions: np.ndarray, fps: float) -> np.ndarray:
    """(T − 1, ...) the horizontal speed of each step between frames of ``positions`` (T, ..., 3),
    in their units per second."""
    step = np.diff(positions[..., [0, 2]], axis=0)
    return np.sqrt(dot(step, step)) * fps


def _speeds(positions: np.ndarray, skeleton: Skeleton, fps: float) -> np.ndarray:
    """(T,) each frame's horizontal speed in m/s, the faster of the steps into and out of it."""
    speed = step_speeds(positions * skeleton.metres_per_unit, fps)
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
