"""Reading BVH motion capture: the hierarchy, the frames, and world joint positions by forward
kinematics, for any channel and rotation order, in metres.

BVH (Biovision Hierarchy; the format as CMU's cgspeed conversions and Blender write it): a
``HIERARCHY`` of ``ROOT``/``JOINT`` blocks, each with an ``OFFSET`` from its parent and the
``CHANNELS`` it animates, ``End Site`` leaves, then ``MOTION``, ``Frames:``, ``Frame Time:`` and
one line of channel values per frame. A joint's rotation is the product of its rotation channels
in the order listed, ``R = R_c1 · R_c2 · R_c3`` acting on column vectors (what
:func:`m2d2m.motion.files.export.save_bvh` writes, and Blender's importer reads); position channels,
where a joint has them, give its translation from its parent in place of its ``OFFSET``. Angles
are degrees. Every malformed file is a :class:`BvhError` (a ``ValueError``) in one sentence.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m2d2m.motion.representation.rotations import euler_to_matrix, matrix_to_quat, qslerp, quat_to_matrix

POSITIONS = ("Xposition", "Yposition", "Zposition")
ROTATIONS = ("Xrotation", "Yrotation", "Zrotation")


class BvhError(ValueError):
    """A file that is not a readable BVH: what is wrong with it and where, in one sentence."""


@dataclass(frozen=True)
class BvhClip:
    """A BVH file's skeleton and motion, lengths in metres."""

    names: tuple[str, ...]
    parents: np.ndarray  # (J,) each joint's parent, -1 for the root; parents come first
    offsets: np.ndarray  # (J, 3) each joint's rest offset from its parent
    end_sites: dict[int, np.ndarray]  # joint → its End Site's offset, for joints that have one
    channels: tuple[tuple[str, ...], ...]  # each joint's channel names, in file order
    values: np.ndarray  # (T, C) the frames' channel values, in file order (positions in metres)
    frame_time: float  # seconds per frame

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    def joint(self, name: str) -> int:
        """The index of the joint ``name``, or a BvhError naming the joints there are."""
        if name not in self.names:
            raise BvhError(f"no joint {name!r} in the BVH; it has {', '.join(self.names)}")
        return self.names.index(name)

    def rest_positions(self) -> np.ndarray:
        """(J, 3) every joint's position in the rest pose: each rotation zero, each joint at its
        OFFSET from its parent."""
        return rest_positions(self.parents, self.offsets)

    def positions(self, at: np.ndarray | None = None) -> np.ndarray:
        """World positions (T, J, 3) of every joint in every frame, by forward kinematics; or, with
        ``at`` (fractional frame indices), at those instants: each joint's rotation slerped and its
        translation interpolated linearly between the frames around each, so that every bone keeps
        its length (interpolating the joints' positions would shorten a bone that turns)."""
        return self.pose(at)[1]

    def pose(self, at: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Every joint's world rotation (T, J, 3, 3), turning its rest frame into the frame's, and
        world position (T, J, 3), as :meth:`positions` makes them: the rotations carry a point
        fixed to a joint (a toe ahead of a rig's ankle: :mod:`m2d2m.motion.rigs.joint_map`)."""
        frames, count = len(self.values), len(self.names)
        if at is not None:
            at = np.clip(np.asarray(at, dtype=np.float64), 0.0, frames - 1)
            before = np.minimum(np.floor(at).astype(np.int64), max(frames - 2, 0))
            after, weight = np.minimum(before + 1, frames - 1), at - before
        world_rotation = np.empty((frames if at is None else len(at), count, 3, 3))
        world_position = np.empty(world_rotation.shape[:-1])
        column = 0
        for joint, channels in enumerate(self.channels):
            block = self.values[:, column : column + len(channels)]
            column += len(channels)
            translation = np.broadcast_to(self.offsets[joint], (frames, 3)).copy()
            rotation = np.broadcast_to(np.eye(3), (frames, 3, 3))
            axes = "".join(name[0] for name in channels if name in ROTATIONS)
            if axes:
                angles = block[:, [i for i, name in enumerate(channels) if name in ROTATIONS]]
                rotation = euler_to_matrix(np.radians(angles), axes)
            for i, name in enumerate(channels):
                if name in POSITIONS:
                    translation[:, POSITIONS.index(name)] = block[:, i]
            if at is not None:
                quaternions = matrix_to_quat(rotation)
                rotation = quat_to_matrix(qslerp(quaternions[before], quaternions[after], weight))
                translation = translation[before] + weight[:, None] * (translation[after] - translation[before])
            parent = self.parents[joint]
            if parent < 0:
                world_rotation[:, joint], world_position[:, joint] = rotation, translation
            else:
                world_rotation[:, joint] = world_rotation[:, parent] @ rotation
                world_position[:, joint] = world_position[:, parent] + np.einsum(
                    "tij,tj->ti", world_rotation[:, parent], translation
                )
        return world_rotation, world_position


def rest_positions(parents: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(J, 3) the joints of a hierarchy (``parents`` first) where their ``offsets`` put them, each
    rotation zero: a rig's rest pose."""
    rest = np.zeros((len(parents), 3))
    for joint, parent in enumerate(parents):
        rest[joint] = offsets[joint] + (rest[parent] if parent >= 0 else 0.0)
    return rest


def read_bvh(path: str | Path, metres_per_unit: float = 1.0) -> BvhClip:
    """The BVH file at ``path``, its lengths (offsets, position channels) × ``metres_per_unit``:
    1 for a file in metres, 0.056444 for CMU's cgspeed conversions (1/0.45 inch a unit)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as error:
        raise BvhError(f"{path}: cannot be read ({error.strerror})") from error
    head, separator, motion = text.partition("MOTION")
    if not head.lstrip().startswith("HIERARCHY") or not separator:
        raise BvhError(f"{path}: not a BVH file (it must start with HIERARCHY and have a MOTION section)")
    names, parents, offsets, end_sites, channels = _hierarchy(head.split()[1:], path)
    values, frame_time = _frames(motion, sum(len(c) for c in channels), path)
    offsets = _bones_from_positions(np.asarray(offsets, dtype=np.float64), channels, values)
    scale = np.ones(values.shape[1])
    scale[[i for i, name in enumerate(n for c in channels for n in c) if name in POSITIONS]] = metres_per_unit
    return BvhClip(
        tuple(names),
        np.asarray(parents, dtype=np.int64),
        offsets * metres_per_unit,
        {joint: np.asarray(offset) * metres_per_unit for joint, offset in end_sites.items()},
        tuple(tuple(c) for c in channels),
        values * scale,
        frame_time,
    )


def _bones_from_positions(offsets: np.ndarray, channels: list[list[str]], values: np.ndarray) -> np.ndarray:
    """``offsets`` (J, 3), but where a joint below the root has a zero OFFSET and position channels
    (some exporters write every bone as a translation), its first frame's translation: the pose
    reads the channels either way, and the rest pose (joint maps, units, retargeting) then has
    its bones instead of a rig collapsed onto its root."""
    offsets = offsets.copy()
    column = 0
    for joint, names in enumerate(channels):
        if joint > 0 and len(values) and not offsets[joint].any():
            for i, name in enumerate(names):
                if name in POSITIONS:
                    offsets[joint, POSITIONS.index(name)] = values[0, column + i]
        column += len(names)
    return offsets


@dataclass(frozen=True)
class BvhHeader:
    """What a BVH file says before its frames: its hierarchy (joints' names, parents, OFFSETs and
    End Sites, as :class:`BvhClip` holds them, in the file's units), its frame count and frame
    time."""

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    end_sites: dict[int, np.ndarray]
    frames: int
    frame_time: float

    def rest_positions(self) -> np.ndarray:
        """(J, 3) every joint where the rest pose puts it (:func:`rest_positions`)."""
        return rest_positions(self.parents, self.offsets)


def read_bvh_header(path: str | Path) -> BvhHeader:
    """The header of the BVH file at ``path``, read up to its ``Frame Time:`` line only: listing a
    corpus of thousands of takes needs their lengths (and joint maps their hierarchies), not their
    frames."""
    path = Path(path)
    hierarchy: list[str] = []  # the words before MOTION
    frames = frame_time = None
    try:
        with path.open(encoding="utf-8", errors="replace") as handle:
            for line in handle:
                words = line.split()
                if words[:1] == ["Frames:"]:
                    frames = int(words[1])
                elif line.lstrip().startswith("Frame Time:") and frames is not None:
                    frame_time = float(line.split(":")[1])
                    break
                elif frames is None and words[:1] != ["MOTION"]:
                    hierarchy.extend(words)
    except OSError as error:
        raise BvhError(f"{path}: cannot be read ({error.strerror})") from error
    except (IndexError, ValueError) as error:
        raise BvhError(f"{path}: a malformed MOTION section (Frames:, Frame Time:, then the frames)") from error
    if frame_time is None:
        raise BvhError(f"{path}: not a BVH file (no Frames: and Frame Time: lines)")
    if hierarchy[:1] != ["HIERARCHY"]:
        raise BvhError(f"{path}: not a BVH file (it must start with HIERARCHY and have a MOTION section)")
    names, parents, offsets, end_sites, _ = _hierarchy(hierarchy[1:], path)
    return BvhHeader(
        tuple(names),
        np.asarray(parents, dtype=np.int64),
        np.asarray(offsets, dtype=np.float64),
        {joint: np.asarray(offset) for joint, offset in end_sites.items()},
        frames,
        frame_time,
    )


def _hierarchy(tokens: list[str], path: Path):
    """Names, parents, offsets, End Sites and channels of the joints, from the tokens after HIERARCHY."""
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    end_sites: dict[int, list[float]] = {}
    channels: list[list[str]] = []
    stack: list[int] = []  # the open joints; -1 marks an open End Site
    i = 0
    try:
        while i < len(tokens):
            token = tokens[i]
            if token in ("ROOT", "JOINT"):
                if (token == "ROOT") != (not stack):
                    raise BvhError(f"{path}: a {token} at the wrong place in the hierarchy")
                names.append(tokens[i + 1])
                parents.append(stack[-1] if stack else -1)
                offsets.append([0.0, 0.0, 0.0])
                channels.append([])
                stack.append(len(names) - 1)
                i += 2
            elif token == "End":  # "End Site"
                stack.append(-1)
                i += 2
            elif token == "OFFSET":
                offset = [float(v) for v in tokens[i + 1 : i + 4]]
                if stack[-1] < 0:
                    end_sites[stack[-2]] = offset
                else:
                    offsets[stack[-1]] = offset
                i += 4
            elif token == "CHANNELS":
                count = int(tokens[i + 1])
                listed = tokens[i + 2 : i + 2 + count]
                unknown = [name for name in listed if name not in POSITIONS + ROTATIONS]
                if unknown:
                    raise BvhError(f"{path}: unknown channel {unknown[0]!r} of joint {names[stack[-1]]!r}")
                channels[stack[-1]] = listed
                i += 2 + count
            elif token == "{":
                i += 1
            elif token == "}":
                stack.pop()
                i += 1
            else:
                raise BvhError(f"{path}: unexpected {token!r} in the hierarchy")
    except BvhError:
        raise
    except (IndexError, ValueError) as error:  # a block cut short, or a number that is not one
        raise BvhError(f"{path}: a malformed hierarchy near token {i} ({error})") from error
    if not names or stack:
        raise BvhError(f"{path}: the hierarchy has no joints or an unclosed block")
    return names, parents, offsets, end_sites, channels


def _frames(motion: str, width: int, path: Path) -> tuple[np.ndarray, float]:
    """The channel values (T, width) and the frame time of the MOTION section."""
    lines = motion.strip().splitlines()
    try:
        count = int(lines[0].split(":")[1])
        frame_time = float(lines[1].split(":")[1])
        values = np.array([[float(v) for v in line.split()] for line in lines[2 : 2 + count]], dtype=np.float64)
    except (IndexError, ValueError) as error:
        raise BvhError(f"{path}: a malformed MOTION section (Frames:, Frame Time:, then the frames)") from error
    if count < 1:
        raise BvhError(f"{path}: no frames")
    if not (math.isfinite(frame_time) and frame_time > 0):
        raise BvhError(f"{path}: Frame Time must be a positive number of seconds, got {frame_time:g}")
    if values.shape != (count, width):
        raise BvhError(
            f"{path}: {count} frames of {width} channels announced, but {len(values)} lines "
            f"{'of ' + str(values.shape[1]) + ' values ' if values.ndim == 2 else ''}follow"
        )
    if not np.isfinite(values).all():
        raise BvhError(f"{path}: a frame holds NaN or infinite values")
    return values, frame_time


def whole_step(fps: float, target_fps: float) -> int | None:
    """n when ``fps`` is n times ``target_fps`` (a Frame Time printed as .0083333 still is), else None."""
    ratio = fps / target_fps
    return int(round(ratio)) if abs(ratio - round(ratio)) < 1e-3 and round(ratio) >= 1 else None


def instants(frames: int, fps: float, target_fps: float) -> np.ndarray:
    """Where the instants ``k / target_fps`` within a clip of ``frames`` frames at ``fps`` fall,
    in (fractional) frames of the clip, the last one kept when it falls within a thousandth of a
    frame past the end (a Frame Time printed as 0.0333333 makes a 30-fps clip that much short)."""
    ratio = fps / target_fps
    return np.minimum(np.arange(math.floor((frames - 1) / ratio + 1e-3) + 1) * ratio, frames - 1)


def resample(positions: np.ndarray, fps: float, target_fps: float) -> np.ndarray:
    """Positions (T, ...) at ``fps`` taken to ``target_fps``: every n-th frame where ``fps`` is n
    times the target (HumanML3D's rule: ``pose_seq[::down_sample]``, so ceil(T / n) frames),
    else linear interpolation at the target's instants within the clip (a BVH's joints keep
    their bones' lengths when read at those instants instead: :meth:`BvhClip.positions`)."""
    step = whole_step(fps, target_fps)
    if step is not None:
        return positions[::step]
    source = instants(len(positions), fps, target_fps)
    below = np.floor(source).astype(int).clip(0, len(positions) - 1)
    above = np.minimum(below + 1, len(positions) - 1)
    weight = (source - below).reshape(-1, *([1] * (positions.ndim - 1)))
    return (1.0 - weight) * positions[below] + weight * positions[above]
