"""A generated motion: features, joints, frame rate and the frames each action occupies, with the
files an animator wants from it (:mod:`m2d2m.motion.files.formats`), delivered as asked
(:mod:`m2d2m.motion.transforms.delivery`)."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from m2d2m.atomic import atomic_path
from m2d2m.layout import relative_to_project
from m2d2m.motion.files.formats import DEFAULT_FORMATS, Writing, formats_named, on_rig, spoken
from m2d2m.motion.representation.pose import REST_POSES
from m2d2m.motion.representation.rigid import bone_length_spread, on_rigid_skeleton
from m2d2m.motion.representation.skeleton import SKELETONS, Skeleton
from m2d2m.motion.transforms.delivery import Delivery, deliver
from m2d2m.motion.transforms.feet import KeptFrames
from m2d2m.motion.transforms.retime import loop_features

if TYPE_CHECKING:
    from m2d2m.motion.rigs.retarget import Target

UNNAMED_ACTION = "transition"  # the name of an action sampled without text (Motion.segments)


@dataclass
class Motion:
    """``features`` (F, D) HumanML3D features (denormalised; (F, 0) for a motion known only by its
    joints), ``joints`` (F, J, 3) global positions,
    ``ranges[i]`` = (first, end) frames of ``actions[i]`` (end exclusive). Frames between two
    ranges belong to no action: a baseline's transition window. ``settings`` records how it was
    made (method, seed, ...), ``quality`` figures of the joints (``bone_length_std_mm_mean`` and
    ``_max``: the spread of bone lengths before :meth:`on_rigid_skeleton`). ``loop``: one cycle
    of a loop, its last frame running on into its first moved by ``loop_travel`` (3,), how far its
    path moves in a cycle (an in-place clip's ``root_track`` carries the path); ``kept_frames``:
    an edit's frames that its delivery's foot fix leaves as they are (its source's, as delivered)."""

    features: np.ndarray
    joints: np.ndarray
    fps: float
    skeleton_name: str
    actions: list[str]
    ranges: list[tuple[int, int]]
    settings: dict = field(default_factory=dict)
    tokens: np.ndarray | None = None  # the generated motion tokens, in order, when it was generated
    quality: dict[str, float] = field(default_factory=dict)
    root_track: np.ndarray | None = None  # (F, 3) the root motion an in-place delivery took out
    loop: bool = False
    kept_frames: KeptFrames | None = None
    loop_travel: np.ndarray | None = None  # (3,) a loop's travel in a cycle; None: not a loop, or not known

    def __post_init__(self) -> None:
        if len(self.actions) != len(self.ranges):
            raise ValueError("need one frame range per action")
        previous_end = 0
        for first, end in self.ranges:
            if not previous_end <= first < end <= len(self.joints):
                raise ValueError(
                    f"action ranges must be ordered, non-empty and within {len(self.joints)} frames; got {self.ranges}"
                )
            previous_end = end

    @property
    def skeleton(self) -> Skeleton:
        return SKELETONS[self.skeleton_name]

    @property
    def seconds(self) -> float:
        return len(self.joints) / self.fps

    @property
    def boundaries(self) -> list[int]:
        """The frame of each transition: where one action ends and the next starts, or the middle
        of the window between them."""
        return [(end + first) // 2 for (_, end), (first, _) in zip(self.ranges[:-1], self.ranges[1:])]

    @property
    def segments(self) -> list[tuple[int, int, str]]:
        """Each action's frames and name, as every file and answer shows them: its text, or
        :data:`UNNAMED_ACTION` for one sampled without text (a gap filled with the model's null
        condition), which would otherwise be a nameless span on the timeline and in the files."""
        return [(first, end, text or UNNAMED_ACTION) for (first, end), text in zip(self.ranges, self.actions)]

    def on_rigid_skeleton(self, shapes: dict[int, np.ndarray] | None = None) -> Motion:
        """This motion with its joints on one rigid skeleton (:mod:`m2d2m.motion.representation.rigid`; ``shapes``:
        another clip's body), so that a BVH of it reproduces the ``.npy`` and the animation; the
        spread of bone lengths it had is kept in ``quality``. The features stay the model's own."""
        spread = bone_length_spread(self.joints, self.skeleton)
        joints = on_rigid_skeleton(self.joints, self.skeleton, shapes=shapes).astype(np.float32)
        return replace(
            self,
            joints=joints,
            quality={
                **self.quality,
                "bone_length_std_mm_mean": spread["mean"],
                "bone_length_std_mm_max": spread["max"],
            },
        )

    def delivered(self, delivery: Delivery, recorded: bool = False) -> Motion:
        """This motion as ``delivery`` asks for it (feet planted, frame rate, loop, root motion:
        :func:`m2d2m.motion.transforms.delivery.deliver`; ``recorded``: captured, not generated, so its feet
        are left as they are unless asked), the delivery recorded in ``settings`` and its figures
        in ``quality``. The features stay the model's own, at its rate, what an edit reads; a
        loop's are the cycle's (:func:`~m2d2m.motion.transforms.retime.loop_features`), so that they and the
        joints hold the same frames. A motion that is one cycle already (an edit of a loop) is
        delivered as the loop it is."""
        done = deliver(
            self.joints,
            self.fps,
            self.skeleton,
            self.ranges,
            delivery,
            self.features,
            recorded,
            self.kept_frames,
            self.loop,
        )
        features = self.features
        if done.loop_span is not None and len(features) == len(self.joints):  # features frame for frame
            features = loop_features(features, tuple(round(f * self.fps / done.fps) for f in done.loop_span))
        loop = self.loop or delivery.loop
        return replace(
            self,
            features=features,
            joints=done.joints,
            fps=done.fps,
            actions=[self.actions[i] for i in done.kept],
            ranges=done.ranges,
            # a rig as run records name files: relative to the project, so a moved project reads alike
            settings={
                **self.settings,
                "delivery": {
                    **asdict(delivery),
                    "loop": loop,
                    "plant_feet": delivery.plants_feet(recorded),
                    "rig": delivery.rig and relative_to_project(delivery.rig),
                },
            },
            quality={**self.quality, **done.quality},
            root_track=done.root_track,
            loop=loop,
            kept_frames=None,
            loop_travel=done.loop_travel,
        )

    def save(
        self,
        directory: str | Path,
        name: str = "motion",
        formats: tuple[str, ...] = DEFAULT_FORMATS,
        size: int = 480,
        progress: Callable[[int], None] | None = None,
        delivery: Delivery = Delivery(),
    ) -> dict[str, Path]:
        """Write ``<name>.<format>`` for each format of :data:`~m2d2m.motion.files.formats.FORMATS` into
        ``directory``, each file whole or not at all; returns format → path. The GIF/MP4 shows each
        action's text over its frames; ``progress(t)`` is called after each frame of an animation is
        drawn. The joints are written as they are (:meth:`delivered` edits them); ``delivery`` says
        the bind pose of the files on our skeleton and the rig the formats written on a rig go on
        (read once for all of them), and an in-place clip's root track goes where a format keeps one."""
        chosen = formats_named(formats)
        target = None
        if delivery.rig is not None and any(fmt.on_rig for fmt in chosen):
            from m2d2m.motion.rigs.retarget import read_target

            target = read_target(
                delivery.rig, delivery.joint_map, skeleton=self.skeleton, rest_frame=delivery.rest_frame
            )
        directory = Path(directory)
        writing = Writing(delivery.rest_pose, size=size, progress=progress)
        return {
            fmt.suffix: fmt.write(
                self, directory / f"{name}.{fmt.suffix}", replace(writing, target=target if fmt.on_rig else None)
            )
            for fmt in chosen
        }

    def save_on_rig(self, path: Path, kind: str, target: Target) -> Path:
        """The file of format ``kind`` (one written on a rig) of this motion on ``target``'s rig, at ``path``."""
        (fmt,) = formats_named([kind])
        if not fmt.on_rig:
            raise ValueError(f"a rig goes with the {spoken(on_rig())}, not {kind}")
        return fmt.write(self, path, Writing(REST_POSES[0], target))  # a rig's bind pose is its own

    def keyed(self) -> tuple[np.ndarray, np.ndarray | None, bool]:
        """The joints and root track a GLB and an FBX key, and whether they end on a closing key:
        a loop's end with its first frame again, moved on by a cycle's travel (an in-place clip's
        root track travels, its joints stay), so that an engine looping the animation plays the
        seam over one frame step like any other, not in no time from the last key to the first."""
        if self.loop_travel is None:
            return self.joints, self.root_track, False
        travel = np.asarray(self.loop_travel, dtype=self.joints.dtype)
        if self.root_track is None:
            return np.concatenate([self.joints, self.joints[:1] + travel]), None, True
        track = np.concatenate([self.root_track, self.root_track[:1] + travel])
        return np.concatenate([self.joints, self.joints[:1]]), track, True


def save_motions(path: str | Path, motions: Sequence[Motion]) -> Path:
    """Several motions in one ``.npz`` (arrays, and their texts and settings as JSON), written
    whole or not at all and read back by :func:`load_motions` without unpickling anything."""
    arrays: dict[str, np.ndarray] = {}
    described = []
    for index, motion in enumerate(motions):
        arrays[f"features{index}"] = motion.features
        arrays[f"joints{index}"] = motion.joints
        if motion.tokens is not None:
            arrays[f"tokens{index}"] = np.asarray(motion.tokens)
        if motion.root_track is not None:
            arrays[f"root_track{index}"] = motion.root_track
        if motion.loop_travel is not None:
            arrays[f"loop_travel{index}"] = motion.loop_travel
        described.append(
            {
                "fps": motion.fps,
                "skeleton": motion.skeleton_name,
                "actions": motion.actions,
                "ranges": [list(r) for r in motion.ranges],
                "settings": motion.settings,
                "quality": motion.quality,
                "loop": motion.loop,
            }
        )
    arrays["described"] = np.array(json.dumps(described, default=str))
    with atomic_path(Path(path)) as partial, partial.open("wb") as file:
        np.savez(file, **arrays)
    return Path(path)


def load_motions(path: str | Path) -> list[Motion]:
    """The motions :func:`save_motions` wrote."""
    with np.load(path, allow_pickle=False) as stored:
        return [
            Motion(
                stored[f"features{index}"],
                stored[f"joints{index}"],
                info["fps"],
                info["skeleton"],
                info["actions"],
                [tuple(r) for r in info["ranges"]],
                info["settings"],
                stored[f"tokens{index}"] if f"tokens{index}" in stored else None,
                info["quality"],
                stored[f"root_track{index}"] if f"root_track{index}" in stored else None,
                loop=info.get("loop", False),
                loop_travel=stored[f"loop_travel{index}"] if f"loop_travel{index}" in stored else None,
            )
            for index, info in enumerate(json.loads(str(stored["described"])))
        ]
