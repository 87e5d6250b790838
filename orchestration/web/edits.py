"""``POST /api/generations/{id}/edit``: an edit of a generation this server made, the operation its
body names (orchestration/web/schema.py) planned by that operation's own planner, as `m2d2m
generate --edit` plans one (orchestration/edit_operations.py), so the API and the command line
accept and refuse the same edits (docs/generation.md, "Editing a result")."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from m2d2m.generators.edits import Edit, Timeline
from m2d2m.generators.protocol import MotionGenerator
from orchestration.edit_operations import plan_edit
from orchestration.editing import edit_options, pose_at, timeline_of
from orchestration.errors import UserError
from orchestration.web.generations import Generation, Generations
from orchestration.web.schema import EditFields, Plan, PoseReference, delivery_of, within_cap


def model_frame(generation: Generation, frame: int, generator: MotionGenerator) -> int:
    """Frame ``frame`` of a generation as it was delivered (at its ``fps``, the index of its
    answer's joints) as a frame of its features, at the model's rate: the same instant."""
    motion = generation.motion
    if not 0 <= frame < len(motion.joints):
        raise UserError(
            f"generation {generation.id} has frames 0 to {len(motion.joints) - 1} at its {motion.fps:g} fps, not {frame}"
        )
    return min(round(frame * generator.fps / motion.fps), len(motion.features) - 1)


@dataclass(frozen=True)
class GenerationSources:
    """The generations of this server an edit names, read as ``generator`` edits them."""

    generations: Generations
    generator: MotionGenerator

    def timeline(self, generation: str) -> Timeline:
        return self.timeline_of(self.generations.get(generation))

    def timeline_of(self, generation: Generation) -> Timeline:
        return timeline_of(generation.motion, self.generator, f"generation {generation.id}")

    def pose(self, reference: PoseReference) -> np.ndarray:
        source = self.generations.get(reference.generation)
        frame = model_frame(source, reference.frame, self.generator)
        return pose_at(self.timeline_of(source), frame, f"generation {source.id}")


def plan_edit_request(
    request: EditFields,
    parent: Generation,
    generations: Generations,
    generator: MotionGenerator,
    max_seconds: float | None,
) -> tuple[Edit, str, Plan]:
    """The edit ``request`` asks of ``parent`` (by ``generator``, the model and run that made it),
    what it does in a line, and its plan: a UserError in one sentence for one it cannot be, with
    the limits of ``POST /api/generate`` (``max_seconds``: the server's cap on the edited clip)."""
    sources = GenerationSources(generations, generator)
    edit, said = plan_edit(generator, sources.timeline_of(parent), request.edit_operation(sources))
    within_cap(edit.frames, generator, max_seconds)
    try:
        options = generator.options(**edit_options(generator, edit, request.options))
    except ValueError as error:
        raise UserError(str(error)) from error
    return (
        edit,
        f"generation {parent.id}: {said}",
        Plan(edit.actions, edit.frames, options, edit.result_actions, [], delivery_of(request)),
    )
