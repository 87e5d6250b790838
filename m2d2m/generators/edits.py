"""Edits of a result on its timeline (issue 41; docs/generation.md, "Editing a result"): redo one
action and keep the rest, fill a gap between two clips, pin a pose, continue a clip, lay a body
part's action over a span.

Every operation is one generation request any model that keeps frames can serve (the
:class:`~m2d2m.generators.protocol.Keep` of its ``generate``): a new timeline of actions and
lengths, the features to keep laid out on it, and the frames copied back bit for bit once the
model has sampled (:class:`Edit`). Around each span that changes, ``margin`` frames of what is
kept are sampled again, so that the model joins old and new itself; outside the margins the result
is the source. The operations work on features, the representation every model shares; the
joints follow from them (:func:`apply_edit`), so the actions before an edit stand where they
stood and those after it continue from where the new motion ends.

Discrete diffusion and MMM fill the free tokens around kept ones (M2D2M §3; MMM §3.3, its
in-betweening); MotionDiffuse replaces the kept entries at every step (its editing by
replacement). A span is widened to whole steps of the model (``step``: 4 frames for the token
models) so that no token holds both kept and free frames.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from m2d2m.generators.protocol import Keep, MotionGenerator
from m2d2m.motion.clip import Motion
from m2d2m.motion.representation import features_to_joints
from m2d2m.motion.rigid import rigid_shapes
from m2d2m.motion.skeleton import Skeleton

EDIT_MARGIN_SECONDS = 0.4  # sampled again on each side of a changed span, so that the join is the model's


@dataclass(frozen=True)
class Edit:
    """A request on a new timeline: ``actions`` with their lengths in ``frames`` (they tile it),
    the ``keep`` the model is given (features laid out on the timeline, the frames it keeps), and
    ``paste``, the frames (F,) or entries (F, D) whose features are copied from ``keep.features``
    into the result; ``body``: the source's features, whose rigid body the result is put on
    (:func:`body_of`); ``pin``: the frame and features of a pinned pose, which the result is
    measured against."""

    actions: list[str]
    frames: list[int]
    keep: Keep
    paste: np.ndarray
    body: np.ndarray
    pin: tuple[int, np.ndarray] | None = None

    def __post_init__(self) -> None:
        if len(self.actions) != len(self.frames) or sum(self.frames) != len(self.keep.features):
            raise ValueError(
                f"{len(self.actions)} actions of {sum(self.frames)} frames on a timeline of {len(self.keep.features)}"
            )
        if not self.keep.frames.any():
            raise ValueError("the edit keeps nothing of the source: generate it anew instead")
        if self.keep.entries.all():
            raise ValueError("the edit leaves nothing to sample: every frame is kept")


@dataclass(frozen=True)
class Timeline:
    """A result's features (F, D) and its actions' texts and ``(first, end)`` frames: the
    actions tile the features (an action runs to the next one's start; the last to the end)."""

    features: np.ndarray
    actions: list[str]
    starts: list[int]

    @property
    def frames(self) -> list[int]:
        """Each action's length: to the next action's start, the last to the end."""
        ends = [*self.starts[1:], len(self.features)]
        return [end - start for start, end in zip(self.starts, ends)]

    def span(self, index: int) -> tuple[int, int]:
        """Action ``index``'s first and end frames; IndexError in one line for one it lacks."""
        if not 0 <= index < len(self.actions):
            raise IndexError(f"action {index + 1} of a result with {len(self.actions)} action(s)")
        return self.starts[index], self.starts[index] + self.frames[index]


def margin_frames(generator: MotionGenerator) -> int:
    """:data:`EDIT_MARGIN_SECONDS` in whole steps of the model."""
    return generator.round_frames(round(EDIT_MARGIN_SECONDS * generator.fps))


def _free(count: int, span: tuple[int, int], margin: int) -> np.ndarray:
    """(count,) True outside ``span`` widened by ``margin`` on each side: the frames kept."""
    kept = np.ones(count, dtype=bool)
    kept[max(0, span[0] - margin) : min(count, span[1] + margin)] = False
    return kept


def _placeholder(before: np.ndarray, after: np.ndarray, frames: int) -> np.ndarray:
    """Features for ``frames`` new frames between ``before`` and ``after`` (either may be empty):
    the nearer edge frame repeated. The model samples them anew; they only stand in where a
    codec reads the neighbourhood of a kept frame."""
    if not len(before):
        return np.repeat(after[:1], frames, axis=0)
    if not len(after):
        return np.repeat(before[-1:], frames, axis=0)
    half = frames // 2
    return np.concatenate([np.repeat(before[-1:], half, axis=0), np.repeat(after[:1], frames - half, axis=0)])


def _edit(features: np.ndarray, actions: list[str], frames: list[int], kept: np.ndarray, body: np.ndarray) -> Edit:
    return Edit(actions, frames, Keep(features, kept), kept.copy(), body)


def regenerate_action(
    timeline: Timeline, index: int, margin: int, text: str | None = None, frames: int | None = None
) -> Edit:
    """Action ``index`` sampled again (under ``text``, ``frames`` long: by default its own), every
    other action kept outside ``margin`` frames on each side of it."""
    first, end = timeline.span(index)
    frames = end - first if frames is None else frames
    if frames <= 0:
        raise ValueError(f"an action needs at least one frame, got {frames}")
    before, after = timeline.features[:first], timeline.features[end:]
    features = np.concatenate([before, _placeholder(before, after, frames), after])
    actions = list(timeline.actions)
    actions[index] = actions[index] if text is None else text
    lengths = list(timeline.frames)
    lengths[index] = frames
    return _edit(features, actions, lengths, _free(len(features), (first, first + frames), margin), timeline.features)


def fill_between(first: Timeline, second: Timeline, gap: int, margin: int, text: str = "") -> Edit:
    """``first``, then ``gap`` new frames doing ``text`` (empty: whatever joins them, the model's
    null condition), then ``second``: the in-between sampled with both ends kept outside
    ``margin`` frames of it. The result takes ``first``'s body, which ``second``'s frames may
    differ from by millimetres."""
    if gap <= 0:
        raise ValueError(f"a gap of at least one frame, got {gap}")
    features = np.concatenate([first.features, _placeholder(first.features, second.features, gap), second.features])
    start = len(first.features)
    return _edit(
        features,
        [*first.actions, text, *second.actions],
        [*first.frames, gap, *second.frames],
        _free(len(features), (start, start + gap), margin),
        first.features,
    )


def continue_after(timeline: Timeline, actions: Sequence[str], frames: Sequence[int], margin: int) -> Edit:
    """``actions`` (``frames`` long each) appended to the timeline, its end sampled again over
    ``margin`` frames so that the new actions start from it."""
    if not actions or len(actions) != len(frames) or min(frames) <= 0:
        raise ValueError("give each new action a length of at least one frame")
    added = sum(frames)
    features = np.concatenate([timeline.features, _placeholder(timeline.features, timeline.features[:0], added)])
    end = len(timeline.features)
    return _edit(
        features,
        [*timeline.actions, *actions],
        [*timeline.frames, *frames],
        _free(len(features), (end, end + added), margin),
        timeline.features,
    )


def hold_pose(timeline: Timeline, pose: np.ndarray, frame: int, step: int, margin: int) -> Edit:
    """The motion passing through ``pose`` (one frame's features, D) at ``frame``: the model is
    given the pose on the ``step`` frames of the grid that hold it (one token of a token model),
    kept, ``margin`` frames on each side sampled again, the rest the source. The source's frames
    are pasted back and the model's frames around the pin bent to meet the pose at ``frame``
    itself, on the grid or not (:func:`meet_pin`); what is left of the distance is in the
    result's ``quality`` (:func:`pin_error`)."""
    count = len(timeline.features)
    if not 0 <= frame < count:
        raise ValueError(f"a pose pinned at frame {frame} lies outside the motion's {count} frames")
    if pose.shape != timeline.features.shape[1:]:
        raise ValueError(f"a pose of {timeline.features.shape[1]} features, got shape {pose.shape}")
    block = (frame // step * step, min(count, frame // step * step + step))
    features = timeline.features.copy()
    features[block[0] : block[1]] = pose
    pasted = _free(count, block, margin)
    kept = pasted.copy()
    kept[block[0] : block[1]] = True
    return Edit(
        list(timeline.actions), list(timeline.frames), Keep(features, kept), pasted, timeline.features, (frame, pose)
    )


def layer_part(timeline: Timeline, span: tuple[int, int], part: np.ndarray, text: str, margin: int) -> Edit:
    """A body part doing ``text`` over the frames ``span`` while the rest of the body does what it
    did (STMC's body-part tracks; MotionDiffuse's editing by replacement): ``part`` (D,) is the
    part's feature dimensions, free over the span and ``margin`` frames on each side (so that it
    eases in and out); every other dimension is kept there, and whole frames elsewhere, all of
    them pasted back. The actions the span cuts are split around it, the span one action doing
    ``text``."""
    first, end = span
    count = len(timeline.features)
    if not 0 <= first < end <= count:
        raise ValueError(f"a span of frames {first} to {end} outside the motion's {count} frames")
    cuts = sorted({*(start for start in timeline.starts if not first < start < end), first, end, count})
    owner = np.searchsorted(timeline.starts, cuts[:-1], side="right") - 1
    actions = [text if first <= a < end else timeline.actions[k] for a, k in zip(cuts[:-1], owner)]
    entries = np.ones(timeline.features.shape, dtype=bool)
    entries[max(0, first - margin) : min(count, end + margin)] &= ~part
    keep = Keep(timeline.features, np.ones(count, dtype=bool), entries)
    return Edit(actions, list(np.diff(cuts).tolist()), keep, entries.copy(), timeline.features)


def apply_edit(edit: Edit, sampled: Motion, skeleton: Skeleton) -> Motion:
    """The model's result of ``edit`` with the pasted frames' features set back to the source's
    exactly, its joints derived from the features (HumanML3D's recovery: the root integrated from
    the first frame), its actions' frames those of the edit's timeline, and for a pinned pose
    its distance from the pose (``quality["pin_error_m"]``)."""
    if len(sampled.features) != len(edit.paste):
        raise ValueError(f"the model made {len(sampled.features)} frames for a timeline of {len(edit.paste)}")
    features = np.array(sampled.features, dtype=np.float32)
    features[edit.paste] = edit.keep.features[edit.paste]
    starts = np.cumsum([0, *edit.frames])
    quality = dict(sampled.quality)
    if edit.pin is not None:
        features = meet_pin(features, edit.paste, *edit.pin, skeleton)
        quality["pin_error_m"] = pin_error(features, edit.pin[1], edit.pin[0], skeleton)
    return replace(
        sampled,
        quality=quality,
        features=features,
        joints=np.asarray(features_to_joints(features, skeleton), dtype=np.float32),
        actions=list(edit.actions),
        ranges=[(int(a), int(b)) for a, b in zip(starts[:-1], starts[1:])],
    )


def meet_pin(features: np.ndarray, pasted: np.ndarray, frame: int, pose: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """``features`` (F, D) bent so that frame ``frame`` is ``pose`` (D,) exactly in its height,
    its joints around the root (RIC) and its rotations, the model's motion elsewhere: what the
    model's frame misses by is added to the sampled frames around it, all of it at the frame and
    easing to none (a half cosine) at the pasted frames on either side, which stay the source's
    bit for bit. The root's path and the velocities stay the model's, so the pose is met where the
    model walked to, facing where it faces (as :func:`pin_error` measures)."""
    count = 3 * (skeleton.num_joints - 1)
    shape = slice(3, 4 + count + 2 * count)  # root height, RIC positions, 6D rotations
    first = frame - int(np.argmax(pasted[frame::-1])) if pasted[: frame + 1].any() else -1
    end = frame + int(np.argmax(pasted[frame:])) if pasted[frame:].any() else len(features)
    ramp_in = (np.arange(first + 1, frame + 1) - first) / (frame - first)
    ramp_out = (end - np.arange(frame + 1, end)) / (end - frame)
    weight = 0.5 - 0.5 * np.cos(np.pi * np.concatenate([ramp_in, ramp_out]))
    bent = features.copy()
    bent[first + 1 : end, shape] += weight[:, None] * (pose[shape] - features[frame, shape])
    return bent


def body_of(edit: Edit, skeleton: Skeleton) -> dict[int, np.ndarray]:
    """The rigid body of the edit's source (:func:`m2d2m.motion.rigid.rigid_shapes`): the result
    put on it, its kept frames have the joints the source had; a body fitted to the result's own
    frames would move them by up to centimetres."""
    return rigid_shapes(features_to_joints(edit.body, skeleton), skeleton)


def pin_error(features: np.ndarray, pose: np.ndarray, frame: int, skeleton: Skeleton) -> float:
    """How far (metres) the motion ``features`` is from the pose at ``frame``: the largest distance
    between a joint of the two, each placed around its root and facing its heading (the features'
    root-relative positions, HumanML3D's RIC), so a pose pinned from a clip facing elsewhere counts
    only by its shape and height."""
    count = 3 * (skeleton.num_joints - 1)
    ours = features[frame, 4 : 4 + count].reshape(-1, 3)
    theirs = pose[4 : 4 + count].reshape(-1, 3)
    return float(np.linalg.norm(ours - theirs, axis=-1).max() * skeleton.metres_per_unit)
