"""The operations that edit a result on its timeline, in seconds (docs/generation.md, "Editing a
result"): each one a type with only its own fields, checked once when it is made, and its own
planner, which sizes it for a model and lays it out as one request of
:mod:`m2d2m.generators.edits`. The command line's flags and the API's bodies both become one of
these, so they accept and refuse the same edits; a new operation is one more type here, with a
flag and an API body to reach it (as diffusers' task pipelines each take only their own arguments).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from m2d2m.generators.edits import (
    Edit,
    Timeline,
    continue_after,
    fill_between,
    hold_pose,
    layer_part,
    margin_frames,
    regenerate_action,
)
from m2d2m.generators.protocol import MotionGenerator
from m2d2m.motion.representation.body_parts import PARTS, part_mask
from orchestration.editing import as_clip
from orchestration.errors import UserError
from orchestration.generate.prompts import action_frames


class EditOperation(ABC):
    """One edit of a result: a frozen dataclass of its own fields, refused in one line when made
    with values no result could take (a check that needs no model), and :meth:`plan`, its planner."""

    @abstractmethod
    def plan(self, generator: MotionGenerator, timeline: Timeline) -> tuple[Edit, str]:
        """The request ``generator`` samples to make this edit of ``timeline``, and a line saying
        what it does; a ValueError or IndexError for one this result cannot take."""


@dataclass(frozen=True)
class Regenerate(EditOperation):
    """Action ``action`` (counted from 1) sampled again, under ``text`` and ``seconds`` when given
    (by default its own), every other action kept; round the loop for a loop."""

    action: int
    text: str | None = None
    seconds: float | None = None

    def __post_init__(self) -> None:
        if self.action < 1:
            raise UserError(f"actions are counted from 1, not {self.action}")

    def plan(self, generator: MotionGenerator, timeline: Timeline) -> tuple[Edit, str]:
        frames = None if self.seconds is None else action_frames(generator, self.seconds, f"action {self.action}")
        edit = regenerate_action(
            timeline, self.action - 1, margin_frames(generator), self.text, frames, generator.frame_step
        )
        return edit, f"action {self.action} of {len(timeline.actions)} sampled again"


@dataclass(frozen=True)
class Fill(EditOperation):
    """``seconds`` of new motion doing ``text`` (empty: whatever joins them, the model's null
    condition) between the result and ``then``, a second one."""

    then: Timeline
    seconds: float = 1.0
    text: str = ""

    def plan(self, generator: MotionGenerator, timeline: Timeline) -> tuple[Edit, str]:
        first, second = as_clip(timeline, generator), as_clip(self.then, generator)
        gap = action_frames(generator, self.seconds, "the gap")
        edit = fill_between(first, second, gap, margin_frames(generator), self.text)
        return edit, f"{self.seconds:g} s filled between two results"


@dataclass(frozen=True)
class Pin(EditOperation):
    """``pose`` (one frame's features) pinned at ``at`` seconds: the model is given it on its step
    grid, and the result meets it at the nearest frame itself."""

    pose: np.ndarray
    at: float

    def plan(self, generator: MotionGenerator, timeline: Timeline) -> tuple[Edit, str]:
        frame = _frame_at(generator, timeline, self.at, "a pose pinned", on_grid=False)
        edit = hold_pose(timeline, self.pose, frame, generator.frame_step, margin_frames(generator))
        return edit, f"a pose pinned at frame {frame}"


@dataclass(frozen=True)
class Continue(EditOperation):
    """``texts`` appended to the result, each ``seconds`` long (None: the model's typical length),
    its end sampled again to lead into them."""

    texts: tuple[str, ...]
    seconds: tuple[float | None, ...]

    def __post_init__(self) -> None:
        if not self.texts:
            raise UserError("continuing takes the new actions' texts (prompts)")
        if len(self.texts) != len(self.seconds):
            raise UserError(
                f"give one length per new action: {len(self.texts)} action(s), {len(self.seconds)} length(s)"
            )

    def plan(self, generator: MotionGenerator, timeline: Timeline) -> tuple[Edit, str]:
        frames = [
            generator.round_frames(generator.typical_frames(None))
            if seconds is None
            else action_frames(generator, seconds, repr(text))
            for text, seconds in zip(self.texts, self.seconds)
        ]
        edit = continue_after(as_clip(timeline, generator), list(self.texts), frames, margin_frames(generator))
        return edit, f"{len(self.texts)} action(s) added"


@dataclass(frozen=True)
class Layer(EditOperation):
    """Body part ``part`` doing ``text`` over ``span`` (start, end seconds), the rest of the body
    as it was: a model that keeps some dimensions alone (MotionDiffuse) can; the token models keep
    whole frames and refuse when sampling."""

    part: str
    text: str
    span: tuple[float, float]

    def __post_init__(self) -> None:
        if self.part not in PARTS:
            raise UserError(f"unknown body part {self.part!r}: choose from {', '.join(PARTS)}")

    def plan(self, generator: MotionGenerator, timeline: Timeline) -> tuple[Edit, str]:
        clip = as_clip(timeline, generator)
        first, end = (_frame_at(generator, clip, seconds, f"the {self.part} body's span") for seconds in self.span)
        mask = part_mask(generator.skeleton, self.part)
        edit = layer_part(clip, (first, end), mask, self.text, margin_frames(generator))
        return edit, f"{self.part} body doing {self.text!r} from {self.span[0]:g} to {self.span[1]:g} s"


def plan_edit(generator: MotionGenerator, timeline: Timeline, operation: EditOperation) -> tuple[Edit, str]:
    """``operation`` planned on ``timeline`` for ``generator`` (its planner), and a line saying
    what it does; what this result cannot take is a UserError in one line."""
    try:
        return operation.plan(generator, timeline)
    except (IndexError, ValueError) as error:
        raise UserError(str(error)) from error


def _frame_at(generator: MotionGenerator, timeline: Timeline, seconds: float, what: str, on_grid: bool = True) -> int:
    """The frame at ``seconds`` of ``timeline``: on the model's step grid (a token's first frame),
    or (not ``on_grid``) the nearest; a time outside the motion is one line (1e308 s is no frame
    at all)."""
    length = len(timeline.features) / generator.fps
    if not 0 <= seconds <= length:
        raise UserError(f"{what} at {seconds:g} s lies outside the motion's {length:g} s")
    frame = min(int(round(seconds * generator.fps)), len(timeline.features) - 1)
    step = 1 if not on_grid else generator.frame_step
    return frame // step * step
