"""Locomotion driven by footsteps: gaits, foot tracks (planted, rolled over the toes, swung to
the next footprint), the pelvis following the smoothed middle of the feet, and the routes
(straight, circle) the footprints follow."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from m2d2m.motion.representation.rotations import dot
from m2d2m.motion.representation.smoothing import gaussian_smooth
from pipelines.synthetic.body import (
    FOOT_PITCH,
    FPS,
    LEFT,
    RIGHT,
    SIGN,
    Body,
    State,
    arm_pose,
)
from pipelines.synthetic.maths import (
    UP,
    ease,
    foot_direction,
    forward_direction,
    leftward,
)
from pipelines.synthetic.program import Program, hold_pose


@dataclass(frozen=True)
class Step:
    """One footstep: which foot, when it leaves and touches the floor (frames), where it lands."""

    side: int
    lift: float
    land: float
    ankle: np.ndarray
    yaw: float


@dataclass(frozen=True)
class Gait:
    """How a kind of stepping looks; lengths in metres, angles in radians, times in seconds."""

    roll: float = 0.0  # heel-off (pivot on the toes) before lift-off; 0 = flat steps
    toe_off: float = 0.0  # extra toes-down pitch reached at lift-off
    land_pitch: float = 0.0  # pitch offset at touchdown (negative: toes up, heel first)
    settle: float = 0.1  # time for the foot to come flat after touchdown
    clearance: float = 0.06  # peak ankle lift in swing
    crouch: float = 0.0  # pelvis lowered while stepping
    bounce: float = 0.0  # extra pelvis drop while a foot is on the floor (running)
    lean: float = 0.02  # trunk flexion while stepping
    arm_swing: float = 0.0  # shoulder swing amplitude
    elbow: float = 0.3  # elbow flexion while stepping
    sway: float = 0.0  # lateral pelvis shift over the supporting foot
    twist: float = 0.0  # pelvis rotation about the vertical with the legs


WALK = Gait(
    roll=0.2,
    toe_off=0.8,
    land_pitch=-0.3,
    settle=0.12,
    clearance=0.07,
    crouch=0.02,
    lean=0.04,
    arm_swing=0.32,
    elbow=0.35,
    sway=0.025,
    twist=0.09,
)


JOG = Gait(
    roll=0.1,
    toe_off=0.7,
    land_pitch=-0.1,
    settle=0.06,
    clearance=0.13,
    crouch=0.05,
    bounce=0.035,
    lean=0.12,
    arm_swing=0.55,
    elbow=1.35,
    sway=0.012,
    twist=0.1,
)


RUN = Gait(
    roll=0.08,
    toe_off=0.75,
    land_pitch=0.0,
    settle=0.05,
    clearance=0.2,
    crouch=0.06,
    bounce=0.05,
    lean=0.2,
    arm_swing=0.75,
    elbow=1.5,
    sway=0.01,
    twist=0.12,
)


BACKWARD = Gait(clearance=0.06, crouch=0.02, lean=0.0, arm_swing=0.15, elbow=0.35, sway=0.02, twist=0.04)


SHUFFLE = Gait(clearance=0.05, crouch=0.03, lean=0.03, elbow=0.35, settle=0.05)


def _foot_tracks(
    body: Body, state: State, steps: Sequence[Step], frames: int, gait: Gait
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ankle targets (T, 2, 3), foot yaw and pitch (T, 2) and on-floor flags (T, 2) of footsteps:
    each foot stays planted, rolls over its toes, swings to its next footprint and settles flat."""
    t = np.arange(frames, dtype=np.float64)
    ankles = np.repeat(state.ankles[None], frames, axis=0)
    yaw = np.repeat(state.foot_yaw[None], frames, axis=0)
    pitch = np.full((frames, 2), FOOT_PITCH)
    down = np.ones((frames, 2), dtype=bool)
    current = {side: (state.ankles[side], float(state.foot_yaw[side])) for side in (LEFT, RIGHT)}
    roll, settle = gait.roll * FPS, max(gait.settle * FPS, 1e-6)
    for step in sorted(steps, key=lambda s: s.lift):
        side = step.side
        start_ankle, start_yaw = current[side]
        toe = start_ankle + body.foot * foot_direction(np.array(start_yaw), np.array(FOOT_PITCH))
        off_pitch = FOOT_PITCH + (gait.toe_off if roll > 0 else 0.0)

        rolling = (t >= step.lift - roll) & (t < step.lift)
        if roll > 0 and rolling.any():
            u = (t[rolling] - (step.lift - roll)) / roll
            p = FOOT_PITCH + gait.toe_off * u**2
            ankles[rolling, side] = toe - body.foot * foot_direction(np.full_like(p, start_yaw), p)
            pitch[rolling, side] = p
        off_ankle = toe - body.foot * foot_direction(np.array(start_yaw), np.array(off_pitch))

        swinging = (t >= step.lift) & (t < step.land)
        u = (t[swinging] - step.lift) / (step.land - step.lift)
        s = ease(u)[:, None]
        path = off_ankle + (step.ankle - off_ankle) * s
        path[:, 1] += gait.clearance * body.scale * np.sin(np.pi * u**0.8)
        ankles[swinging, side] = path
        yaw[swinging, side] = start_yaw + (step.yaw - start_yaw) * s[:, 0]
        pitch[swinging, side] = off_pitch + (FOOT_PITCH + gait.land_pitch - off_pitch) * s[:, 0]
        down[swinging, side] = False

        landed = t >= step.land
        ankles[landed, side] = step.ankle
        yaw[landed, side] = step.yaw
        pitch[landed, side] = FOOT_PITCH + gait.land_pitch * (1.0 - ease((t[landed] - step.land) / settle))
        current[side] = (step.ankle, step.yaw)
    return ankles, yaw, pitch, down


def stepping(
    body: Body,
    state: State,
    steps: Sequence[Step],
    gait: Gait,
    period: float,
    *,
    end_yaw: float | None = None,
    seconds_after: float = 0.45,
) -> tuple[Program, State]:
    """Program of a footstep sequence: feet from :func:`_foot_tracks`, the pelvis at the smoothed
    middle of the feet (so stride × cadence is its speed) with sway over the supporting foot,
    counter-rotating pelvis and chest, and arms swinging opposite to the legs."""
    last = max(s.land for s in steps) + gait.settle * FPS
    frames = int(np.ceil(last + seconds_after * FPS))
    ankles, foot_yaw, foot_pitch, down = _foot_tracks(body, state, steps, frames, gait)
    program = hold_pose(body, state, frames)
    t = np.arange(frames, dtype=np.float64)
    sigma = 0.3 * period * FPS

    first = min(s.lift for s in steps) - gait.roll * FPS - 2.0
    moving = gaussian_smooth(((t >= first) & (t <= last)).astype(np.float64), sigma, truncate=3.0)
    moving *= ease(t / 6.0) * ease((frames - 1.0 - t) / 6.0)  # at rest at both ends
    yaw = gaussian_smooth(foot_yaw.mean(axis=1), sigma, truncate=3.0)
    centre = gaussian_smooth(ankles.mean(axis=1), sigma, truncate=3.0)
    centre[:, 1] = 0.0
    final_yaw = float(foot_yaw[-1].mean()) if end_yaw is None else end_yaw
    end = State(ankles[-1].copy(), foot_yaw[-1].copy(), final_yaw, False)
    centre = _pin_end(centre, end.centre)
    yaw = _pin_end(yaw, final_yaw)

    support = gaussian_smooth(down[:, LEFT].astype(float) - down[:, RIGHT].astype(float), sigma, truncate=3.0)
    separation = dot(ankles[:, LEFT] - ankles[:, RIGHT], forward_direction(yaw))
    stride = max(float(np.percentile(np.abs(separation), 95)), 0.25)
    ahead = np.clip(gaussian_smooth(separation, 1.0, truncate=3.0) / stride, -1.0, 1.0)  # +1: left foot ahead
    airborne = gaussian_smooth((~down.any(axis=1)).astype(np.float64), 1.0, truncate=3.0)
    on_floor = gaussian_smooth(down.any(axis=1).astype(np.float64) * moving, 1.0, truncate=3.0)

    program.pelvis = centre + UP * body.stand_height
    program.pelvis += (gait.sway * body.scale * support)[:, None] * leftward(yaw)
    program.pelvis[:, 1] -= (gait.crouch * moving + gait.bounce * on_floor) * body.scale
    program.pelvis[:, 1] += 0.3 * gait.bounce * airborne * body.scale
    program.yaw = yaw - gait.twist * ahead
    program.tilt[:, 0] += 0.5 * gait.lean * moving
    program.tilt[:, 1] -= 2.0 * gait.sway * support  # the hip of the swinging leg drops
    program.trunk[:, 0] += gait.lean * moving
    program.trunk[:, 2] += 1.8 * gait.twist * ahead
    program.neck[:, 0] -= 0.8 * gait.lean * moving
    program.neck[:, 1] -= 0.8 * gait.twist * ahead
    for side in (LEFT, RIGHT):
        swing = -SIGN[side] * gait.arm_swing * body.energy * ahead
        elbow = 0.3 + (gait.elbow - 0.3) * moving + 0.35 * np.maximum(swing, 0.0)
        program.wrists[:, side], program.elbows[:, side] = arm_pose(
            body, side, 0.06 + swing, 0.12 + 0.06 * moving, elbow
        )
    program.ankles, program.foot_yaw, program.foot_pitch = ankles, foot_yaw, foot_pitch
    return program, end


def _pin_end(x: np.ndarray, target: np.ndarray | float, frames: int = 8) -> np.ndarray:
    """Bend the last ``frames`` of a curve so it ends exactly on ``target``."""
    x = np.array(x, dtype=np.float64)
    frames = min(frames, len(x))
    w = ease(np.linspace(0.0, 1.0, frames)).reshape((-1,) + (1,) * (x.ndim - 1))
    x[-frames:] += (np.asarray(target) - x[-1]) * w
    return x


Route = Callable[[float], tuple[np.ndarray, float]]


def straight(state: State, direction: float) -> Route:
    """Straight line from the feet's centre; ``direction`` relative to the heading."""
    heading = state.yaw + direction
    start, towards = state.centre, forward_direction(heading)
    return lambda s: (start + towards * s, heading)


def circle(state: State, radius: float, turn: float) -> Route:
    """Circle of ``radius`` starting at the feet's centre, curving left (``turn`` +1,
    counterclockwise seen from above) or right (−1, clockwise)."""
    centre = state.centre + turn * radius * leftward(state.yaw)

    def path(s: float) -> tuple[np.ndarray, float]:
        heading = state.yaw + turn * s / radius
        return centre - turn * radius * leftward(heading), heading

    return path


def path_steps(
    body: Body,
    path: Route,
    advances: Sequence[float],
    period: float,
    swing: float,
    gait: Gait,
    first_side: int,
    facing: float = 0.0,
) -> list[Step]:
    """Footsteps along ``path``: step i lands ``sum(advances[:i])`` along it (the last step closes
    beside the previous one), alternating feet every ``period`` seconds, each airborne for
    ``swing`` periods, feet turned to the path heading plus ``facing``."""
    steps = []
    lead = (0.2 + gait.roll) * FPS
    distance = np.concatenate([[0.0], np.cumsum(advances)])
    count = len(advances) + 1
    for i in range(count):
        side = first_side if i % 2 == 0 else 1 - first_side
        where, heading = path(float(distance[min(i + 1, count - 1)]))
        face = heading + facing
        ankle = where + SIGN[side] * 0.5 * body.step_width * leftward(face)
        ankle[1] = body.ankle_height
        lift = lead + i * period * FPS
        steps.append(Step(side, lift, lift + swing * period * FPS, ankle, face + SIGN[side] * body.toe_out))
    return steps


def ramp_lengths(count: int, length: float, ramp: Sequence[float]) -> list[float]:
    """Step advances: full ``length`` in the middle, shorter while speeding up and slowing down."""
    advances = [length] * count
    for i, factor in enumerate(ramp):
        if i < count:
            advances[i] = min(advances[i], factor * length)
            advances[-1 - i] = min(advances[-1 - i], factor * length)
    return advances
