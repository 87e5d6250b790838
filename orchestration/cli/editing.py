"""`m2d2m generate --edit SOURCE` with a timeline operation (orchestration/edit_operations.py):
the flags of the five operations and the ones that serve them, the one operation they ask for,
checked before a model loads, and the edit sampled.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from orchestration.cli.arguments import body_part, positive_int
from orchestration.cli.results import planned_outputs, report
from orchestration.cli.sampling import sampling_options
from orchestration.errors import UserError

# `generate --edit`'s timeline operations by flag (each its dest), and the flags that serve one of them
_OPERATION_FLAGS = {
    "--regenerate": "regenerate",
    "--fill-to": "fill_to",
    "--pin": "pin",
    "--continue": "extend",
    "--layer": "layer",
}
_SERVING_FLAGS = {"--at": ("at", "--pin"), "--span": ("span", "--layer")}


def _pose_reference(value: str) -> tuple[str, int]:
    """POSE@FRAME: a result's .npy and one of its frames (at the model's rate)."""
    path, at, frame = value.rpartition("@")
    if not at or not path or not frame.isdigit():
        raise argparse.ArgumentTypeError(f"expected POSE@FRAME (a .npy and a frame number), got {value!r}")
    return path, int(frame)


def _span(value: str) -> tuple[float, float]:
    """START:END seconds, START before END."""
    start, colon, end = value.partition(":")
    try:
        span = float(start), float(end)
    except ValueError:
        span = None
    if not colon or span is None or not 0 <= span[0] < span[1]:
        raise argparse.ArgumentTypeError(f"expected START:END in seconds, START before END, got {value!r}")
    return span


def edit_timeline(args: argparse.Namespace) -> None:
    """``generate --edit SOURCE`` with a timeline operation (orchestration/edit_operations.py)."""
    from m2d2m.layout import relative_to_project
    from orchestration.edit_operations import plan_edit
    from orchestration.editing import read_result, sample_edit
    from orchestration.generate.loading import load_generator
    from orchestration.generate.outputs import staged
    from orchestration.generate.prompts import check_length, length_cap

    chosen = chosen_operation(args)
    planned = planned_outputs(args)
    generator = load_generator(args.model, args.checkpoint, args.dataset)
    operation = edit_operation(args, chosen, lambda path: read_result(path, generator))
    edit, said = plan_edit(generator, read_result(args.edit, generator), operation)
    check_length(edit.frames, generator.fps, length_cap(args.max_seconds))  # the cap of a new generation
    print(f"{args.edit}: {said}")
    options = sampling_options(args)
    if args.method is not None:
        options["method"] = args.method
    with staged(planned) as planned:
        for seed, variation in planned:
            motion = sample_edit(generator, edit, seed, f"{relative_to_project(args.edit)}: {said}", **options)
            report(motion, variation, edit.result_actions, args)
            if "pin_error_m" in motion.quality:
                print(f"  the pose is met within {motion.quality['pin_error_m'] * 1000:.0f} mm (its farthest joint)")


def edit_flags(args: argparse.Namespace) -> list[str]:
    """The timeline operations' flags given, in the order of the help."""
    dests = {**_OPERATION_FLAGS, **{flag: dest for flag, (dest, _) in _SERVING_FLAGS.items()}}
    given = {flag: getattr(args, dest) for flag, dest in dests.items()}
    return [flag for flag, value in given.items() if value is not None and value is not False]


def chosen_operation(args: argparse.Namespace) -> str:
    """The flag of the one timeline operation `generate --edit` asks for, checked before a model
    loads: none or two, or a flag that serves another operation, is one line."""
    chosen = [flag for flag in edit_flags(args) if flag in _OPERATION_FLAGS]
    if len(chosen) != 1:
        raise UserError(
            "an edit is one of: regenerate an action, fill to a second result, pin a pose, continue, "
            "lay a body part's action over a span (one at a time)"
        )
    for flag, (dest, owner) in _SERVING_FLAGS.items():
        if getattr(args, dest) is not None and chosen[0] != owner:
            raise UserError(f"{flag} goes with {owner}, not with {chosen[0]}")
    return chosen[0]


def edit_operation(args: argparse.Namespace, chosen: str, read: Callable[[str], Any]) -> Any:
    """The operation of flag ``chosen`` (orchestration/edit_operations.py) from its flags, the
    prompts and ``--seconds`` (``read``: a result's file as a timeline): a text or length it does
    not take is one line."""
    from orchestration.edit_operations import Continue, Fill, Layer, Pin, Regenerate
    from orchestration.editing import pose_at

    texts, seconds = list(args.prompts), list(args.seconds or [])
    text, length, one_each = (texts or [None])[0], (seconds or [None])[0], len(texts) <= 1 and len(seconds) <= 1
    if chosen == "--regenerate":
        if not one_each:
            raise UserError("regenerating takes at most one text (the action's new one) and one length")
        return Regenerate(args.regenerate, text, length)
    if chosen == "--fill-to":
        if not one_each:
            raise UserError("filling takes at most one text (what happens in the gap) and one length (the gap's)")
        return Fill(read(args.fill_to), 1.0 if length is None else length, text or "")
    if chosen == "--pin":
        if args.at is None or texts or seconds:
            raise UserError("pinning a pose takes the time to pin it at (--at; the API's at) and no text or length")
        source, frame = args.pin
        return Pin(pose_at(read(source), frame, f"--pin: {source}"), args.at)
    if chosen == "--layer":
        if args.span is None or texts or seconds:
            raise UserError("laying a body part's action takes the span it lasts (--span; the API's span) alone")
        return Layer(*args.layer, args.span)
    lengths = seconds * len(texts) if len(seconds) == 1 else seconds or [None] * len(texts)
    return Continue(tuple(texts), tuple(lengths))


def add_edit_options(parser: argparse.ArgumentParser) -> None:
    """`generate`'s options that edit a motion: the source, the timeline operations and the flags
    that serve them, and the body part to keep."""
    parser.add_argument(
        "--edit",
        metavar="SOURCE",
        help="edit this motion instead: a .npy of features (the .features.npy generate writes) "
        "or joints; the prompts share its length (with --keep-body)",
    )
    parser.add_argument(
        "--regenerate",
        type=positive_int,
        metavar="K",
        help="with --edit: sample action K again (a prompt: its new text; --seconds: its new length), "
        "the others kept outside a 0.4-s margin",
    )
    parser.add_argument(
        "--fill-to",
        metavar="SECOND",
        help="with --edit: join SOURCE to this second result by --seconds (default 1) of new motion "
        "(a prompt: what happens in it)",
    )
    parser.add_argument(
        "--pin",
        type=_pose_reference,
        metavar="POSE@FRAME",
        help="with --edit and --at: the motion passes through this pose (a result's .npy and its frame)",
    )
    parser.add_argument("--at", type=float, metavar="SECONDS", help="where --pin pins its pose")
    parser.add_argument(
        "--continue",
        dest="extend",
        action="store_true",
        help="with --edit: append the prompts to SOURCE (--seconds each), its end sampled again to lead into them",
    )
    parser.add_argument(
        "--layer",
        type=body_part,
        metavar="PART=TEXT",
        help="with --edit and --span: this body part does TEXT over the span, the rest of the body as it was, "
        'e.g. upper="a person waves" (--model motiondiffuse)',
    )
    parser.add_argument("--span", type=_span, metavar="START:END", help="where --layer lays its action, in seconds")
    parser.add_argument(
        "--keep-body",
        metavar="PART",
        help="the body part (upper, lower) of --edit's motion to keep on every frame; the rest "
        "follows the prompts "
        "(--model mmm-body keeps lower: MMM's upper-body editing; --option lower_mask=0.25)",
    )
