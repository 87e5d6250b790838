"""Editing a result on its timeline, in seconds, for the command line, the API and Python (issue 41;
docs/generation.md, "Editing a result"): a result read back from the files ``m2d2m generate``
wrote (or a generation in memory) as the timeline an operation of
:mod:`orchestration.edit_operations` plans on, and the planned edit sampled and finished.

A result's timeline is its ``.features.npy`` (the model's own features, at its frame rate; a
loop's, the cycle's own) and the actions of its ``.json`` sidecar (their frames converted from the
sidecar's rate, which a ``--fps`` delivery changed), with its joints as delivered when they are at
the model's rate (the kept frames of an edit keep them, feet and all). A model that works in steps
(the token models' 4 frames) gets whole steps: an action whose length is not one loses its last
frames (said in a warning), the margins are whole steps, and a pinned pose is given to the model
on the step that holds its frame (the result meets it at the frame itself). A loop keeps every
frame: its regenerated actions and pinned poses are sampled round the loop, in whole steps of the
request (:mod:`m2d2m.generators.edits`); to fill or continue one is to make a clip of it, fitted.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from m2d2m.generators.edits import Edit, Timeline, apply_edit, body_of, kept_frames
from m2d2m.generators.protocol import MotionGenerator
from m2d2m.motion.clip import Motion
from m2d2m.motion.representation.features import features_to_joints
from orchestration.errors import UserError
from orchestration.generate.prompts import check_seconds
from orchestration.viewing import load_features, read_sidecar


def read_result(path: str | Path, generator: MotionGenerator) -> Timeline:
    """The timeline of a result on disk (its ``.npy`` or ``.features.npy``; the features beside the
    joints when there are, else features made from the joints), its actions and whether it is a
    loop from its sidecar; a file without one is one action. Fitted to the model's steps. Joints
    are at their sidecar's rate (a ``--fps`` delivery), resampled to the model's; features are
    always the model's."""
    path = Path(path)
    is_features = path.name.endswith(".features.npy")
    features_file = path if is_features else path.with_name(path.stem + ".features.npy")
    sidecar = read_sidecar(path)
    if features_file.is_file():  # the model's own, written by its generation
        features = load_features(features_file, generator.skeleton, given=False)
    else:
        features = load_features(path, generator.skeleton, fps=None if sidecar is None else sidecar.fps)
    if sidecar is None or not sidecar.segments:
        return _fitted(Timeline(features, [""], [0]), generator.frame_step, str(path))
    joints_file = path.with_name(path.name.removesuffix(".features.npy") + ".npy") if is_features else path
    joints = None
    if joints_file.is_file() and sidecar.fps == generator.fps:
        joints = np.load(joints_file, allow_pickle=False)
        if sidecar.root_motion is not None:  # an in-place clip: its path added back, where the features have it
            joints = joints + np.load(joints_file.with_name(sidecar.root_motion), allow_pickle=False)[:, None]
    return _timeline(
        features,
        [text for _, _, text in sidecar.segments],
        [first for first, _, _ in sidecar.segments],
        generator,
        sidecar.fps,
        str(path),
        sidecar.loop,
        joints,
    )


def timeline_of(motion: Motion, generator: MotionGenerator, origin: str) -> Timeline:
    """The timeline of a result in memory (a served generation): its features, at the model's
    rate, and its actions, whose frames a delivery at another rate changed."""
    firsts = [first for first, _ in motion.ranges]
    joints = None
    if motion.fps == generator.fps:
        joints = motion.joints if motion.root_track is None else motion.joints + motion.root_track[:, None]
    features = np.asarray(motion.features)
    return _timeline(features, list(motion.actions), firsts, generator, motion.fps, origin, motion.loop, joints)


def motion_of(
    features: np.ndarray, texts: Sequence[str], seconds: Sequence[float | None], generator: MotionGenerator, origin: str
) -> Motion:
    """A motion made elsewhere (its features at the model's rate) as a result of ``generator`` to
    edit: its actions ``texts``, each ``seconds`` long in order (the last one's None: to the end;
    fitted to the model's steps), its joints from the features on one rigid skeleton."""
    for text, length in zip(texts, seconds):
        if length is not None:
            check_seconds(generator, length, repr(text))
    lengths = [round(s * generator.fps) if s is not None else None for s in seconds]
    if None in lengths[:-1] or any(n is not None and n < 1 for n in lengths):
        raise UserError(f"{origin}: give every action but the last a length of at least one frame")
    firsts = [0, *np.cumsum(lengths[:-1]).tolist()]
    if firsts[-1] >= len(features) or sum(n or 0 for n in lengths) > len(features):
        raise UserError(f"{origin}: its actions' seconds add up to more than its {len(features) / generator.fps:g} s")
    timeline = _timeline(features, list(texts), firsts, generator, generator.fps, origin)
    ends = [*timeline.starts[1:], len(timeline.features)]
    joints = features_to_joints(timeline.features, generator.skeleton)
    return Motion(
        timeline.features,
        np.asarray(joints, dtype=np.float32),
        generator.fps,
        generator.skeleton.name,
        list(timeline.actions),
        list(zip(timeline.starts, ends)),
    ).on_rigid_skeleton()


def _timeline(
    features: np.ndarray,
    actions: list[str],
    firsts: list[int],
    generator: MotionGenerator,
    fps: float,
    origin: str,
    loop: bool = False,
    joints: np.ndarray | None = None,
) -> Timeline:
    """Features at the model's rate with actions starting at ``firsts`` frames of ``fps`` (the
    first action from frame 0), fitted to the model's steps unless a ``loop``; ``joints``: as
    delivered, kept when they are the features' frames."""
    scale = generator.fps / fps
    starts = [0, *(round(first * scale) for first in firsts[1:])]
    if joints is not None and np.shape(joints) != (len(features), generator.skeleton.num_joints, 3):
        joints = None
    timeline = Timeline(features, actions or [""], starts, loop, joints)
    if min(timeline.frames) < 1:
        raise UserError(f"{origin}: an action is shorter than a frame at the model's {generator.fps:g} fps")
    return timeline if loop else _fitted(timeline, generator.frame_step, origin)


def _fitted(timeline: Timeline, step: int, origin: str) -> Timeline:
    """``timeline`` with each action cut to whole steps of ``step`` frames (a warning says how many
    frames went); an action shorter than a step is one line. A loop so cut is a clip."""
    kept = [n // step * step for n in timeline.frames]
    if min(kept) == 0:
        raise UserError(f"{origin}: an action is shorter than the model's step of {step} frames")
    if kept == timeline.frames:
        return replace(timeline, loop=False)
    frames = np.concatenate([np.arange(s, s + n) for s, n in zip(timeline.starts, kept)])
    print(
        f"warning: {origin}: {sum(timeline.frames) - sum(kept)} frame(s) cut so that each action is whole "
        f"steps of {step} frames",
        file=sys.stderr,
    )
    return Timeline(
        timeline.features[frames],
        timeline.actions,
        [int(s) for s in np.cumsum([0, *kept[:-1]])],
        joints=None if timeline.joints is None else timeline.joints[frames],
    )


def as_clip(timeline: Timeline, generator: MotionGenerator) -> Timeline:
    """A loop as a clip (its frames in order, fitted to the model's steps), for the edits that do
    not keep it one cycle: filling between it and another, continuing it, a body part over a span."""
    return _fitted(timeline, generator.frame_step, f"the loop of {len(timeline.features)} frames")


def edit_options(generator: MotionGenerator, edit: Edit, options: dict[str, Any]) -> dict[str, Any]:
    """The sampling options an edit is made with: the asked ones, with the method the model edits
    several actions with where it declares one (:attr:`~m2d2m.generators.protocol.MotionGenerator.edit_method`)."""
    if generator.edit_method is not None and len(edit.actions) > 1:
        return {**options, "method": generator.edit_method}
    return dict(options)


def finish_edit(edit: Edit, sampled: Motion, generator: MotionGenerator, said: str, **recorded: Any) -> Motion:
    """The model's sample of ``edit`` with the kept frames pasted back, on one rigid skeleton, its
    settings recording the edit (``said``: what it does; ``recorded``: more, such as its parent),
    its kept frames' joints their sources' as delivered, which its delivery's foot fix keeps."""
    motion = apply_edit(edit, sampled, generator.skeleton)
    edited = edit.result_origin < 0  # a frame with any entry sampled
    settings = {**motion.settings, "edit": said, "edited_frames": int(edited.sum()), **recorded}
    body = body_of(edit, generator.skeleton)
    motion = replace(motion, settings=settings).on_rigid_skeleton(body)
    return replace(motion, kept_frames=kept_frames(edit, motion, body))


def sample_edit(generator: MotionGenerator, edit: Edit, seed: int = 0, said: str = "", **options: Any) -> Motion:
    """``edit`` sampled by ``generator`` with ``seed`` and finished (:func:`finish_edit`)."""
    try:
        settings = generator.options(**edit_options(generator, edit, options))
        sampled = generator.generate([edit.actions], [edit.frames], settings, [seed], [edit.keep])
    except ValueError as error:
        raise UserError(str(error)) from error
    return finish_edit(edit, sampled[0], generator, said)


def pose_at(timeline: Timeline, frame: int, origin: str) -> np.ndarray:
    """One frame's features of a result, to pin: a UserError naming the frames it has."""
    if not 0 <= frame < len(timeline.features):
        raise UserError(f"{origin} has frames 0 to {len(timeline.features) - 1}, not {frame}")
    return timeline.features[frame]
