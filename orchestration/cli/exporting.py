"""`m2d2m render`, `export` and `rig`: a motion already made (a result, a recording, a corpus's
clip) drawn as an animation or written in an animator's format, and what a character's rig can take.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from m2d2m.motion.files.formats import animations, exported, on_rig, spoken, suffixes
from orchestration.cli.arguments import add_overwrite, non_negative_int, positive_float
from orchestration.cli.delivery import (
    JOINT_MAP_HELP,
    REST_FRAME_HELP,
    add_delivery,
    delivered,
    delivery_asked,
    delivery_notes,
)
from orchestration.errors import UserError


def _render(args: argparse.Namespace) -> None:
    from m2d2m.motion.files.render import render_motion
    from orchestration.viewing import load_motion

    out = Path(args.out)
    if out.suffix.lower().lstrip(".") not in {fmt.suffix for fmt in animations()}:
        raise UserError(
            f"{out}: the animation format comes from the suffix; use {spoken(f'.{fmt.suffix}' for fmt in animations())}"
        )
    if out.exists() and not args.overwrite:
        raise UserError(f"{out} exists; give another name, or --overwrite to replace it")
    motion = load_motion(args.source, args.id, args.skeleton)
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        render_motion(
            motion.joints,
            out,
            skeleton=motion.skeleton,
            fps=args.fps or motion.fps,
            segments=motion.segments or None,
            title=motion.caption,
        )
    except RuntimeError as error:  # no MP4 encoder on this machine, or the encoder failed
        raise UserError(str(error)) from error
    print(f"wrote {out}")


def _export(args: argparse.Namespace) -> None:
    import numpy as np

    from m2d2m.motion.clip import Motion
    from orchestration.generate.outputs import plan_output, staged
    from orchestration.viewing import load_motion

    out = Path(args.out)
    if out.suffix.lower().lstrip(".") not in {fmt.suffix for fmt in exported()}:
        raise UserError(f"{out}: export writes {suffixes(exported())} (the suffix is the format)")
    output = plan_output(out, "motion", None, delivery_asked(args), args.overwrite)
    shown = load_motion(args.source, args.id, args.skeleton)
    fps, said = _source_rate(args.source_fps, shown)
    print(f"{args.source}: read at {fps:g} fps ({said})")
    # a recording without text has no actions: not one nameless span (Motion.segments would call it a transition)
    segments = shown.segments or ([(0, len(shown.joints), shown.caption)] if shown.caption else [])
    motion = delivered(
        Motion(
            np.zeros((len(shown.joints), 0), np.float32),  # no features: contacts come from the joints
            shown.joints,
            fps,
            shown.skeleton.name,
            [text for _, _, text in segments],
            [(first, end) for first, end, _ in segments],
            loop=shown.loop,  # a loop's files close it again (its GLB's closing key)
        ),
        output.delivery,
        recorded=True,  # a file's motion: its feet are fixed only on --foot-fix
    )
    try:
        with staged([(0, output)]) as [(_, output)]:
            motion.save(output.staging, output.name, output.formats, delivery=output.delivery)
    except (OSError, RuntimeError, ValueError) as error:  # Blender failed, or a rig it cannot read
        raise UserError(str(error)) from error
    print(f"wrote {out}")
    delivery_notes({output.formats[0]: out}, motion, output.delivery)


def _source_rate(given: float | None, shown: Any) -> tuple[float, str]:
    """The rate a motion to export was made at, and where it comes from: ``--source-fps``, else
    its sidecar's, else its skeleton's (assumed, and said, so a clip is never played at a rate
    no one chose without a word)."""
    if given:
        return given, "--source-fps"
    if shown.fps:
        return shown.fps, "its sidecar's"
    return shown.skeleton.fps, f"the {shown.skeleton.name} skeleton's; --source-fps for another"


def _rig(args: argparse.Namespace) -> None:
    from m2d2m.motion.files.bvh_reader import BvhError
    from m2d2m.motion.rigs.joint_map import rig_mapping
    from m2d2m.motion.rigs.retarget import read_rig, target_of

    rig = Path(args.file)
    if not rig.is_file():
        raise UserError(f"{rig}: no such file (a BVH, or a GLB or glTF character with a skin)")
    try:
        clip = read_rig(rig)
        mapping = rig_mapping(clip, args.joint_map)
    except (BvhError, ValueError) as error:  # a file that is no rig, a YAML that is no map
        raise UserError(str(error)) from error
    print(f"{rig}: {len(clip.names)} joints; joint map {mapping.name}")
    print("\n".join(mapping.lines()))
    if args.out:
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(mapping.yaml(rig.name), encoding="utf-8")
        print(f"wrote {out}: correct it and give it back with --joint-map {out}")
    try:
        target = target_of(clip, mapping.joint_map(), rest_frame=args.rest_frame)
    except (BvhError, ValueError) as error:  # joints not found, or a rig our motion cannot go onto
        print("can receive motion: no")
        raise UserError(str(error)) from error
    bind = target.bind
    posed = "its rest pose" if bind.frame is None else f"frame {bind.frame} of its file"
    turned = ", turned to stand Y-up (written back in its own axes)" if bind.turned else ""
    print(f"can receive motion: yes ({target.metres_per_unit:g} m a unit; aimed from {posed}{turned})")


def add_viewers(verbs) -> None:
    render = verbs.add_parser("render", help=f"draw a motion as a stick-figure {spoken(animations())}")
    export = verbs.add_parser(
        "export",
        help=f"write a motion as {spoken(exported())} ({spoken(on_rig())} on your rig with --rig)",
    )
    for parser, run in ((render, _render), (export, _export)):
        parser.add_argument("source", help="a .npy of joints (T, J, 3) or features (T, D), or a raw corpus directory")
        parser.add_argument("--id", help="clip id when SOURCE is a corpus directory")
        parser.add_argument(
            "--skeleton", choices=["t2m", "kit"], help="the motion's skeleton (default: its sidecar's, else t2m)"
        )
        parser.add_argument("--out", required=True, help="output file; its suffix chooses the format")
        add_overwrite(parser, "--out's file")
        parser.set_defaults(run=run)
    render.add_argument(
        "--fps",
        type=positive_float,
        help="the motion's frames per second (default: its sidecar's, else the skeleton's)",
    )
    export.add_argument(
        "--source-fps",
        type=positive_float,
        help="the source's frames per second (default: its sidecar's, else the skeleton's)",
    )
    add_delivery(export, recorded=True)


def add_rig(verbs) -> None:
    rig = verbs.add_parser(
        "rig", help="which joints of a character's rig take ours: matched by name, guessed, derived or missing"
    )
    rig.add_argument("file", metavar="FILE", help="the rig: a BVH (its hierarchy and OFFSETs) or a skinned GLB/glTF")
    rig.add_argument(
        "--joint-map",
        metavar="MAP",
        help=JOINT_MAP_HELP,
    )
    rig.add_argument("--rest-frame", metavar="N", type=non_negative_int, help=REST_FRAME_HELP)
    rig.add_argument("--out", metavar="YAML", help="also write the mapping as a YAML joint map to correct")
    rig.set_defaults(run=_rig)
