"""The locomotion families: walk, walk backwards, walk in a circle, jog, run, sidestep, turn."""

from __future__ import annotations

import numpy as np

from pipelines.synthetic.body import FPS, LEFT, RIGHT, SIDES, SIGN, Body, State
from pipelines.synthetic.family import ActionFamily, draw_choice, draw_count
from pipelines.synthetic.maths import keyframes, leftward
from pipelines.synthetic.program import Program
from pipelines.synthetic.stepping import (
    BACKWARD,
    JOG,
    RUN,
    SHUFFLE,
    WALK,
    Step,
    circle,
    path_steps,
    ramp_lengths,
    stepping,
    straight,
)
from pipelines.synthetic.words import choose, number_word, times_phrase

_WALK_SPEEDS = {"slow": (0.40, 1.55), "normal": (0.52, 1.8), "fast": (0.62, 2.05)}  # step m, steps/s


_JOG_SPEEDS = {"slow": (0.75, 2.4), "normal": (0.9, 2.6)}


_RUN_SPEEDS = {"normal": (1.0, 3.0), "fast": (1.15, 3.2)}


def _stride(body: Body, table: dict, speed: str, rng: np.random.Generator) -> tuple[float, float]:
    """Step length (scaled by leg length) and period (s) for a speed word, with a little jitter."""
    length, cadence = table[speed]
    length *= body.leg / 0.826 * rng.uniform(0.95, 1.05)
    return length, 1.0 / (cadence * body.tempo * rng.uniform(0.97, 1.03))


def walk(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """``steps`` footsteps forward at a ``speed`` (slow / normal / fast)."""
    length, period = _stride(body, _WALK_SPEEDS, p["speed"], rng)
    steps = path_steps(body, straight(state, 0.0), [length] * (p["steps"] - 1), period, 0.8, WALK, int(rng.integers(2)))
    return stepping(body, state, steps, WALK, period)


def walk_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    speed = choose(
        rng,
        {
            "slow": ("slowly/ADV", "at/ADP a/DET slow/ADJ pace/NOUN"),
            "normal": ("", "", "at/ADP a/DET normal/ADJ pace/NOUN", "at/ADP a/DET steady/ADJ pace/NOUN"),
            "fast": ("quickly/ADV", "briskly/ADV", "fast/ADV", "at/ADP a/DET fast/ADJ pace/NOUN"),
        }[p["speed"]],
    )
    n = number_word(p["steps"])
    phrases = [
        f"@walk forward/ADV {speed}",
        f"@take {n} steps/NOUN forward/ADV {speed}",
        f"@walk {n} steps/NOUN forward/ADV {speed}",
        f"@walk straight/ADV ahead/ADV {speed}",
        f"@walk forward/ADV {speed} and/CCONJ @stop",
    ]
    if p["speed"] == "slow":
        phrases.append("@stroll slowly/ADV forward/ADV")
    if p["speed"] == "fast":
        phrases.append(f"@hurry forward/ADV {n} steps/NOUN")
    return phrases


WALK_FAMILY = ActionFamily(
    "walk",
    motion=walk,
    phrases=walk_phrases,
    draw=lambda r: {"steps": draw_count(r, 3, 10), "speed": draw_choice(r, ("slow", "normal", "fast"))},
)


def walk_backwards(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """``steps`` flat-footed steps backwards, still facing forward."""
    length, period = _stride(body, {"slow": (0.28, 1.4), "normal": (0.36, 1.65)}, p["speed"], rng)
    steps = path_steps(
        body,
        straight(state, np.pi),
        [length] * (p["steps"] - 1),
        period,
        0.7,
        BACKWARD,
        int(rng.integers(2)),
        facing=-np.pi,
    )
    return stepping(body, state, steps, BACKWARD, period)


def walk_backwards_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    speed = "slowly/ADV" if p["speed"] == "slow" else ""
    back = choose(rng, ("backwards/ADV", "backward/ADV"))
    n = number_word(p["steps"])
    return [
        f"@walk {back} {speed}",
        f"@take {n} steps/NOUN {back} {speed}",
        f"@walk {back} {n} steps/NOUN {speed}",
        f"@back up/ADP {speed}",
        f"@move {back} {speed}",
    ]


WALK_BACKWARDS_FAMILY = ActionFamily(
    "walk_backwards",
    motion=walk_backwards,
    phrases=walk_backwards_phrases,
    draw=lambda r: {"steps": draw_count(r, 3, 7), "speed": draw_choice(r, ("slow", "normal"))},
)


def walk_circle(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """One full circle of ``radius`` m, ``clockwise`` or counterclockwise seen from above."""
    turn = -1.0 if p["direction"] == "clockwise" else 1.0
    length, period = _stride(body, {"normal": (0.46, 1.8)}, "normal", rng)
    count = max(int(round(2 * np.pi * p["radius"] / length)), 6)
    length = 2 * np.pi * p["radius"] / count
    steps = path_steps(body, circle(state, p["radius"], turn), [length] * count, period, 0.8, WALK, int(turn < 0))
    return stepping(body, state, steps, WALK, period)


def walk_circle_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    clockwise = p["direction"] == "clockwise"
    way = "clockwise" if clockwise else choose(rng, ("counterclockwise", "anticlockwise"))
    side = "right" if clockwise else "left"
    return [
        f"@walk in/ADP a/DET circle/NOUN {way}/ADV",
        f"@walk {way}/ADV in/ADP a/DET circle/NOUN",
        f"@walk in/ADP {'an' if way[0] == 'a' else 'a'}/DET {way}/ADJ circle/NOUN",
        f"@walk around/ADV in/ADP a/DET circle/NOUN to/ADP the/DET {side}/NOUN",
        f"@walk in/ADP a/DET full/ADJ circle/NOUN {way}/ADV",
        f"@walk around/ADV in/ADP a/DET circle/NOUN {way}/ADV",
    ]


WALK_CIRCLE_FAMILY = ActionFamily(
    "walk_circle",
    motion=walk_circle,
    phrases=walk_circle_phrases,
    draw=lambda r: {
        "direction": draw_choice(r, ("clockwise", "counterclockwise")),
        "radius": round(float(r.uniform(0.6, 0.95)), 2),
    },
)


def jog(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Jogging forward for ``steps`` footsteps, speeding up and slowing down."""
    length, period = _stride(body, _JOG_SPEEDS, p["speed"], rng)
    advances = ramp_lengths(p["steps"] - 1, length, (0.45, 0.75, 0.92))
    steps = path_steps(body, straight(state, 0.0), advances, period, 1.25, JOG, int(rng.integers(2)))
    return stepping(body, state, steps, JOG, period)


def jog_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    speed = (
        choose(rng, ("slowly/ADV", "lightly/ADV", "at/ADP an/DET easy/ADJ pace/NOUN")) if p["speed"] == "slow" else ""
    )
    return [
        f"@jog forward/ADV {speed}",
        f"@jog straight/ADV ahead/ADV {speed}",
        f"@jog forward/ADV {speed} and/CCONJ @stop",
        f"@jog a/DET short/ADJ distance/NOUN forward/ADV {speed}",
    ]


JOG_FAMILY = ActionFamily(
    "jog",
    motion=jog,
    phrases=jog_phrases,
    draw=lambda r: {"steps": draw_count(r, 6, 13), "speed": draw_choice(r, ("slow", "normal"))},
)


def run(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Running forward for ``steps`` footsteps, speeding up and slowing down."""
    length, period = _stride(body, _RUN_SPEEDS, p["speed"], rng)
    advances = ramp_lengths(p["steps"] - 1, length, (0.4, 0.65, 0.85, 0.95))
    steps = path_steps(body, straight(state, 0.0), advances, period, 1.4, RUN, int(rng.integers(2)))
    return stepping(body, state, steps, RUN, period)


def run_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    speed = choose(rng, ("quickly/ADV", "fast/ADV", "at/ADP full/ADJ speed/NOUN")) if p["speed"] == "fast" else ""
    phrases = [
        f"@run forward/ADV {speed}",
        f"@run straight/ADV ahead/ADV {speed}",
        f"@run forward/ADV {speed} and/CCONJ @stop",
        f"@run a/DET short/ADJ distance/NOUN forward/ADV {speed}",
    ]
    if p["speed"] == "fast":
        phrases.append("@sprint forward/ADV")
    return phrases


RUN_FAMILY = ActionFamily(
    "run",
    motion=run,
    phrases=run_phrases,
    draw=lambda r: {"steps": draw_count(r, 6, 15), "speed": draw_choice(r, ("normal", "fast"))},
)


def sidestep(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """``count`` step-together sidesteps toward ``side``: the leading foot opens, the other closes."""
    lead = SIDES.index(p["side"])
    width = rng.uniform(0.26, 0.36) * body.scale
    period = rng.uniform(0.42, 0.5) / body.tempo
    towards = SIGN[lead] * leftward(state.yaw)
    steps = []
    for k in range(p["count"]):
        for j, side in enumerate((lead, 1 - lead)):
            lift = (0.2 + (2 * k + j) * period) * FPS
            ankle = state.ankles[side] + towards * width * (k + 1)
            steps.append(Step(side, lift, lift + 0.65 * period * FPS, ankle, float(state.foot_yaw[side])))
    return stepping(body, state, steps, SHUFFLE, 2 * period, end_yaw=state.yaw)


def sidestep_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    side, n = p["side"], p["count"]
    return [
        f"@sidestep to/ADP the/DET {side}/NOUN {times_phrase(n, rng)}",
        f"@take {number_word(n)} side/NOUN steps/NOUN to/ADP the/DET {side}/NOUN",
        f"@take {number_word(n)} steps/NOUN sideways/ADV to/ADP the/DET {side}/NOUN",
        f"@step sideways/ADV to/ADP {{their}} {side}/NOUN {times_phrase(n, rng)}",
        f"@shuffle {number_word(n)} steps/NOUN to/ADP the/DET {side}/NOUN",
    ]


SIDESTEP_FAMILY = ActionFamily(
    "sidestep",
    motion=sidestep,
    phrases=sidestep_phrases,
    draw=lambda r: {"side": draw_choice(r, SIDES), "count": draw_count(r, 2, 4)},
)


def turn(body: Body, state: State, p: dict, rng: np.random.Generator) -> tuple[Program, State]:
    """Turning on the spot by ``angle`` degrees toward ``side`` in small pivoting steps, the foot on
    the turning side first; the head leads the turn."""
    sign = 1.0 if p["side"] == "left" else -1.0
    total = sign * np.radians(p["angle"])
    count = max(2, int(np.ceil(abs(p["angle"]) / 50.0)))
    period = rng.uniform(0.42, 0.52) / body.tempo
    centre = state.centre
    lead = LEFT if sign > 0 else RIGHT
    steps = []
    for i in range(count + 1):
        side = lead if i % 2 == 0 else 1 - lead
        heading = state.yaw + total * min(i + 1, count) / count
        ankle = centre + SIGN[side] * 0.5 * body.step_width * leftward(heading)
        ankle[1] = body.ankle_height
        lift = (0.2 + i * period) * FPS
        steps.append(Step(side, lift, lift + 0.7 * period * FPS, ankle, heading + SIGN[side] * body.toe_out))
    program, end = stepping(body, state, steps, SHUFFLE, 2 * period, end_yaw=state.yaw + total)
    look = keyframes(len(program), [(0, 0.0), (steps[0].lift, 0.35 * sign), (steps[-1].land, 0.0)])
    program.neck[:, 1] += look
    return program, end


def turn_phrases(p: dict, rng: np.random.Generator) -> list[str]:
    side = p["side"]
    if p["angle"] == 45:
        return [
            f"@turn slightly/ADV to/ADP the/DET {side}/NOUN",
            f"@turn slightly/ADV {side}/ADV",
            f"@turn forty/NUM five/NUM degrees/NOUN to/ADP the/DET {side}/NOUN",
        ]
    if p["angle"] == 90:
        return [
            f"@turn {side}/ADV",
            f"@turn to/ADP the/DET {side}/NOUN",
            f"@turn ninety/NUM degrees/NOUN to/ADP the/DET {side}/NOUN",
            f"@turn to/ADP {{their}} {side}/NOUN",
            f"@make a/DET quarter/NOUN turn/NOUN to/ADP the/DET {side}/NOUN",
        ]
    way = "counterclockwise" if side == "left" else "clockwise"
    return [
        f"@turn around/ADV to/ADP the/DET {side}/NOUN",
        f"@turn around/ADV over/ADP {{their}} {side}/ADJ shoulder/NOUN",
        f"@turn one/NUM hundred/NUM and/CCONJ eighty/NUM degrees/NOUN to/ADP the/DET {side}/NOUN",
        f"@make a/DET half/ADJ turn/NOUN to/ADP the/DET {side}/NOUN",
        f"@turn around/ADV {way}/ADV",
    ]


TURN_FAMILY = ActionFamily(
    "turn",
    motion=turn,
    phrases=turn_phrases,
    draw=lambda r: {"side": draw_choice(r, SIDES), "angle": draw_choice(r, (45, 90, 180), (1, 3, 2))},
)


ACTION_FAMILIES = (
    WALK_FAMILY,
    WALK_BACKWARDS_FAMILY,
    WALK_CIRCLE_FAMILY,
    JOG_FAMILY,
    RUN_FAMILY,
    SIDESTEP_FAMILY,
    TURN_FAMILY,
)
