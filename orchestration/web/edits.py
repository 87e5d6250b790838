"""``POST /api/generations/{id}/edit``: an edit of a generation this server made, planned as `m2d2m
generate --edit` plans one (orchestration/editing.py), so the API and the command line accept and
refuse the same edits (docs/generation.md, "Editing a result")."""

from __future__ import annotations

from m2d2m.generators.edits import Edit, Timeline
from m2d2m.generators.protocol import MotionGenerator
from orchestration.editing import edit_options, plan_edit, pose_at, timeline_of
from orchestration.errors import UserError
from orchestration.web.generations import Generation, Generations
from orchestration.web.schema import EditRequest, Plan, delivery_of, within_cap

# the fields each operation takes; any other one set is refused, not ignored
FIELDS = {
    "regenerate": {"action", "text", "seconds"},
    "fill": {"then", "text", "seconds"},
    "pin": {"pose", "at"},
    "continue": {"actions"},
    "layer": {"part", "text", "span"},
}
OPERATION_FIELDS = set().union(*FIELDS.values())


def model_frame(generation: Generation, frame: int, generator: MotionGenerator) -> int:
    """Frame ``frame`` of a generation as it was delivered (at its ``fps``, the index of its
    answer's joints) as a frame of its features, at the model's rate: the same instant."""
    motion = generation.motion
    if not 0 <= frame < len(motion.joints):
        raise UserError(
            f"generation {generation.id} has frames 0 to {len(motion.joints) - 1} at its {motion.fps:g} fps, not {frame}"
        )
    return min(round(frame * generator.fps / motion.fps), len(motion.features) - 1)


def plan_edit_request(
    request: EditRequest,
    parent: Generation,
    generations: Generations,
    generator: MotionGenerator,
    max_seconds: float | None,
) -> tuple[Edit, str, Plan]:
    """The edit ``request`` asks of ``parent`` (by ``generator``, the model and run that made it),
    what it does in a line, and its plan: a UserError in one sentence for one it cannot be, with
    the limits of ``POST /api/generate`` (``max_seconds``: the server's cap on the edited clip)."""
    given = {name for name in OPERATION_FIELDS if getattr(request, name) is not None}
    stray = sorted(given - FIELDS[request.operation])
    if stray:
        raise UserError(f"{', '.join(stray)} does not go with the operation {request.operation}")
    if request.operation == "regenerate" and request.action is None:
        raise UserError("regenerate names the action to sample again (action, counted from 1)")
    if request.operation == "fill" and request.then is None:
        raise UserError("fill names the generation that follows the gap (then)")
    if request.operation == "pin" and request.pose is None:
        raise UserError("pin names the pose (pose: a generation and its frame)")
    layer = None
    if request.operation == "layer":
        if request.part is None or request.text is None or request.span is None:
            raise UserError("layer names the body part, its text and its span (part, text, span)")
        layer = (request.part, request.text)

    def timeline(generation: Generation) -> Timeline:
        return timeline_of(generation.motion, generator, f"generation {generation.id}")

    if layer is not None:  # its text is the layer's, not an action's
        texts = []
    elif request.text is not None:
        texts = [request.text]
    else:
        texts = [action.text for action in request.actions or ()]
    if request.actions is not None:
        seconds = [action.seconds for action in request.actions]  # None: the model's typical length
    else:
        seconds = [] if request.seconds is None else [request.seconds]
    pose = None
    if request.pose is not None:
        source = generations.get(request.pose.generation)
        frame = model_frame(source, request.pose.frame, generator)
        pose = pose_at(timeline(source), frame, f"generation {source.id}")
    edit, said = plan_edit(
        generator,
        timeline(parent),
        texts,
        seconds,
        regenerate=request.action,
        fill_to=None if request.then is None else timeline(generations.get(request.then)),
        pose=pose,
        at=request.at,
        extend=request.operation == "continue",
        layer=layer,
        span=None if request.span is None else (request.span[0], request.span[1]),
    )
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
