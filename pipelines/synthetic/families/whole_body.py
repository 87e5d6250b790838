"""The whole-body families: kick, squat, bow, sit down, stand up."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pipelines.synthetic.body import (
    FOOT_PITCH,
    FPS,
    LEFT,
    RIGHT,
    SIDES,
    SIGN,
    Body,
    State,
    arm_pose,
)
from pipelines.synthetic.family import ActionFamily, draw_choice, draw_count
from pipelines.synthetic.maths import UP, forward_direction, keyframes, leftward
from pipelines.synthetic.program import Program, hold_pose, idle
from pipelines.synthetic.words import choose, number_word, times_phrase


def _seat_transition(body: Body, state: State, duration: float, standing_up: bool) -> Program:
    """Move between standing and the seat in ``duration`` frames: the trunk leans forward to keep
    the weight over the feet while the hips travel back and down (or up and forward)."""
    frames = int(np.ceil(duration + 0.3 * FPS))
    standing = hold_pose(body, replace(state, seated=False), frames)
    seated = hold_pose(body, replace(state, seated=True), frames)
    if standing_up:
        back = keyframes(frames, [(0.25 * duration, 1.0), (0.8 * duration, 0.0)])
        down = keyframes(frames, [(0.2 * duration, 1.0), (duration, 0.0)])
        lean = keyframes(frames, [(0, 0.0), (0.35 * duration, 1.0), (duration, 0.0)])
    else:
        back = keyframes(frames, [(0.05 * duration, 0.0), (0.75 * duration, 1.0)])
        down = keyframes(frames, [(0.15 * duration, 0.0), (duration, 1.0)])
        lean = keyframes(frames, [(0, 0.0), (0.55 * duration, 1.0), (duration, 0.0)])
    progress = 0.5 * (back + down)  # 0 standing, 1 seated
    program = standing
    for name in ("tilt", "trunk", "wrists", "elbows"):
        a, b = getattr(standing, name), getattr(seated, name)
        setattr(program, name, a + (b - a) * progress.reshape((-1,) + (1,) * (a.ndim - 1)))
    program.pelvis = standing.pelvis + (seated.pelvis - standing.pelvis) * back[:, None]
    program.pelvis[:, 1] = standing.pelvis[:, 1] + (seated.pelvis[:, 1] - standing.pelvis[:, 1]) * down
    program.trunk[:, 0] += 0.55 * lean
    program.tilt[:, 0] += 0.25 * lean
    program.neck[:, 0] -= 0.5 * lean
    return program


def kick(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Shift the weight onto the other foot and kick forward ``count`` times with the ``side``
    leg (knee up, snap the foot out ``low`` or ``high``, pull it back), then put the foot back."""
    kicker = SIDES.index(p["side"])
    heading = forward_direction(state.yaw)
    shift_time = rng.uniform(0.3, 0.4) * FPS
    chamber, snap, back = 0.25 * FPS, 0.17 * FPS, 0.25 * FPS
    each = chamber + snap + back
    down_time = 0.3 * FPS
    frames = int(np.ceil(2 * shift_time + p["count"] * each + down_time + 0.2 * FPS))
    program = idle(body, state, frames, rng)
    high = p["height"] == "high"
    home = state.ankles[kicker]
    knee_up = home + heading * 0.2 * body.leg + UP * 0.38 * body.leg
    reach = (0.9 if high else 0.85) * body.leg
    lift = (0.95 if high else 0.35) * body.leg
    out = home + heading * reach + UP * lift
    keys_ankle = [(0, home), (shift_time, home)]
    keys_pitch = [(0, FOOT_PITCH), (shift_time, FOOT_PITCH)]
    keys_lean = [(0, 0.0), (shift_time, 0.0)]
    now = shift_time
    for _ in range(p["count"]):
        keys_ankle += [(now + chamber, knee_up), (now + chamber + snap, out), (now + each, knee_up)]
        keys_pitch += [(now + chamber, 0.9), (now + chamber + snap, -0.3 if high else 0.3), (now + each, 0.9)]
        keys_lean += [(now + chamber, -0.05), (now + chamber + snap, -0.25 if high else -0.1), (now + each, -0.05)]
        now += each
    keys_ankle.append((now + down_time, home))
    keys_pitch.append((now + down_time, FOOT_PITCH))
    keys_lean.append((now + down_time, 0.0))
    program.ankles[:, kicker] = keyframes(frames, keys_ankle)
    program.foot_pitch[:, kicker] = keyframes(frames, keys_pitch)
    weight = keyframes(
        frames, [(0, 0.0), (shift_time, 1.0), (now + down_time, 1.0), (now + down_time + shift_time, 0.0)]
    )
    toward = -SIGN[kicker] * (0.5 * body.step_width + 0.01) * leftward(state.yaw)
    program.pelvis += weight[:, None] * toward
    program.pelvis[:, 1] -= 0.03 * body.scale * weight
    lean = keyframes(frames, keys_lean)
    program.trunk[:, 0] += lean
    program.tilt[:, 0] += 0.6 * lean
    program.tilt[:, 1] -= SIGN[kicker] * 0.05 * weight
    program.neck[:, 0] -= lean
    for side in (LEFT, RIGHT):
        forward_arm = 0.5 if side != kicker else -0.2
        program.wrists[:, side], program.elbows[:, side] = arm_pose(
            body, side, 0.06 + forward_arm * weight, 0.12 + 0.5 * weight, 0.3 + 0.6 * weight
        )
    return program, state


def kick_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    side, n, height = p["side"], p["count"], p["height"]
    times = times_phrase(n, rng, optional_once=True)
    kicks = f"a/DET {height}/ADJ kick/NOUN" if n == 1 else f"two/NUM {height}/ADJ kicks/NOUN"
    return [
        f"@kick {height}/ADV with/ADP {{their}} {side}/ADJ leg/NOUN {times}",
        f"@kick {{their}} {side}/ADJ leg/NOUN {height}/ADV {times}",
        f"@kick forward/ADV {height}/ADV with/ADP the/DET {side}/ADJ foot/NOUN {times}",
        f"@do {kicks} with/ADP {{their}} {side}/ADJ leg/NOUN",
        f"@lift {{their}} {side}/ADJ knee/NOUN and/CCONJ @kick forward/ADV {height}/ADV {times}",
    ]


KICK_FAMILY = ActionFamily(
    "kick",
    motion=kick,
    phrases=kick_phrases,
    draw=lambda r: {
        "side": draw_choice(r, SIDES),
        "height": draw_choice(r, ("low", "high")),
        "count": draw_count(r, 1, 2),
    },
)


def squat(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """``count`` squats, ``shallow`` or ``deep``: hips back and down, heels flat, trunk leaning
    forward and arms reaching forward for balance."""
    depth = (0.22 if p["depth"] == "shallow" else 0.36) * body.leg / 0.826 * rng.uniform(0.92, 1.08)
    down, hold = rng.uniform(0.65, 0.9) * FPS, rng.uniform(0.15, 0.35) * FPS
    each = 2 * down + hold
    frames = int(np.ceil(p["count"] * each + 0.2 * FPS))
    program = idle(body, state, frames, rng)
    keys = [(0.0, 0.0)]
    for k in range(p["count"]):
        keys += [(k * each + down, 1.0), (k * each + down + hold, 1.0), ((k + 1) * each, 0.0)]
    bend = keyframes(frames, keys)
    program.pelvis[:, 1] -= depth * bend
    program.pelvis -= (0.55 * depth * bend)[:, None] * forward_direction(state.yaw)
    program.tilt[:, 0] += 1.1 * depth * bend
    program.trunk[:, 0] += 0.9 * depth * bend
    program.neck[:, 0] -= 1.2 * depth * bend
    for side in (LEFT, RIGHT):
        program.wrists[:, side], program.elbows[:, side] = arm_pose(
            body, side, 0.06 + 1.4 * bend * depth / 0.36, 0.12, 0.3 - 0.1 * bend
        )
    return program, state


def squat_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    n, deep = p["count"], p["depth"] == "deep"
    how = choose(rng, ("deeply/ADV", "low/ADV")) if deep else "halfway/ADV"
    times = times_phrase(n, rng, optional_once=True)
    adjective = "deep/ADJ" if deep else "shallow/ADJ"
    squats = f"a/DET {adjective} squat/NOUN" if n == 1 else f"{number_word(n)} {adjective} squats/NOUN"
    return [
        f"@squat down/ADP {how} {times}",
        f"@squat {how} {times}",
        f"@do {squats}",
        f"@squat down/ADP {how} and/CCONJ @stand back/ADV up/ADP {times}",
        f"@bend {{their}} knees/NOUN and/CCONJ @squat {how} {times}",
    ]


SQUAT_FAMILY = ActionFamily(
    "squat",
    motion=squat,
    phrases=squat_phrases,
    draw=lambda r: {"count": draw_count(r, 1, 3), "depth": draw_choice(r, ("shallow", "deep"))},
)


def bow(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Bend forward at the hips and waist, ``slight`` (about 25°) or ``deep`` (about 50°), pause,
    and come back up; the arms stay along the body."""
    angle = np.radians(25.0 if p["depth"] == "slight" else 50.0) * rng.uniform(0.9, 1.1)
    down, hold = rng.uniform(0.7, 0.9) * FPS, rng.uniform(0.4, 0.8) * FPS
    frames = int(np.ceil(2 * down + hold + 0.2 * FPS))
    program = idle(body, state, frames, rng)
    bend = keyframes(frames, [(0, 0.0), (down, 1.0), (down + hold, 1.0), (2 * down + hold, 0.0)])
    program.tilt[:, 0] += 0.45 * angle * bend
    program.trunk[:, 0] += 0.55 * angle * bend
    program.neck[:, 0] += 0.2 * bend
    program.pelvis -= (0.12 * angle * body.scale * bend)[:, None] * forward_direction(state.yaw)
    for side in (LEFT, RIGHT):
        program.wrists[:, side], program.elbows[:, side] = arm_pose(
            body, side, 0.06 + 0.6 * angle * bend, 0.12 - 0.06 * bend, 0.3
        )
    return program, state


def bow_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    deep = p["depth"] == "deep"
    how = choose(rng, ("deeply/ADV", "low/ADV")) if deep else "slightly/ADV"
    adjective = "deep/ADJ" if deep else choose(rng, ("small/ADJ", "slight/ADJ"))
    return [
        f"@bow {how}",
        f"@take a/DET {adjective} bow/NOUN",
        f"@bow forward/ADV {how}",
        f"@bend forward/ADV {how} at/ADP the/DET waist/NOUN",
        f"@bow {how} and/CCONJ @stand back/ADV up/ADP",
        f"@give a/DET {adjective} bow/NOUN",
    ]


BOW_FAMILY = ActionFamily(
    "bow", motion=bow, phrases=bow_phrases, draw=lambda r: {"depth": draw_choice(r, ("slight", "deep"))}
)


def sit_down(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Sit down on an implied seat behind the feet: lean forward, hips back and down."""
    duration = (2.2 if p["speed"] == "slow" else 1.6) * rng.uniform(0.9, 1.1) * FPS
    return _seat_transition(body, state, duration, standing_up=False), replace(state, seated=True)


def sit_down_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    slowly = "slowly/ADV" if p["speed"] == "slow" else ""
    return [
        f"@sit down/ADP {slowly}",
        f"@sit down/ADP on/ADP a/DET chair/NOUN {slowly}",
        f"@sit {slowly} down/ADP on/ADP a/DET seat/NOUN",
        f"@take a/DET seat/NOUN {slowly}",
        f"@lower {{themselves}} {slowly} onto/ADP a/DET chair/NOUN",
    ]


SIT_DOWN_FAMILY = ActionFamily(
    "sit_down",
    motion=sit_down,
    phrases=sit_down_phrases,
    seated_after=True,
    draw=lambda r: {"speed": draw_choice(r, ("slow", "normal"))},
)


def stand_up(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Stand up from the seat: lean forward over the feet, push up, straighten."""
    duration = (2.2 if p["speed"] == "slow" else 1.6) * rng.uniform(0.9, 1.1) * FPS
    return _seat_transition(body, state, duration, standing_up=True), replace(state, seated=False)


def stand_up_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    slowly = "slowly/ADV" if p["speed"] == "slow" else ""
    return [
        f"@stand up/ADP {slowly}",
        f"@get up/ADP {slowly}",
        f"@stand up/ADP from/ADP the/DET chair/NOUN {slowly}",
        f"@get up/ADP from/ADP {{their}} seat/NOUN {slowly}",
        f"@rise {slowly} from/ADP the/DET chair/NOUN",
        f"@rise to/ADP {{their}} feet/NOUN {slowly}",
    ]


STAND_UP_FAMILY = ActionFamily(
    "stand_up",
    motion=stand_up,
    phrases=stand_up_phrases,
    seated_before=True,
    draw=lambda r: {"speed": draw_choice(r, ("slow", "normal"))},
)


ACTION_FAMILIES = (KICK_FAMILY, SQUAT_FAMILY, BOW_FAMILY, SIT_DOWN_FAMILY, STAND_UP_FAMILY)
