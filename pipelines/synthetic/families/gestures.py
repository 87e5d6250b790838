"""The arm gestures: wave, raise arms, clap, punch."""

from __future__ import annotations

import numpy as np

from pipelines.synthetic.body import (
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
from pipelines.synthetic.maths import ease, keyframes
from pipelines.synthetic.program import Program, idle
from pipelines.synthetic.words import choose, number_word, times_phrase


def _blend_arm(program: Program, side: int, wrist: np.ndarray, pole: np.ndarray, weight: np.ndarray) -> None:
    """Move one arm from its current curve toward (wrist, pole) curves by ``weight`` (T,)."""
    w = weight[:, None]
    program.wrists[:, side] += (wrist - program.wrists[:, side]) * w
    program.elbows[:, side] += (pole - program.elbows[:, side]) * w


def _arm_sides(side: str) -> tuple[int, ...]:
    return (LEFT, RIGHT) if side == "both" else (SIDES.index(side),)


_RAISE = {"up": (2.95, 0.1), "forward": (1.57, 0.05), "sideways": (0.0, 1.57)}  # flex, abduction


def wave(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Raise the ``side`` hand(s) beside the head and wave ``count`` times (side to side)."""
    rate = rng.uniform(1.8, 2.5) * body.tempo
    up = rng.uniform(0.45, 0.6) * FPS
    waving = p["count"] / rate * FPS
    frames = int(np.ceil(2 * up + waving + 0.2 * FPS))
    program = idle(body, state, frames, rng)
    t = np.arange(frames, dtype=np.float64)
    raised = keyframes(frames, [(0, 0.0), (up, 1.0), (up + waving, 1.0), (2 * up + waving, 0.0)])
    sway = 0.1 * body.energy * body.arm / 0.53 * np.sin(2 * np.pi * p["count"] * np.clip((t - up) / waving, 0.0, 1.0))
    for side in _arm_sides(p["side"]):
        s = SIGN[side]
        hand = np.array([s * 0.24, 0.13, 0.12]) * body.arm / 0.53
        wrist = hand + np.stack([s * sway, -0.2 * np.abs(sway), np.zeros(frames)], axis=-1)
        _blend_arm(program, side, wrist, np.array([0.4 * s, -1.0, 0.0]), raised)
    if p["side"] != "both":
        program.neck[:, 1] += 0.12 * SIGN[SIDES.index(p["side"])] * raised  # a glance at the hand
    return program, state


def wave_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    times = times_phrase(p["count"], rng)
    if p["side"] == "both":
        return [
            f"@wave both/DET hands/NOUN {times}",
            f"@wave with/ADP both/DET hands/NOUN {times}",
            f"@raise both/DET hands/NOUN and/CCONJ @wave {times}",
            f"@wave both/DET arms/NOUN above/ADP {{their}} head/NOUN {times}",
        ]
    side = p["side"]
    hand = f"{{their}} {side}/ADJ hand/NOUN"
    return [
        f"@wave {hand} {times}",
        f"@wave with/ADP {hand} {times}",
        f"@wave {times} with/ADP the/DET {side}/ADJ hand/NOUN",
        f"@raise {hand} and/CCONJ @wave {times}",
        f"@wave {hand} back/ADV and/CCONJ forth/ADV {times}",
    ]


WAVE_FAMILY = ActionFamily(
    "wave",
    motion=wave,
    phrases=wave_phrases,
    draw=lambda r: {"side": draw_choice(r, ("left", "right", "both"), (2, 2, 1)), "count": draw_count(r, 2, 5)},
)


def raise_arms(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Raise one or both arms ``up`` overhead, ``forward`` or ``sideways`` to shoulder height,
    hold, and lower them again."""
    rise = rng.uniform(0.6, 0.9) * FPS
    hold = rng.uniform(0.5, 1.2) * FPS
    frames = int(np.ceil(2 * rise + hold + 0.2 * FPS))
    program = idle(body, state, frames, rng)
    raised = keyframes(frames, [(0, 0.0), (rise, 1.0), (rise + hold, 1.0), (2 * rise + hold, 0.0)])
    flex, abduct = _RAISE[p["direction"]]
    if p["direction"] == "up" and rng.random() < 0.4:
        flex, abduct = 0.15, 2.9  # overhead by way of the sides
    for side in _arm_sides(p["side"]):
        program.wrists[:, side], program.elbows[:, side] = arm_pose(
            body,
            side,
            0.06 + (flex - 0.06) * raised,
            0.12 + (abduct - 0.12) * raised,
            0.3 - 0.15 * raised,
        )
    program.trunk[:, 0] -= 0.04 * raised * (p["direction"] == "up")
    return program, state


def raise_arms_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    both = p["side"] == "both"
    arms = choose(rng, ("both/DET arms/NOUN", "{their} arms/NOUN")) if both else f"{{their}} {p['side']}/ADJ arm/NOUN"
    it = "them/PRON" if both else "it/PRON"
    if p["direction"] == "up":
        return [
            f"@raise {arms} above/ADP {{their}} head/NOUN",
            f"@raise {arms} straight/ADV up/ADV",
            f"@lift {arms} over/ADP {{their}} head/NOUN",
            f"@raise {arms} above/ADP {{their}} head/NOUN and/CCONJ @lower {it}",
            f"@put {arms} up/ADP in/ADP the/DET air/NOUN",
        ]
    if p["direction"] == "forward":
        return [
            f"@raise {arms} in/ADP front/NOUN of/ADP {{them}}",
            f"@stretch {arms} out/ADP in/ADP front/NOUN of/ADP {{them}}",
            f"@lift {arms} forward/ADV to/ADP shoulder/NOUN height/NOUN",
            f"@raise {arms} forward/ADV and/CCONJ then/ADV @lower {it}",
        ]
    sides = "the/DET sides/NOUN" if both else "the/DET side/NOUN"
    return [
        f"@raise {arms} out/ADP to/ADP {sides}",
        f"@stretch {arms} out/ADP sideways/ADV",
        f"@lift {arms} sideways/ADV to/ADP shoulder/NOUN height/NOUN",
        f"@hold {arms} out/ADP to/ADP {sides} and/CCONJ then/ADV @lower {it}",
    ]


RAISE_ARMS_FAMILY = ActionFamily(
    "raise_arms",
    motion=raise_arms,
    phrases=raise_arms_phrases,
    draw=lambda r: {
        "side": draw_choice(r, ("left", "right", "both")),
        "direction": draw_choice(r, ("up", "forward", "sideways")),
    },
)


def clap(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Bring the hands up in front of the chest and clap ``count`` times."""
    rate = rng.uniform(1.8, 2.6) * body.tempo
    up = rng.uniform(0.4, 0.55) * FPS
    clapping = p["count"] / rate * FPS
    frames = int(np.ceil(2 * up + clapping + 0.2 * FPS))
    program = idle(body, state, frames, rng)
    t = np.arange(frames, dtype=np.float64)
    raised = keyframes(frames, [(0, 0.0), (up, 1.0), (up + clapping, 1.0), (2 * up + clapping, 0.0)])
    apart, together = 0.34 * body.energy, 0.07
    phase = 2 * np.pi * p["count"] * np.clip((t - up) / clapping, 0.0, 1.0)
    gap = together + (apart - together) * (0.5 + 0.5 * np.cos(phase))
    reach = 0.62 * body.arm
    for side in (LEFT, RIGHT):
        s = SIGN[side]
        inward = body.shoulder_half_width - 0.5 * gap  # hands meet on the midline
        ahead = np.sqrt(np.maximum(reach**2 - inward**2 - 0.2**2, 0.01))
        wrist = np.stack([-s * inward, np.full(frames, -0.2), ahead], axis=-1)
        _blend_arm(program, side, wrist, np.array([0.7 * s, -1.0, -0.2]), raised)
    return program, state


def clap_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    times = times_phrase(p["count"], rng)
    return [
        f"@clap {times}",
        f"@clap {{their}} hands/NOUN {times}",
        f"@clap {number_word(p['count'])} times/NOUN",
        f"@clap {{their}} hands/NOUN together/ADV {times}",
        f"@bring {{their}} hands/NOUN together/ADV and/CCONJ @clap {times}",
    ]


CLAP_FAMILY = ActionFamily("clap", motion=clap, phrases=clap_phrases, draw=lambda r: {"count": draw_count(r, 2, 7)})


def punch(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Raise both fists to a guard and punch straight ahead ``count`` times with the ``side``
    arm, the chest turning into each punch."""
    hitter = SIDES.index(p["side"])
    guard_time = rng.uniform(0.4, 0.55) * FPS
    each = rng.uniform(0.42, 0.55) / body.tempo * FPS
    frames = int(np.ceil(2 * guard_time + p["count"] * each + 0.2 * FPS))
    program = idle(body, state, frames, rng)
    t = np.arange(frames, dtype=np.float64)
    end = guard_time + p["count"] * each
    guard = keyframes(frames, [(0, 0.0), (guard_time, 1.0), (end, 1.0), (end + guard_time, 0.0)])
    into = np.clip((t - guard_time) / each, 0.0, p["count"])
    cycle = into - np.floor(into)
    extended = np.where(
        into >= p["count"], 0.0, np.where(cycle < 0.3, ease(cycle / 0.3), 1.0 - ease((cycle - 0.42) / 0.5))
    )
    scale = body.arm / 0.53
    for side in (LEFT, RIGHT):
        s = SIGN[side]
        fist = np.array([-0.06 * s, 0.04, 0.2]) * scale
        target = np.repeat(fist[None], frames, axis=0)
        if side == hitter:
            strike = np.array([-0.16 * s, 0.0, 0.5]) * scale
            target = fist + (strike - fist) * extended[:, None]
        _blend_arm(program, side, target, np.array([0.35 * s, -1.0, -0.1]), guard)
    program.trunk[:, 2] -= 0.3 * SIGN[hitter] * extended  # the punching shoulder comes forward
    program.trunk[:, 0] += 0.08 * guard
    program.neck[:, 1] += 0.2 * SIGN[hitter] * extended  # the eyes stay on the target
    program.pelvis[:, 1] -= 0.03 * body.scale * guard
    return program, state


def punch_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    side, n = p["side"], p["count"]
    times = times_phrase(n, rng, optional_once=True)
    phrases = [
        f"@punch forward/ADV with/ADP {{their}} {side}/ADJ hand/NOUN {times}",
        f"@punch with/ADP {{their}} {side}/ADJ fist/NOUN {times}",
        f"@punch the/DET air/NOUN with/ADP {{their}} {side}/ADJ fist/NOUN {times}",
        f"@raise {{their}} fists/NOUN and/CCONJ @punch with/ADP the/DET {side}/ADJ hand/NOUN {times}",
    ]
    phrases.append(
        f"@throw {number_word(n)} punches/NOUN with/ADP {{their}} {side}/ADJ arm/NOUN"
        if n > 1
        else f"@throw a/DET {side}/ADJ punch/NOUN"
    )
    return phrases


PUNCH_FAMILY = ActionFamily(
    "punch",
    motion=punch,
    phrases=punch_phrases,
    draw=lambda r: {"side": draw_choice(r, SIDES), "count": draw_count(r, 1, 4)},
)


ACTION_FAMILIES = (WAVE_FAMILY, RAISE_ARMS_FAMILY, CLAP_FAMILY, PUNCH_FAMILY)
