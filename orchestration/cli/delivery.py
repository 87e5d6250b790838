"""How a clip is delivered (docs/generation.md, "Delivering a clip"): the options `m2d2m generate`
and `m2d2m export` share, read into one :class:`~m2d2m.motion.transforms.delivery.Delivery`, and what an
animator must know of the files written.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from m2d2m.motion.files.formats import FORMATS, on_rig, spoken
from orchestration.cli.arguments import non_negative_int, positive_float
from orchestration.errors import UserError

# the presets are m2d2m.motion.rigs.joint_map.PRESETS, named here so that --help imports no model code
JOINT_MAP_HELP = (
    "the rig's joints for ours: a preset (cmu, cmu-motionbuilder, mixamo, smpl, bandai-namco), auto, or a YAML "
    "correcting some or all joints (`m2d2m rig FILE --out map.yaml` writes one); default: the preset the rig's "
    "joints fit, else auto"
)


REST_FRAME_HELP = (
    "the frame of the rig's BVH (0 the first) whose pose motions are aimed from, instead of its rest pose "
    "(default: the rest pose where it stands as the file's motion does, else frame 0)"
)


def add_delivery(parser: argparse.ArgumentParser, recorded: bool = False) -> None:
    """How a clip is delivered (docs/generation.md, "Delivering a clip"): one set of options for
    `m2d2m generate` and `m2d2m export` (``recorded``: its motion is a file's, whose feet are left
    as they are unless asked), as the API's fields and the page's menu."""
    from m2d2m.motion.representation.pose import REST_POSES
    from m2d2m.motion.transforms.retime import ROOT_MODES

    group = parser.add_argument_group('delivery (docs/generation.md, "Delivering a clip")')
    group.add_argument(
        "--fps",
        type=positive_float,
        help="the files' frame rate, resampled by slerp (24, 30, 60…; default: the model's)",
    )
    group.add_argument(
        "--root",
        choices=ROOT_MODES,
        default=ROOT_MODES[0],
        help="keep the root's path, take it out (in-place: the "
        f"{spoken([fmt for fmt in FORMATS.values() if fmt.root_motion], 'and')} keep it as a track), "
        "or ground the clip",
    )
    group.add_argument("--loop", action="store_true", help="one seamless cycle: the end blended into the start")
    feet = group.add_mutually_exclusive_group()
    feet.add_argument(
        "--foot-fix",
        dest="foot_fix",
        action="store_const",
        const=True,
        help="keep the feet from sliding where they touch down"
        + (" (default: the motion exactly as the file has it)" if recorded else " (the default)"),
    )
    feet.add_argument(
        "--no-foot-fix",
        dest="foot_fix",
        action="store_const",
        const=False,
        help="keep the feet as " + ("the file has them (the default)" if recorded else "generated"),
    )
    group.add_argument(
        "--rest",
        choices=REST_POSES,
        default=REST_POSES[0],
        help=f"the bind pose of the {spoken(on_rig(), 'and')}: skeleton (HumanML3D's: "
        "arms down, head bone forward; default) or "
        "tpose (arms out, head up: what retargeting tools expect); the motion is the same",
    )
    group.add_argument(
        "--rig",
        metavar="FILE",
        help=f"write the {spoken(on_rig(), 'and')} on this rig: a BVH (its hierarchy and "
        "OFFSETs) or a skinned GLB "
        "(whose GLB and FBX are the character itself, animated)",
    )
    group.add_argument(
        "--joint-map",
        metavar="MAP",
        help=JOINT_MAP_HELP,
    )
    group.add_argument("--rest-frame", metavar="N", type=non_negative_int, help=REST_FRAME_HELP)


def delivery_asked(args: argparse.Namespace) -> Any:
    """The delivery the command line asks for (``--fps``, ``--root``, ``--loop``, ``--foot-fix``
    or ``--no-foot-fix``, ``--rest``, ``--rig``, ``--joint-map``), checked in one line before anything runs."""
    from m2d2m.motion.transforms.delivery import Delivery

    try:
        return Delivery(
            fps=args.fps,
            root=args.root,
            loop=args.loop,
            plant_feet=args.foot_fix,  # None: Delivery.plants_feet's rule for what is delivered
            rest_pose=args.rest,
            rig=None if args.rig is None else str(Path(args.rig).resolve()),
            joint_map=args.joint_map,
            rest_frame=args.rest_frame,
        )
    except ValueError as error:
        raise UserError(str(error)) from error


def delivered(motion: Any, delivery: Any, recorded: bool = False) -> Any:
    """``motion`` delivered as asked (``recorded``: a file's motion, not a generation); a clip the
    delivery cannot take (a loop of a clip shorter than its cross-fade) is one line."""
    try:
        return motion.delivered(delivery, recorded)
    except ValueError as error:
        raise UserError(str(error)) from error


def delivery_notes(files: dict[str, Path], motion: Any, delivery: Any) -> None:
    """What an animator must know of the files written: a BVH's rate and bind pose, an in-place
    clip's root track (where the files keep it), a loop's travel."""
    if "bvh" in files:
        print(bvh_note(files["bvh"], motion.fps, delivery.rest_pose, delivery.rig))
    if motion.root_track is not None:
        written = [FORMATS[kind] for kind in files]
        # a file on a rig has no such track: its root is the rig's own
        kept = [fmt.root_motion for fmt in written if fmt.root_motion and not (fmt.on_rig and delivery.rig)]
        lacking = spoken([fmt for fmt in FORMATS.values() if not fmt.root_motion], "and")
        where = f"kept in {' and '.join(kept)}" if kept else f"not kept: {lacking} have no place for it"
        print(f"root motion: taken out of the clip (in place); {where}")
    if motion.loop:
        print(f"loop: one cycle of {motion.seconds:.2f} s, travelling {motion.quality['loop_travel_m']:.2f} m a cycle")


def bvh_note(path: Path, fps: float, rest_pose: str, rig: str | None = None) -> str:
    """What an animator must know to import a BVH: its rate (Blender keeps its scene's 24 fps
    unless told) and its bind pose."""
    if rig is not None:
        rest = f"the rig's own ({Path(rig).name})"
    else:
        rest = "a T-pose" if rest_pose == "tpose" else "HumanML3D's (arms down; --rest tpose for a T-pose)"
    return (
        f"{path.name}: {fps:g} fps (Frame Time {1 / fps:.4f} s; in Blender's BVH import tick "
        f"'Update Scene FPS' or it plays at the scene's rate), rest pose {rest}"
    )
