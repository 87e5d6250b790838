"""A generator sampled for a person's request: a new motion from prompts, an edit keeping time
spans or a body part of a motion, or a motion whose body parts each do their own sentence. In
front of the generator's protocol call sit the planning of :mod:`orchestration.generate.prompts`;
behind it the decoded joints are put on one rigid skeleton, so that every file of a generation
shows the same body.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np

from m2d2m.generators.protocol import MotionGenerator, keep_part, keep_spans
from m2d2m.motion.clip import Motion
from m2d2m.progress import progress
from orchestration.errors import UserError
from orchestration.generate.prompts import DEFAULT_MAX_SECONDS, PromptPlanner, action_frames, check_length
from orchestration.registry import models


@contextmanager
def _progress(description: str) -> Iterator[Callable[[float], None]]:
    """A percentage bar on stderr for a generator's ``progress`` callback (the fraction done), plain
    lines when stderr is not a terminal (none for a generation of a few seconds)."""
    with progress(total=100, unit="%", desc=description, leave=False) as bar:
        yield lambda done: bar.update(round(100 * done) - bar.n)


def generate(
    generator: MotionGenerator,
    prompts: str | Sequence[str],
    seconds: float | Sequence[float] | None = None,
    seed: int = 0,
    split: bool = True,
    max_seconds: float | None = DEFAULT_MAX_SECONDS,
    **options: Any,
) -> Motion:
    """One motion doing ``prompts`` in order, with the generator's multi-action preset changed by
    ``options`` (for M2D2M: method, ts, eta, guidance, truncation), on one rigid skeleton
    (:meth:`Motion.on_rigid_skeleton`; the decoded spread of bone lengths is in ``quality``)."""
    prompts = [prompts] if isinstance(prompts, str) else list(prompts)
    seconds = [seconds] if isinstance(seconds, (int, float)) else seconds
    planner = PromptPlanner(generator)
    actions, frames = planner.plan(prompts, seconds, split)
    check_length(frames, generator.fps, max_seconds)
    notices = planner.notices(actions)

    def warn() -> None:
        """Say what the model does not know once sampling has begun: a request refused before
        that stays the one line of its error."""
        while notices:
            print(f"warning: {notices.pop(0)}", file=sys.stderr)

    try:
        settings = generator.options(**options)
        with _progress(f"sampling {len(actions)} action(s), {sum(frames) / generator.fps:.1f} s") as advance:
            motion = generator.generate(
                [actions], [frames], settings, [seed], progress=lambda done: (warn(), advance(done))
            )[0]
        warn()
        return motion.on_rigid_skeleton()
    except ValueError as error:
        raise UserError(str(error)) from error


def edit(
    generator: MotionGenerator,
    motion: Motion,
    keep: Sequence[tuple[float, float]],
    actions: Sequence[str] | None = None,
    seed: int = 0,
    **options: Any,
) -> Motion:
    """Regenerate ``motion`` except the time spans ``keep`` (seconds): keep the start and the end
    to in-between, the start alone to complete a prefix. ``actions`` may replace the texts of the
    motion's actions, one each; every action keeps its frames."""
    actions = list(motion.actions if actions is None else actions)
    if len(actions) != len(motion.actions):
        raise UserError(f"give one text per action of the motion ({len(motion.actions)})")
    starts = [first for first, _ in motion.ranges] + [len(motion.features)]
    frames = [end - start for start, end in zip(starts[:-1], starts[1:])]
    try:
        return generator.generate(
            [actions], [frames], generator.options(**options), [seed], [keep_spans(motion, keep)]
        )[0].on_rigid_skeleton()
    except ValueError as error:
        raise UserError(str(error)) from error


def edit_part(
    generator: MotionGenerator,
    features: np.ndarray,
    prompts: Sequence[str],
    part: str,
    seed: int = 0,
    split: bool = True,
    max_seconds: float | None = DEFAULT_MAX_SECONDS,
    **options: Any,
) -> Motion:
    """Keep body part ``part`` of ``features`` (F, D) on every frame and generate the rest of the
    body doing ``prompts`` (MMM's upper-body editing keeps ``lower``; docs/generation.md). The
    motion is cut to whole steps of the generator; its actions share its length in proportion to
    their typical lengths."""
    if generator.feature_dim != features.shape[-1]:
        raise UserError(f"the motion has {features.shape[-1]}-d features, the model {generator.feature_dim}-d ones")
    step = generator.frame_step
    features = features[: len(features) // step * step]
    if not len(features):
        raise UserError(f"the motion to edit is shorter than the model's step of {step} frames")
    actions, frames = PromptPlanner(generator).plan(prompts, [len(features) / generator.fps], split)
    check_length(frames, generator.fps, max_seconds)
    try:
        keep = keep_part(features, generator.skeleton, part)
        return generator.generate([actions], [frames], generator.options(**options), [seed], [keep])[
            0
        ].on_rigid_skeleton()
    except ValueError as error:
        raise UserError(str(error)) from error


def generate_parts(
    generator: MotionGenerator,
    parts: Mapping[str, str],
    seconds: float | None = None,
    seed: int = 0,
    max_seconds: float | None = DEFAULT_MAX_SECONDS,
    **options: Any,
) -> Motion:
    """One motion in which every body part does its own sentence (``parts``: part → sentence; the
    parts of :mod:`m2d2m.motion.representation.body_parts`), ``seconds`` long or the corpus's median action, for
    a model with body-part control (MotionDiffuse's eq. 10; docs/generation.md)."""
    if not generator.part_control:
        able = [name for name, entry in models().items() if entry.load("generator").part_control]
        raise UserError(f"{generator.model} has no body-part control; use --model {' or '.join(able)}")
    if seconds is None:
        frames = generator.typical_frames(None)
    else:
        frames = action_frames(generator, seconds, "the body parts' motion")
    check_length([frames], generator.fps, max_seconds)
    try:
        settings = generator.options(**options)
        with _progress(f"sampling {len(parts)} body parts, {frames / generator.fps:.1f} s") as advance:
            motion = generator.generate_parts([dict(parts)], [frames], settings, [seed], progress=advance)[0]
        return motion.on_rigid_skeleton()
    except ValueError as error:
        raise UserError(str(error)) from error
