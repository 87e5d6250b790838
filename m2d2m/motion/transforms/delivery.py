"""What an animator asks of a clip before its files are written (issue 40; docs/generation.md,
"Delivering a clip"): feet planted, a frame rate, a loop, root motion, the rig a BVH is on.

The edits run in one order, each on the one before's output: feet first, at the model's rate and
with the model's own contact channels (:mod:`m2d2m.motion.transforms.feet`), when asked or by default for
generated motion (:meth:`Delivery.plants_feet`: recorded motion comes out as it came in); then the frame rate (by slerp,
:mod:`m2d2m.motion.transforms.retime`), so that a loop's period is a whole number of frames at the asked rate;
then the loop; then the root (an in-place clip of a loop is an in-place loop). Action ranges
follow every step (and a loop's features its cycle: :meth:`~m2d2m.motion.clip.Motion.delivered`); a
clip that is one cycle already (an edit of a loop) is delivered as the loop it is. ``m2d2m generate``, ``m2d2m export``, the HTTP API and the page all take a
:class:`Delivery`, so the four deliver the same clip.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from m2d2m.motion.representation.pose import REST_POSES
from m2d2m.motion.representation.skeleton import Skeleton
from m2d2m.motion.transforms.feet import KeptFrames, fix_feet, skating_ratio
from m2d2m.motion.transforms.retime import (
    ROOT_MODES,
    check_fps,
    cycle_travel,
    frame_count,
    make_loop,
    resample,
    resample_ranges,
    root_motion,
)


@dataclass(frozen=True)
class Delivery:
    """``fps``: the files' frame rate (None: the model's); ``root``: ``keep``, ``in-place`` or
    ``ground``; ``loop``: one seamless cycle; ``plant_feet``: the foot fix, or None for the
    rule of :meth:`plants_feet` (on for generated motion, off for recorded motion); ``rest_pose``: a BVH's or GLB's bind pose;
    ``rig``: a BVH or glTF character whose skeleton the BVH is written on, through ``joint_map`` (a preset or a
    YAML file; default: the preset the rig's joints fit), aimed from frame ``rest_frame`` of its file
    (:func:`~m2d2m.motion.rigs.retarget.rig_bind`; default: its rest pose where that stands, else frame 0).
    ValueError in one line for a value no clip can take."""

    fps: float | None = None
    root: str = "keep"
    loop: bool = False
    plant_feet: bool | None = None
    rest_pose: str = "skeleton"
    rig: str | None = None
    joint_map: str | None = None
    rest_frame: int | None = None

    def __post_init__(self) -> None:
        if self.fps is not None:
            check_fps(self.fps)
        if self.root not in ROOT_MODES:
            raise ValueError(f"root must be one of {', '.join(ROOT_MODES)}, got {self.root!r}")
        if self.rest_pose not in REST_POSES:
            raise ValueError(f"rest pose must be one of {', '.join(REST_POSES)}, got {self.rest_pose!r}")
        if self.rig is not None and not Path(self.rig).is_file():
            raise ValueError(f"rig {self.rig}: no such file (a BVH or GLB)")
        if (self.joint_map is not None or self.rest_frame is not None) and self.rig is None:
            raise ValueError("a joint map and a rest frame go with a rig: give the rig too")
        if self.rest_frame is not None and self.rest_frame < 0:
            raise ValueError(f"a rest frame is a frame of the rig's file, 0 or more, got {self.rest_frame}")

    def plants_feet(self, recorded: bool) -> bool:
        """Whether the feet are fixed, the one rule for the CLI, the API and the page: as asked,
        else yes for generated motion, whose feet slide, and no for recorded motion (a capture, a
        corpus clip, a user's file), which is delivered exactly as it came (docs/generation.md,
        "Delivering a clip")."""
        return not recorded if self.plant_feet is None else self.plant_feet


@dataclass(frozen=True)
class Delivered:
    """A clip as delivered: its ``joints`` at ``fps``, the ``ranges`` of the actions ``kept`` (a
    loop may cut some), the ``root_track`` an in-place clip took out, ``quality`` figures, and
    for a loop the ``loop_span`` (first, end) of the frames at ``fps`` it was made from (None for
    a clip that was one cycle already) and the ``loop_travel`` (3,) of its path in a cycle
    (:class:`~m2d2m.motion.transforms.retime.Loop`)."""

    joints: np.ndarray
    fps: float
    ranges: list[tuple[int, int]]
    kept: list[int]
    root_track: np.ndarray | None
    quality: dict[str, float] = field(default_factory=dict)
    loop_span: tuple[int, int] | None = None
    loop_travel: np.ndarray | None = None


def deliver(
    joints: np.ndarray,
    fps: float,
    skeleton: Skeleton,
    ranges: list[tuple[int, int]],
    delivery: Delivery,
    features: np.ndarray | None = None,
    recorded: bool = False,
    kept_frames: KeptFrames | None = None,
    cycle: bool = False,
) -> Delivered:
    """``joints`` (T, J, 3) at ``fps`` with the actions' frame ``ranges``, edited as ``delivery``
    asks; ``features`` (T, D), the model's own, give the foot contacts when they match the joints;
    ``recorded``: the clip was captured, not generated (:meth:`Delivery.plants_feet`);
    ``kept_frames``: frames the foot fix leaves as they are (an edit's kept frames); ``cycle``:
    the clip is one cycle of a loop already (an edit of a loop), which a loop keeps whole."""
    quality: dict[str, float] = {}
    kept = list(range(len(ranges)))
    travel = None
    if delivery.plants_feet(recorded):
        quality["skating_before_fix"] = skating_ratio(joints, skeleton, fps)
        joints = fix_feet(joints, skeleton, fps, features, kept_frames)
        quality["skating"] = skating_ratio(joints, skeleton, fps)
    if delivery.fps is not None and delivery.fps != fps:
        target = float(delivery.fps)
        if cycle:  # through the next cycle's first frame, so that the cycle keeps its period
            ahead = np.concatenate([joints, joints[:1] + cycle_travel(joints)])
            joints = resample(ahead, skeleton, fps, target)[: frame_count(len(joints), fps, target)]
        else:
            joints = resample(joints, skeleton, fps, target)
        ranges = resample_ranges(ranges, fps, target, len(joints))
        fps = target
    span = None
    if cycle:
        travel = cycle_travel(joints)
        quality["loop_travel_m"] = float(np.linalg.norm(travel))
    elif delivery.loop:
        loop = make_loop(joints, fps, skeleton)
        span = first, end = loop.span
        looped = [(max(a, first) - first, min(b, end) - first) for a, b in ranges]
        kept = [i for i, (a, b) in zip(kept, looped) if a < b]
        ranges = [(a, b) for a, b in looped if a < b]
        joints, travel = loop.joints, loop.travel
        quality["loop_travel_m"] = float(np.linalg.norm(loop.travel))
    joints, track = root_motion(joints, delivery.root)
    return Delivered(joints.astype(np.float32), fps, ranges, kept, track, quality, span, travel)
