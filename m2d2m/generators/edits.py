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
stood and those after it continue from where the new motion ends; the kept frames' joints are
their sources' as delivered, feet planted and all (:func:`kept_frames`).

A loop (one cycle whose last frame runs on into its first) is edited round the loop: the request
starts part-way round, so that the span that changes has the loop's own frames on both sides
(its seam among them, kept), and the result is read off it in the loop's order, again one cycle
(:class:`Cycle`).

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
from m2d2m.motion.representation.features import facing_direction, features_to_joints
from m2d2m.motion.representation.rigid import on_rigid_skeleton, rigid_shapes
from m2d2m.motion.representation.skeleton import Skeleton
from m2d2m.motion.transforms.feet import KeptFrames

EDIT_MARGIN_SECONDS = 0.4  # sampled again on each side of a changed span, so that the join is the model's


@dataclass(frozen=True)
class Timeline:
    """A result's features (F, D) and its actions' texts and ``(first, end)`` frames: the
    actions tile the features (an action runs to the next one's start; the last to the end).
    ``loop``: one cycle of a loop, its last frame running on into its first; ``joints`` (F, J, 3):
    the result as it was delivered, frame for frame with the features (None when it was
    delivered at another rate), which an edit's kept frames keep (:func:`kept_frames`)."""

    features: np.ndarray
    actions: list[str]
    starts: list[int]
    loop: bool = False
    joints: np.ndarray | None = None

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


@dataclass(frozen=True)
class Cycle:
    """How a loop's edit is read off its request: the result's ``actions`` and their lengths in
    ``frames`` (one cycle), and ``take`` (result frames,), the request frame each one is."""

    actions: list[str]
    frames: list[int]
    take: np.ndarray


@dataclass(frozen=True)
class Edit:
    """A request on a new timeline: ``actions`` with their lengths in ``frames`` (they tile it),
    the ``keep`` the model is given (features laid out on the timeline, the frames it keeps), and
    ``paste``, the frames (F,) or entries (F, D) whose features are copied from ``keep.features``
    into the result; ``sources``: the results the kept frames come from, the first one's rigid
    body the result's (:func:`body_of`); ``origin`` (F,): the frame of the sources (counted
    through them in order) each request frame pastes whole, −1 where anything is sampled;
    ``pin``: the frame and features of a pinned pose, which the result is measured against;
    ``cycle``: for a loop, how the result is read off the request (else it is the request)."""

    actions: list[str]
    frames: list[int]
    keep: Keep
    paste: np.ndarray
    sources: tuple[Timeline, ...]
    origin: np.ndarray
    pin: tuple[int, np.ndarray] | None = None
    cycle: Cycle | None = None

    def __post_init__(self) -> None:
        if len(self.actions) != len(self.frames) or sum(self.frames) != len(self.keep.features):
            raise ValueError(
                f"{len(self.actions)} actions of {sum(self.frames)} frames on a timeline of {len(self.keep.features)}"
            )
        if len(self.origin) != len(self.keep.features):
            raise ValueError(f"an origin for each of the {len(self.keep.features)} frames, got {len(self.origin)}")
        if not self.keep.frames.any():
            raise ValueError("the edit keeps nothing of the source: generate it anew instead")
        if self.keep.entries.all():
            raise ValueError("the edit leaves nothing to sample: every frame is kept")

    @property
    def result_actions(self) -> list[str]:
        """The result's actions, in order (a loop's request starts part-way round it)."""
        return list(self.actions if self.cycle is None else self.cycle.actions)

    @property
    def result_origin(self) -> np.ndarray:
        """(result frames,) the frame of the sources each frame of the result keeps, −1 for one sampled."""
        return self.origin if self.cycle is None else self.origin[self.cycle.take]


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
    the nearer edge frame repeated, zeros with neither (the edit then keeps nothing, which
    :class:`Edit` refuses in its own words). The model samples them anew; they only stand in
    where a codec reads the neighbourhood of a kept frame."""
    if not len(before) and not len(after):
        return np.zeros((frames, *before.shape[1:]), dtype=before.dtype)
    if not len(before):
        return np.repeat(after[:1], frames, axis=0)
    if not len(after):
        return np.repeat(before[-1:], frames, axis=0)
    half = frames // 2
    return np.concatenate([np.repeat(before[-1:], half, axis=0), np.repeat(after[:1], frames - half, axis=0)])


def _new(frames: int) -> np.ndarray:
    """The origin of ``frames`` frames sampled anew."""
    return np.full(frames, -1)


def _edit(
    features: np.ndarray,
    actions: list[str],
    frames: list[int],
    kept: np.ndarray,
    sources: tuple[Timeline, ...],
    origin: np.ndarray,
) -> Edit:
    """The edit that keeps and pastes back the whole frames ``kept``, whose sources' frames are ``origin``."""
    return Edit(actions, frames, Keep(features, kept), kept.copy(), sources, np.where(kept, origin, -1))


def regenerate_action(
    timeline: Timeline,
    index: int,
    margin: int,
    text: str | None = None,
    frames: int | None = None,
    step: int = 1,
) -> Edit:
    """Action ``index`` sampled again (under ``text``, ``frames`` long: by default its own), every
    other action kept outside ``margin`` frames on each side of it; in a loop, round the loop
    (``step``: the model's, whose whole steps the request of a loop is laid out in)."""
    first, end = timeline.span(index)
    frames = end - first if frames is None else frames
    if frames <= 0:
        raise ValueError(f"an action needs at least one frame, got {frames}")
    before, after = timeline.features[:first], timeline.features[end:]
    if timeline.loop:  # its neighbours round the loop
        count = len(timeline.features)
        middle = _placeholder(timeline.features[[first - 1]], timeline.features[[end % count]], frames)
    else:
        middle = _placeholder(before, after, frames)
    actions = list(timeline.actions)
    actions[index] = actions[index] if text is None else text
    lengths = list(timeline.frames)
    lengths[index] = frames
    if timeline.loop:
        return _round_the_loop(timeline, (first, end), middle, margin, step, actions, lengths)
    count = len(before) + frames + len(after)
    return _edit(
        np.concatenate([before, middle, after]),
        actions,
        lengths,
        _free(count, (first, first + frames), margin),
        (timeline,),
        np.concatenate([np.arange(first), _new(frames), np.arange(end, len(timeline.features))]),
    )


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
        (first, second),
        np.concatenate([np.arange(start), _new(gap), start + np.arange(len(second.features))]),
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
        (timeline,),
        np.concatenate([np.arange(end), _new(added)]),
    )


def hold_pose(timeline: Timeline, pose: np.ndarray, frame: int, step: int, margin: int) -> Edit:
    """The motion passing through ``pose`` (one frame's features, D) at ``frame``: the model is
    given the pose on the ``step`` frames of the grid that hold it (one token of a token model;
    round a loop, the ``step`` frames from it), kept, ``margin`` frames on each side sampled again,
    the rest the source. The source's frames are pasted back and the model's frames around the
    pin bent to meet the pose at ``frame`` itself, on the grid or not (:func:`meet_pin`); what is
    left of the distance is in the result's ``quality`` (:func:`pin_error`)."""
    count = len(timeline.features)
    if not 0 <= frame < count:
        raise ValueError(f"a pose pinned at frame {frame} lies outside the motion's {count} frames")
    if pose.shape != timeline.features.shape[1:]:
        raise ValueError(f"a pose of {timeline.features.shape[1]} features, got shape {pose.shape}")
    if timeline.loop:
        first = min(frame, count - step)
        held = np.repeat(pose[None], step, axis=0)
        return _round_the_loop(
            timeline, (first, first + step), held, margin, step, list(timeline.actions), timeline.frames, frame - first
        )
    block = (frame // step * step, min(count, frame // step * step + step))
    features = timeline.features.copy()
    features[block[0] : block[1]] = pose
    pasted = _free(count, block, margin)
    kept = pasted.copy()
    kept[block[0] : block[1]] = True
    return Edit(
        list(timeline.actions),
        list(timeline.frames),
        Keep(features, kept),
        pasted,
        (timeline,),
        np.where(pasted, np.arange(count), -1),
        (frame, pose),
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
    origin = np.where(entries.all(axis=1), np.arange(count), -1)
    return Edit(actions, list(np.diff(cuts).tolist()), keep, entries.copy(), (timeline,), origin)


def _round_the_loop(
    timeline: Timeline,
    span: tuple[int, int],
    middle: np.ndarray,
    margin: int,
    step: int,
    actions: list[str],
    frames: list[int],
    pinned: int | None = None,
) -> Edit:
    """The loop ``timeline`` with its frames ``span`` replaced by ``middle`` (placeholders of new
    frames; with ``pinned``, a pose the model keeps and nothing pastes, met at that frame of it)
    and sampled with ``margin`` frames on each side; the result one cycle of ``actions`` in
    ``frames``.

    The result, written from the span's end round to its start and then the middle (the
    ``ring``), is asked for starting part-way round: half the kept frames before the sampled
    ones, the rest after them, the seam kept among them, in whole steps of ``step`` (frames of
    the ring's start repeated at the end, kept, to fill the last step). The request's actions
    are the result's cut at the nearest whole steps: kept frames keep their features whatever
    text the model is given."""
    count = len(timeline.features)
    first, end = span
    around = (end + np.arange(count - (end - first))) % count  # the kept frames, from the span's end round to its start
    ring = np.concatenate([timeline.features[around], middle])
    length, kept_count = len(ring), len(around)
    before = (kept_count - 2 * margin) // 2 // step * step
    sampled = -(-(len(middle) + 2 * margin) // step) * step
    total = -(-length // step) * step
    if before < step or total - before - sampled < step:
        raise ValueError(
            f"a loop of {count} frames is too short to sample {end - first} of them again with {margin} "
            "on each side and keep frames round the loop"
        )
    start = (kept_count - margin - before) % length
    order = (start + np.arange(total)) % length  # request frame → ring frame
    result = np.arange(length)
    ring_of_result = np.where(  # result frame → ring frame: before the span, the middle, after it
        result < first,
        kept_count - first + result,
        np.where(result < first + len(middle), kept_count + result - first, result - first - len(middle)),
    )
    free = np.zeros(total, dtype=bool)
    free[before : before + sampled] = True
    kept = ~free
    if pinned is not None:
        kept[before + margin : before + margin + len(middle)] = True
    owner = np.repeat(np.arange(len(frames)), frames)[np.argsort(ring_of_result)][order]  # each request frame's action
    cuts = np.unique(np.round((np.flatnonzero(np.diff(owner)) + 1) / step).astype(int) * step)
    bounds = [0, *(int(c) for c in cuts if 0 < c < total), total]
    pieces: list[tuple[int, int]] = []  # (action, frames) of the request
    for a, b in zip(bounds[:-1], bounds[1:]):
        action = int(owner[(a + b) // 2])
        if pieces and pieces[-1][0] == action:
            pieces[-1] = (action, pieces[-1][1] + b - a)
        else:
            pieces.append((action, b - a))
    origin = np.concatenate([around, _new(len(middle))])[order]
    return Edit(
        [actions[action] for action, _ in pieces],
        [n for _, n in pieces],
        Keep(ring[order], kept),
        ~free,
        (timeline,),
        np.where(free, -1, origin),
        None if pinned is None else (before + margin + pinned, middle[0]),
        Cycle(list(actions), list(frames), (ring_of_result - start) % length),
    )


def apply_edit(edit: Edit, sampled: Motion, skeleton: Skeleton) -> Motion:
    """The model's result of ``edit`` with the pasted frames' features set back to the source's
    exactly (read off the request in a loop's order, for a loop), its joints derived from the
    features (HumanML3D's recovery: the root integrated from the first frame), its actions' frames
    those of the edit's timeline, and for a pinned pose its distance from the pose
    (``quality["pin_error_m"]``)."""
    if len(sampled.features) != len(edit.paste):
        raise ValueError(f"the model made {len(sampled.features)} frames for a timeline of {len(edit.paste)}")
    features = np.array(sampled.features, dtype=np.float32)
    features[edit.paste] = edit.keep.features[edit.paste]
    quality = dict(sampled.quality)
    if edit.pin is not None:
        features = meet_pin(features, edit.paste, *edit.pin, skeleton)
        quality["pin_error_m"] = pin_error(features, edit.pin[1], edit.pin[0], skeleton)
    actions, frames, tokens = edit.actions, edit.frames, sampled.tokens
    if edit.cycle is not None:
        features = features[edit.cycle.take]
        actions, frames, tokens = edit.cycle.actions, edit.cycle.frames, None  # the request's tokens, not the cycle's
    starts = np.cumsum([0, *frames])
    return replace(
        sampled,
        quality=quality,
        features=features,
        joints=np.asarray(features_to_joints(features, skeleton), dtype=np.float32),
        actions=list(actions),
        ranges=[(int(a), int(b)) for a, b in zip(starts[:-1], starts[1:])],
        tokens=tokens,
        loop=edit.cycle is not None,
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
    """The rigid body of the edit's source (:func:`m2d2m.motion.representation.rigid.rigid_shapes`): the result
    put on it, its kept frames have the joints the source had; a body fitted to the result's own
    frames would move them by up to centimetres."""
    return rigid_shapes(features_to_joints(edit.sources[0].features, skeleton), skeleton)


def kept_frames(edit: Edit, result: Motion, body: dict[int, np.ndarray]) -> KeptFrames | None:
    """The frames of ``result`` (the edit applied, on the source's ``body``) that its sources
    delivered, as they delivered them (feet planted, a loop's seam faded), each turned about the
    vertical and moved as the result's frame is from the source's: the foot fix of the result's
    delivery leaves them as they are (:class:`~m2d2m.motion.transforms.feet.KeptFrames`). Why: the fix run
    again over the result re-plants the contact runs that cross a margin and moved kept feet by
    up to 4 cm. None when no source was delivered at the model's rate."""
    skeleton = result.skeleton
    delivered, own = [], []
    for source in edit.sources:
        joints = on_rigid_skeleton(features_to_joints(source.features, skeleton), skeleton, shapes=body)
        own.append(joints)
        if source.joints is None:
            delivered.append(np.full_like(joints, np.nan))
        else:  # placed as its own frame 0 is: the features begin facing +Z at the origin, a delivery need not
            delivered.append(_moved(source.joints[:1], joints[:1], source.joints, skeleton))
    origin = edit.result_origin
    frames = (origin >= 0) & ~np.isnan(np.concatenate(delivered)[np.maximum(origin, 0), 0, 0])
    if not frames.any():
        return None
    kept = np.array(result.joints, dtype=np.float64)
    source_frames = origin[frames]
    kept[frames] = _moved(
        np.concatenate(own)[source_frames], result.joints[frames], np.concatenate(delivered)[source_frames], skeleton
    )
    return KeptFrames(frames, kept.astype(np.float32))


def _moved(was: np.ndarray, now: np.ndarray, poses: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """``poses`` (N, J, 3) moved as each pose ``was`` (N or 1, J, 3) is to ``now``: turned about
    the vertical by the change of its facing (hips and shoulders, which the foot fix leaves) and
    moved with its root."""
    turn = np.arctan2(*facing_direction(now, skeleton)[..., [0, 2]].T) - np.arctan2(
        *facing_direction(was, skeleton)[..., [0, 2]].T
    )
    cos, sin = np.cos(turn)[:, None], np.sin(turn)[:, None]
    offsets = np.asarray(poses, dtype=np.float64) - was[:, :1]
    moved = np.stack(
        [offsets[..., 0] * cos + offsets[..., 2] * sin, offsets[..., 1], offsets[..., 2] * cos - offsets[..., 0] * sin],
        axis=-1,
    )
    return moved + now[:, :1]


def pin_error(features: np.ndarray, pose: np.ndarray, frame: int, skeleton: Skeleton) -> float:
    """How far (metres) the motion ``features`` is from the pose at ``frame``: the largest distance
    between a joint of the two, each placed around its root and facing its heading (the features'
    root-relative positions, HumanML3D's RIC), so a pose pinned from a clip facing elsewhere counts
    only by its shape and height."""
    count = 3 * (skeleton.num_joints - 1)
    ours = features[frame, 4 : 4 + count].reshape(-1, 3)
    theirs = pose[4 : 4 + count].reshape(-1, 3)
    return float(np.linalg.norm(ours - theirs, axis=-1).max() * skeleton.metres_per_unit)
