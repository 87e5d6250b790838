"""A generated motion: features, joints, frame rate and the frames each action occupies, with the
files an animator wants from it (joints ``.npy`` with a JSON sidecar, BVH, GIF or MP4)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from m2d2m.motion.export import save_bvh, save_motion_npy
from m2d2m.motion.render import render_motion
from m2d2m.motion.skeleton import SKELETONS, Skeleton

FORMATS = ("npy", "bvh", "gif", "mp4")


@dataclass
class Motion:
    """``features`` (F, D) HumanML3D features (denormalised), ``joints`` (F, J, 3) global positions,
    ``ranges[i]`` = (first, end) frames of ``actions[i]`` (end exclusive). Frames between two
    ranges belong to no action: a baseline's transition window. ``settings`` records how it was
    made (method, seed, ...)."""

    features: np.ndarray
    joints: np.ndarray
    fps: float
    skeleton_name: str
    actions: list[str]
    ranges: list[tuple[int, int]]
    settings: dict = field(default_factory=dict)
    tokens: np.ndarray | None = None  # the generated motion tokens, in order, when it was generated

    def __post_init__(self) -> None:
        if len(self.actions) != len(self.ranges):
            raise ValueError("need one frame range per action")
        previous_end = 0
        for first, end in self.ranges:
            if not previous_end <= first < end <= len(self.joints):
                raise ValueError(f"action ranges must be ordered, non-empty and within {len(self.joints)} frames; "
                                 f"got {self.ranges}")
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
        return [(first, end, text) for (first, end), text in zip(self.ranges, self.actions)]

    def save(self, directory: str | Path, name: str = "motion", formats: tuple[str, ...] = ("npy", "bvh", "gif"),
             size: int = 480) -> dict[str, Path]:
        """Write ``<name>.<format>`` for each format into ``directory``; returns format → path.
        The GIF/MP4 shows each action's text over its frames."""
        unknown = sorted(set(formats) - set(FORMATS))
        if unknown:
            raise ValueError(f"unknown formats {unknown}: choose from {', '.join(FORMATS)}")
        directory = Path(directory)
        written: dict[str, Path] = {}
        for kind in formats:
            path = directory / f"{name}.{kind}"
            if kind == "npy":
                written[kind] = save_motion_npy(path, self.joints, self.fps, self.skeleton, self.segments)
                np.save(directory / f"{name}.features.npy", self.features.astype(np.float32))
            elif kind == "bvh":
                written[kind] = save_bvh(path, self.joints, self.skeleton, self.fps)
            else:
                written[kind] = render_motion(self.joints, path, self.skeleton, self.fps, self.segments, size=size)
        return written
