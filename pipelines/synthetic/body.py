"""The procedural body on the T2M skeleton: its joints, rest pose and bone lengths (drawn per
clip), and the :class:`State` an action leaves for the next one (feet, heading, seated or not)."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from m2d2m.motion.representation.rotations import dot, normalize
from m2d2m.motion.representation.skeleton import T2M
from pipelines.synthetic.maths import UP, forward_direction, leftward

FPS = T2M.fps


GRAVITY = 9.81


SIDES = ("left", "right")


LEFT, RIGHT = 0, 1


SIGN = np.array([1.0, -1.0])  # body-frame x of the left and the right side: +x is the left


HIP, KNEE, ANKLE, TOE = (1, 2), (4, 5), (7, 8), (10, 11)


COLLAR, SHOULDER, ELBOW, WRIST = (13, 14), (16, 17), (18, 19), (20, 21)


SPINE = ((3, 0.3), (6, 0.35), (9, 0.35))  # spine joints and their share of the trunk angles


TOE_HEIGHT = 0.012  # toe joint centre above the floor when the foot is down (m)


FOOT_PITCH = np.radians(22.0)  # ankle→toe bone below the horizontal when the foot is flat


NECK_REST = -1.2  # raw neck→head offset is +z; this tips it up and a little forward


COLLAR_REST = np.radians(160.0)  # raw collar→shoulder offset is −y; this points it up and out


LIFT_PITCH = 0.75  # extra toes-down pitch of a foot pushing off or landing on its toes


REACH = 0.998  # legs never straighter than this fraction of thigh + shin


_BONE_GROUPS = {
    "legs": (4, 5, 7, 8, 10, 11),
    "arms": (16, 17, 18, 19, 20, 21),
    "torso": (3, 6, 9, 12, 15),
    "hips": (1, 2),
    "collars": (13, 14),
}


def _symmetric_lengths() -> np.ndarray:
    """T2M's target bone lengths with each left/right pair replaced by its mean."""
    lengths = T2M.bone_lengths.copy()
    for left, right in zip(T2M.left_joints, T2M.right_joints):
        lengths[left] = lengths[right] = 0.5 * (lengths[left] + lengths[right])
    return lengths


@dataclass(frozen=True)
class Body:
    """One synthetic person: bone lengths (m) and a few traits of how they move."""

    lengths: np.ndarray
    scale: float
    toe_out: float  # each foot turned out from the heading (rad)
    step_width: float  # lateral distance between the ankles when standing (m)
    energy: float  # multiplier of arm swing and gesture amplitudes
    tempo: float  # multiplier of cadences

    @cached_property
    def offsets(self) -> np.ndarray:
        """Rest offsets (22, 3): T2M's raw directions times this body's lengths."""
        return T2M.raw_offsets * self.lengths[:, None]

    @property
    def thigh(self) -> float:
        return float(self.lengths[KNEE[0]])

    @property
    def shin(self) -> float:
        return float(self.lengths[ANKLE[0]])

    @property
    def foot(self) -> float:
        return float(self.lengths[TOE[0]])

    @property
    def upper_arm(self) -> float:
        return float(self.lengths[ELBOW[0]])

    @property
    def forearm(self) -> float:
        return float(self.lengths[WRIST[0]])

    @property
    def leg(self) -> float:
        return self.thigh + self.shin

    @property
    def arm(self) -> float:
        return self.upper_arm + self.forearm

    @property
    def ankle_height(self) -> float:
        """Ankle joint height when the foot is flat on the floor."""
        return TOE_HEIGHT + self.foot * float(np.sin(FOOT_PITCH))

    @property
    def stand_height(self) -> float:
        """Pelvis height when standing with the knees almost straight."""
        return self.ankle_height + 0.994 * self.leg

    @property
    def shoulder_half_width(self) -> float:
        """Lateral distance of a shoulder joint from the chest's midline."""
        return float(self.lengths[COLLAR[0]] + self.lengths[SHOULDER[0]] * np.sin(COLLAR_REST))


def sample_body(rng: np.random.Generator) -> Body:
    """A person of random size (overall ×0.85–1.15, each body part ±6 %, left = right)."""
    scale = float(np.clip(rng.normal(1.0, 0.07), 0.85, 1.15))
    lengths = _symmetric_lengths() * scale
    for joints in _BONE_GROUPS.values():
        lengths[list(joints)] *= np.clip(rng.normal(1.0, 0.025), 0.94, 1.06)
    return Body(
        lengths=lengths,
        scale=scale,
        toe_out=float(rng.uniform(0.04, 0.16)),
        step_width=float(rng.uniform(0.15, 0.22) * scale),
        energy=float(rng.uniform(0.8, 1.2)),
        tempo=float(rng.uniform(0.93, 1.07)),
    )


@dataclass(frozen=True)
class State:
    """Where an action leaves the body: feet (planted), heading and posture."""

    ankles: np.ndarray  # (2, 3)
    foot_yaw: np.ndarray  # (2,)
    yaw: float
    seated: bool = False

    @property
    def centre(self) -> np.ndarray:
        """Floor point between the feet."""
        centre = self.ankles.mean(axis=0)
        centre[1] = 0.0
        return centre


def initial_state(body: Body, rng: np.random.Generator, seated: bool = False) -> State:
    """Feet side by side at a random place and heading (raw corpora are not canonicalised)."""
    yaw = float(rng.uniform(-np.pi, np.pi))
    centre = np.array([rng.uniform(-1.0, 1.0), 0.0, rng.uniform(-1.0, 1.0)])
    return _feet_at(body, centre, yaw, seated)


def _feet_at(body: Body, centre: np.ndarray, yaw: float, seated: bool = False) -> State:
    """Standing (or seated) state with both feet at the body's width around ``centre``."""
    ankles = centre[None] + SIGN[:, None] * 0.5 * body.step_width * leftward(yaw)[None]
    ankles[:, 1] = body.ankle_height
    return State(ankles, yaw + SIGN * body.toe_out, float(yaw), seated)


def arm_pose(
    body: Body,
    side: int,
    flex: np.ndarray | float,
    abduct: np.ndarray | float,
    elbow: np.ndarray | float,
) -> tuple[np.ndarray, np.ndarray]:
    """Wrist target and elbow pole (chest frame) of an arm swung forward by ``flex``, out by
    ``abduct`` and bent forward at the elbow by ``elbow`` (radians, any broadcastable shapes)."""
    flex, abduct, elbow = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (flex, abduct, elbow)))
    s = SIGN[side]
    upper = np.stack([s * np.sin(abduct), -np.cos(abduct) * np.cos(flex), np.cos(abduct) * np.sin(flex)], axis=-1)
    ahead = np.stack([np.zeros_like(flex), np.sin(flex), np.cos(flex)], axis=-1)
    ahead = normalize(ahead - dot(ahead, upper)[..., None] * upper)
    lower = np.cos(elbow)[..., None] * upper + np.sin(elbow)[..., None] * ahead
    wrist = body.upper_arm * upper + body.forearm * lower
    pole = -ahead + np.array([0.3 * s, 0.0, 0.0])
    return wrist, pole


def rest_arms(body: Body) -> tuple[np.ndarray, np.ndarray]:
    """Relaxed arms hanging by the sides: wrist targets and elbow poles (2, 3)."""
    arms = [arm_pose(body, side, 0.06, 0.12, 0.3) for side in (LEFT, RIGHT)]
    return np.stack([a[0] for a in arms]), np.stack([a[1] for a in arms])


def seated_pelvis(body: Body, state: State) -> np.ndarray:
    """Pelvis on an implied seat: thighs level, shins about vertical."""
    back = 0.9 * body.thigh
    return state.centre - back * forward_direction(state.yaw) + UP * (body.ankle_height + 0.97 * body.shin)
