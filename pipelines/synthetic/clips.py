"""One clip of the corpus, a function of (seed, index): its plan of actions that can follow each
other, the actions chained on a random body with idles and blended boundaries, the texture,
its joints and captions."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from pipelines.synthetic.body import Body, initial_state, sample_body
from pipelines.synthetic.captions import action_text, make_captions
from pipelines.synthetic.families import ACTIONS, FAMILIES
from pipelines.synthetic.program import (
    Program,
    Texture,
    blend_boundaries,
    idle,
    program_joints,
)
from pipelines.synthetic.words import Token, caption_text

# Real capture's high-frequency content, calibrated against HumanML3D (bench/calibrate_corpus.py).
TEXTURE = Texture(pelvis=0.00169, wrists=0.00324)


MIN_FRAMES, MAX_FRAMES = 40, 199  # HumanML3D keeps 40 ≤ T < 200


def check_families(families: Iterable[str] | None) -> tuple[str, ...]:
    """The families to draw from, in canonical order; unknown names are an error."""
    if families is None:
        return FAMILIES
    families = (families,) if isinstance(families, str) else tuple(families)
    unknown = sorted(set(families) - set(FAMILIES))
    if unknown or not families:
        raise ValueError(f"unknown action families {unknown or '(none given)'}; valid: {', '.join(FAMILIES)}")
    return tuple(f for f in FAMILIES if f in families)


def sample_plan(
    rng: np.random.Generator,
    families: Sequence[str],
    max_actions: int = 3,
) -> list[tuple[str, dict]]:
    """1–``max_actions`` actions that can follow each other: nothing but "stand up" after
    "sit down", "stand up" only from a seat, and no family twice in a row."""
    count = int(rng.choice(3, p=(0.4, 0.35, 0.25))) + 1
    plan: list[tuple[str, dict]] = []
    seated = False
    for i in range(min(count, max_actions)):
        if i == 0:
            options = list(families)
        else:
            options = [f for f in families if ACTIONS[f].seated_before == seated and f != plan[-1][0]]
        if not options:
            break
        name = options[int(rng.integers(len(options)))]
        plan.append((name, ACTIONS[name].draw(rng)))
        seated = ACTIONS[name].seated_after
    return plan


@dataclass(frozen=True)
class Clip:
    """One generated clip: its joints and everything written about it."""

    id: str
    joints: np.ndarray
    plan: list[tuple[str, dict]]
    segments: tuple[tuple[int, int], ...]
    captions: list[list[Token]]
    body_scale: float

    def annotation(self) -> dict:
        return {
            "id": self.id,
            "frames": len(self.joints),
            "body_scale": round(self.body_scale, 4),
            "actions": [
                {"family": name, "params": params, "start": start, "end": end, "text": action_text(name, params)}
                for (name, params), (start, end) in zip(self.plan, self.segments)
            ],
            "captions": [caption_text(c) for c in self.captions],
        }


def make_clip(
    index: int, seed: int = 0, families: Sequence[str] = FAMILIES, max_actions: int = 3, texture: Texture = TEXTURE
) -> Clip:
    """Clip number ``index`` of the corpus with ``seed``: a function of (seed, index) only.
    A plan whose motion would exceed 199 frames loses its last action (a lone action that is
    too long is drawn again), so long families keep their share of first actions. The texture
    is drawn from its own stream, so plans, captions and bodies do not depend on it."""
    rng = np.random.default_rng([seed, index])
    plan = sample_plan(rng, families, max_actions)
    for _ in range(40):
        composition = compose(plan, rng, MIN_FRAMES)
        if len(composition.program) <= MAX_FRAMES:
            break
        plan = plan[:-1] if len(plan) > 1 else sample_plan(rng, families, 1)
    else:
        raise RuntimeError(f"clip {index}: no plan of {families} fits in {MAX_FRAMES} frames")
    program = texture.apply(composition.program, np.random.default_rng([seed, index, 2]))
    joints = program_joints(program, composition.body).astype(np.float32)
    return Clip(f"{index:06d}", joints, plan, composition.segments, make_captions(plan, rng), composition.body.scale)


@dataclass(frozen=True)
class Composition:
    """A clip before rendering: its program, the body it is made on and each action's frame
    range ``[start, end)``."""

    program: Program
    body: Body
    segments: tuple[tuple[int, int], ...]


def compose(actions: Sequence[tuple[str, dict]], rng: np.random.Generator, min_frames: int = 40) -> Composition:
    """Chain actions on a random body, with short idles around and sometimes between them, and
    cross-fade the posture at every boundary; each action starts where the previous one ended
    (same feet, heading and posture). Cheap: nothing is rendered yet."""
    body = sample_body(rng)
    state = initial_state(body, rng, seated=ACTIONS[actions[0][0]].seated_before)
    programs = [idle(body, state, int(rng.integers(4, 14)), rng)]
    segments = []
    frame = len(programs[0])
    for i, (name, params) in enumerate(actions):
        program, state = ACTIONS[name].motion(body, state, params, rng)
        segments.append((frame, frame + len(program)))
        programs.append(program)
        frame += len(program)
        if i < len(actions) - 1 and rng.random() < 0.4:
            programs.append(idle(body, state, int(rng.integers(3, 9)), rng))
            frame += len(programs[-1])
    programs.append(idle(body, state, max(int(rng.integers(4, 14)), min_frames - frame), rng))
    boundaries = np.cumsum([len(p) for p in programs])[:-1]
    program = blend_boundaries(Program.concat(programs), boundaries)
    return Composition(program, body, tuple(segments))
