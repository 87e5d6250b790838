"""Leaps (jumps and hops): the ballistic chain of crouch, take-off, flight and landing, its
heights and travel over time, and the feet through it."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from m2d2m.motion.representation.smoothing import gaussian_smooth
from pipelines.synthetic.body import (
    FOOT_PITCH,
    FPS,
    GRAVITY,
    LIFT_PITCH,
    TOE_HEIGHT,
    Body,
)
from pipelines.synthetic.maths import UP, ease, foot_direction


@dataclass(frozen=True)
class _Leap:
    """Vertical timing of one take-off and landing: a crouch, a push with constant upward
    acceleration, a ballistic flight, a landing that brakes with constant deceleration and a
    recovery, so the pelvis height and its velocity are continuous. Times are frames."""

    start: float
    crouch_end: float
    takeoff: float
    touchdown: float
    absorbed: float
    end: float
    before: float  # pelvis height when the crouch starts
    low: float
    lift_height: float  # pelvis height at take-off and touchdown
    bottom: float
    after: float  # pelvis height after the recovery
    speed_up: float

    @staticmethod
    def plan(
        start: float,
        before: float,
        low: float,
        lift_height: float,
        apex: float,
        bottom: float,
        after: float,
        crouch_time: float,
        recover_time: float,
    ) -> _Leap:
        speed_up = float(np.sqrt(2.0 * GRAVITY * apex))
        crouch_end = start + crouch_time * FPS
        takeoff = crouch_end + 2.0 * (lift_height - low) / speed_up * FPS
        touchdown = takeoff + 2.0 * speed_up / GRAVITY * FPS
        absorbed = touchdown + 2.0 * (lift_height - bottom) / speed_up * FPS
        return _Leap(
            start,
            crouch_end,
            takeoff,
            touchdown,
            absorbed,
            absorbed + recover_time * FPS,
            before,
            low,
            lift_height,
            bottom,
            after,
            speed_up,
        )

    def height(self, t: np.ndarray) -> np.ndarray:
        """Pelvis height at frames ``t`` (held outside the leap)."""
        y = np.where(t < self.start, self.before, self.after).astype(np.float64)
        phase = (t >= self.start) & (t < self.crouch_end)
        y[phase] = self.before + (self.low - self.before) * ease(
            (t[phase] - self.start) / (self.crouch_end - self.start)
        )
        phase = (t >= self.crouch_end) & (t < self.takeoff)
        tau = (t[phase] - self.crouch_end) / FPS
        push = (self.takeoff - self.crouch_end) / FPS
        y[phase] = self.low + 0.5 * self.speed_up / push * tau**2
        phase = (t >= self.takeoff) & (t < self.touchdown)
        tau = (t[phase] - self.takeoff) / FPS
        y[phase] = self.lift_height + self.speed_up * tau - 0.5 * GRAVITY * tau**2
        phase = (t >= self.touchdown) & (t < self.absorbed)
        tau = (t[phase] - self.touchdown) / FPS
        brake = (self.absorbed - self.touchdown) / FPS
        y[phase] = self.lift_height - self.speed_up * tau + 0.5 * self.speed_up / brake * tau**2
        phase = (t >= self.absorbed) & (t < self.end)
        y[phase] = self.bottom + (self.after - self.bottom) * ease(
            (t[phase] - self.absorbed) / max(self.end - self.absorbed, 1e-9)
        )
        return y


def leap_chain(
    body: Body,
    count: int,
    start: float,
    stand: float,
    crouch: float,
    apex: float,
    absorb: float,
    crouch_time: float,
    rng: np.random.Generator,
) -> list[_Leap]:
    """``count`` leaps back to back: the landing crouch of one is the take-off crouch of the
    next, and only the last one recovers to standing."""
    toes_up = TOE_HEIGHT + body.foot * np.sin(FOOT_PITCH + LIFT_PITCH)
    lift_height = toes_up + 0.975 * body.leg
    leaps, before = [], stand
    for k in range(count):
        last = k == count - 1
        height = apex * rng.uniform(0.85, 1.15)
        leap = _Leap.plan(
            start,
            before,
            stand - crouch,
            lift_height,
            height,
            stand - absorb,
            stand if last else stand - absorb,
            crouch_time if k == 0 else 0.1,
            0.45 if last else 0.0,
        )
        leaps.append(leap)
        start, before = leap.end, leap.after
    return leaps


def leap_heights(leaps: Sequence[_Leap], t: np.ndarray) -> np.ndarray:
    """Pelvis height through a chain of leaps."""
    y = leaps[0].height(t)
    for leap in leaps[1:]:
        later = t >= leap.start
        y[later] = leap.height(t[later])
    return y


def leap_travel(leaps: Sequence[_Leap], distances: Sequence[float], t: np.ndarray) -> np.ndarray:
    """Forward pelvis travel through a chain of leaps: ahead of the feet at each take-off, behind
    them at each touchdown, never stopping between leaps (knots, then lightly smoothed)."""
    feet = np.concatenate([[0.0], np.cumsum(distances)])
    first, last = leaps[0], leaps[-1]
    knots = [(first.start, 0.0), (first.crouch_end, -0.1 * distances[0])]
    for k, leap in enumerate(leaps):
        ahead = 0.3 * distances[k]
        knots += [(leap.takeoff, feet[k] + ahead), (leap.touchdown, feet[k + 1] - ahead)]
    knots += [(last.absorbed, feet[-1] + 0.1 * distances[-1]), (last.end, feet[-1])]
    times, values = zip(*knots)
    return gaussian_smooth(np.interp(t, times, values), 1.5, truncate=3.0)


def leap_foot(
    body: Body,
    leaps: Sequence[_Leap],
    t: np.ndarray,
    start: np.ndarray,
    heading: np.ndarray,
    distances: Sequence[float],
    yaw: float,
    tuck: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Ankle targets and pitch of a foot that leaps: it rises on its toes in each push, flies
    with the pelvis (tucked up by ``tuck``), lands on its toes and rolls down flat, its toe fixed
    on the floor whenever it touches it."""
    ankles = np.repeat(start[None], len(t), axis=0)
    pitch = np.full(len(t), FOOT_PITCH)
    yaw_t = np.full(len(t), yaw)
    flat = body.foot * foot_direction(np.array(yaw), np.array(FOOT_PITCH))
    high = body.foot * foot_direction(np.array(yaw), np.array(FOOT_PITCH + LIFT_PITCH))
    planted = start.copy()
    for leap, distance in zip(leaps, distances):
        landing = planted + heading * distance
        toe_from, toe_to = planted + flat, landing + flat
        rise = leap.crouch_end + 0.3 * (leap.takeoff - leap.crouch_end)
        phase = (t >= rise) & (t < leap.takeoff)
        p = FOOT_PITCH + LIFT_PITCH * ((t[phase] - rise) / (leap.takeoff - rise)) ** 2
        ankles[phase] = toe_from - body.foot * foot_direction(yaw_t[phase], p)
        pitch[phase] = p

        phase = (t >= leap.takeoff) & (t < leap.touchdown)
        u = (t[phase] - leap.takeoff) / (leap.touchdown - leap.takeoff)
        path = (toe_from - high) + ((toe_to - high) - (toe_from - high)) * u[:, None]
        lifted = leap.height(t[phase]) - leap.lift_height + tuck * np.sin(np.pi * u)
        ankles[phase] = path + UP * lifted[:, None]
        pitch[phase] = FOOT_PITCH + LIFT_PITCH - 0.3 * np.sin(np.pi * u) ** 2

        flat_again = leap.touchdown + 0.5 * (leap.absorbed - leap.touchdown)
        phase = (t >= leap.touchdown) & (t < flat_again)
        p = FOOT_PITCH + LIFT_PITCH * (1.0 - ease((t[phase] - leap.touchdown) / (flat_again - leap.touchdown)))
        ankles[phase] = toe_to - body.foot * foot_direction(yaw_t[phase], p)
        pitch[phase] = p
        ankles[t >= flat_again] = landing
        pitch[t >= flat_again] = FOOT_PITCH
        planted = landing
    return ankles, pitch
