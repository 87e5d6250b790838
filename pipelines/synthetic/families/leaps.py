"""The leaping families: jump and hop."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from m2d2m.motion.representation.smoothing import gaussian_smooth
from pipelines.synthetic.body import (
    FPS,
    HIP,
    LEFT,
    RIGHT,
    SIDES,
    SIGN,
    Body,
    State,
    arm_pose,
)
from pipelines.synthetic.family import ActionFamily, draw_choice, draw_count
from pipelines.synthetic.leaping import leap_chain, leap_foot, leap_heights, leap_travel
from pipelines.synthetic.maths import (
    UP,
    forward_direction,
    keyframes,
    leftward,
    to_world,
)
from pipelines.synthetic.program import Program, hold_pose, idle
from pipelines.synthetic.words import choose, number_word, times_phrase


def jump(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """``count`` two-footed jumps, ``in_place`` or ``forward`` (about 0.5–0.9 m each): crouch with
    the arms swung back, push off the toes swinging the arms up, fly, land on the toes, absorb."""
    forward = p["direction"] == "forward"
    distances = [rng.uniform(0.5, 0.9) * body.scale if forward else 0.0 for _ in range(p["count"])]
    apex = (rng.uniform(0.12, 0.2) if forward else rng.uniform(0.16, 0.3)) * body.scale
    leaps = leap_chain(
        body,
        p["count"],
        2.0,
        body.stand_height,
        rng.uniform(0.14, 0.22) * body.scale,
        apex,
        rng.uniform(0.1, 0.16) * body.scale,
        0.4,
        rng,
    )
    frames = int(np.ceil(leaps[-1].end)) + 1
    t = np.arange(frames, dtype=np.float64)
    heading = forward_direction(state.yaw)
    program = hold_pose(body, state, frames)
    program.pelvis = (
        state.centre + heading * leap_travel(leaps, distances, t)[:, None] + UP * leap_heights(leaps, t)[:, None]
    )
    for side in (LEFT, RIGHT):
        program.ankles[:, side], program.foot_pitch[:, side] = leap_foot(
            body,
            leaps,
            t,
            state.ankles[side],
            heading,
            distances,
            float(state.foot_yaw[side]),
            tuck=0.35 * apex,
        )
    trunk_keys, arm_keys = [(0.0, 0.0)], [(0.0, 0.06)]
    lean = 0.1 + 0.3 * forward
    for leap in leaps:
        middle = 0.5 * (leap.takeoff + leap.touchdown)
        trunk_keys += [(leap.crouch_end, 0.45), (leap.takeoff, lean), (middle, 0.5 * lean), (leap.absorbed, 0.35)]
        arm_keys += [(leap.crouch_end, -0.7), (middle, 1.9 * body.energy), (leap.absorbed, 0.4)]
    trunk_keys.append((leaps[-1].end, 0.0))
    arm_keys.append((leaps[-1].end, 0.06))
    trunk = gaussian_smooth(keyframes(frames, trunk_keys), 1.5, truncate=3.0)
    program.trunk[:, 0] = trunk
    program.tilt[:, 0] += 0.6 * trunk
    program.neck[:, 0] -= 0.7 * trunk
    flex = gaussian_smooth(keyframes(frames, arm_keys), 2.0, truncate=3.0)
    for side in (LEFT, RIGHT):
        program.wrists[:, side], program.elbows[:, side] = arm_pose(body, side, flex, 0.2, 0.4)
    return program, replace(state, ankles=state.ankles + heading * sum(distances))


def jump_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    n = p["count"]
    times = times_phrase(n, rng, optional_once=True)
    if p["direction"] == "forward":
        phrases = [
            f"@jump forward/ADV {times}",
            f"@leap forward/ADV {times}",
            f"@jump forward/ADV with/ADP both/DET feet/NOUN {times}",
        ]
        phrases.append(f"@do {number_word(n)} jumps/NOUN forward/ADV" if n > 1 else "@do a/DET jump/NOUN forward/ADV")
        return phrases
    phrases = [
        f"@jump in/ADP place/NOUN {times}",
        f"@jump on/ADP the/DET spot/NOUN {times}",
        f"@jump straight/ADV up/ADV {times}",
    ]
    phrases.append(
        f"@do {number_word(n)} jumps/NOUN in/ADP place/NOUN" if n > 1 else "@do a/DET jump/NOUN in/ADP place/NOUN"
    )
    if n > 1:
        phrases.append(f"@jump up/ADV and/CCONJ down/ADV {times}")
    return phrases


JUMP_FAMILY = ActionFamily(
    "jump",
    motion=jump,
    phrases=jump_phrases,
    draw=lambda r: {"direction": draw_choice(r, ("in_place", "forward")), "count": draw_count(r, 1, 3)},
)


def hop(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """``count`` hops on the ``side`` leg, ``in_place`` or ``forward``: the other foot is lifted
    behind with the knee bent and the arms held out a little for balance, then put back down."""
    stance = SIDES.index(p["side"])
    free = 1 - stance
    forward = p["direction"] == "forward"
    heading, left = forward_direction(state.yaw), leftward(state.yaw)
    lift_time = put_time = 0.5 * FPS
    distances = [rng.uniform(0.25, 0.4) * body.scale if forward else 0.0 for _ in range(p["count"])]
    stand = body.stand_height - 0.03 * body.scale
    leaps = leap_chain(
        body,
        p["count"],
        lift_time,
        stand,
        0.07 * body.scale,
        rng.uniform(0.06, 0.1) * body.scale,
        0.07 * body.scale,
        0.2,
        rng,
    )
    hopped = leaps[-1].end
    frames = int(np.ceil(hopped + put_time + 0.3 * FPS))
    t = np.arange(frames, dtype=np.float64)

    lifted = keyframes(frames, [(0, 0.0), (lift_time, 1.0), (hopped, 1.0), (hopped + put_time, 0.0)])
    height = body.stand_height + (stand - body.stand_height) * lifted
    during = (t >= leaps[0].start) & (t < hopped)
    height[during] = leap_heights(leaps, t[during])
    program = idle(body, state, frames, rng)
    shift = SIGN[stance] * 0.06 * body.scale * left
    program.pelvis = (
        state.centre
        + heading * leap_travel(leaps, distances, t)[:, None]
        + lifted[:, None] * shift
        + UP * height[:, None]
    )
    program.ankles[:, stance], program.foot_pitch[:, stance] = leap_foot(
        body, leaps, t, state.ankles[stance], heading, distances, float(state.foot_yaw[stance]), 0.0
    )
    end = replace(state, ankles=state.ankles + heading * sum(distances))

    hip = SIGN[free] * body.lengths[HIP[free]]
    tucked = program.pelvis + to_world(state.yaw, np.array([hip, -0.6 * body.leg, -0.25 * body.leg]))
    floor = np.where(t[:, None] < 0.5 * (lift_time + hopped), state.ankles[free], end.ankles[free])
    program.ankles[:, free] = floor + (tucked - floor) * lifted[:, None]
    program.ankles[:, free, 1] += 0.05 * np.sin(np.pi * lifted)
    program.foot_pitch[:, free] += 0.5 * lifted
    program.tilt[:, 1] += SIGN[stance] * 0.05 * lifted
    program.trunk[:, 0] += 0.08 * lifted
    for side in (LEFT, RIGHT):
        program.wrists[:, side], program.elbows[:, side] = arm_pose(
            body, side, 0.06 + 0.3 * lifted, 0.12 + 0.45 * lifted, 0.3 + 0.5 * lifted
        )
    return program, end


def hop_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    side, n = p["side"], p["count"]
    other = "right" if side == "left" else "left"
    where = (
        "forward/ADV" if p["direction"] == "forward" else choose(rng, ("in/ADP place/NOUN", "on/ADP the/DET spot/NOUN"))
    )
    times = times_phrase(n, rng)
    return [
        f"@hop {where} on/ADP {{their}} {side}/ADJ leg/NOUN {times}",
        f"@hop on/ADP {{their}} {side}/ADJ foot/NOUN {where} {times}",
        f"@hop {times} on/ADP the/DET {side}/ADJ leg/NOUN {where}",
        f"@stand on/ADP {{their}} {side}/ADJ leg/NOUN and/CCONJ @hop {where} {times}",
        f"@lift {{their}} {other}/ADJ foot/NOUN and/CCONJ @hop {where} on/ADP the/DET {side}/ADJ one/NOUN {times}",
        f"@do {number_word(n)} hops/NOUN {where} on/ADP {{their}} {side}/ADJ leg/NOUN",
    ]


HOP_FAMILY = ActionFamily(
    "hop",
    motion=hop,
    phrases=hop_phrases,
    draw=lambda r: {
        "side": draw_choice(r, SIDES),
        "count": draw_count(r, 2, 5),
        "direction": draw_choice(r, ("in_place", "forward")),
    },
)


ACTION_FAMILIES = (JUMP_FAMILY, HOP_FAMILY)
