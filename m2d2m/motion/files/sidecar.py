"""The JSON sidecar beside an exported ``.npy`` of joints: one type, written and read here, so that
what `m2d2m generate` and `export` write is what `export`, `render` and an edit read back
(docs/generation.md, "Output files"). It states every convention a tool outside M2D2M needs:
joint names and order, units, axes, frame rate, each action's frames, and where an in-place
clip's root motion went."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from m2d2m.atomic import atomic_path
from m2d2m.motion.representation.skeleton import SKELETONS

UNITS = {"t2m": "metre", "kit": "KIT-ML units (about 640 per metre)"}
AXES = {"up": "+Y", "forward": "+Z (facing at frame 0)", "left": "+X"}


class SidecarError(ValueError):
    """A ``.json`` beside a ``.npy`` that is not the sidecar m2d2m writes (one line)."""


def sidecar_path(npy: str | Path) -> Path:
    """Where the sidecar of ``npy`` is: ``motion.json`` for ``motion.npy`` and ``motion.features.npy`` alike."""
    npy = Path(npy)
    return npy.with_name(npy.name.removesuffix(".npy").removesuffix(".features") + ".json")


@dataclass(frozen=True)
class Sidecar:
    """What the sidecar of ``file`` (the joints, float32 (num_frames, J, 3) of ``skeleton``) says:
    its rate, its actions as ``(start, end, text)`` frames (end exclusive), ``quality`` figures of
    how the joints were made, ``root_motion``: the file (T, 3) of the root track an in-place clip
    took out (add it to every joint for the clip's own path), and ``loop``: one cycle of a loop."""

    file: str
    skeleton: str
    fps: float
    num_frames: int
    segments: list[tuple[int, int, str]] = field(default_factory=list)
    quality: dict[str, float] = field(default_factory=dict)
    root_motion: str | None = None
    loop: bool = False

    def write(self, directory: Path) -> Path:
        """Write ``<stem>.json`` beside ``file`` in ``directory``, whole or not at all; its path."""
        path = sidecar_path(directory / self.file)
        with atomic_path(path) as partial:
            partial.write_text(json.dumps(self.as_json(), indent=2, ensure_ascii=False) + "\n", encoding="utf-8")
        return path

    def as_json(self) -> dict:
        """The record as written, the skeleton's conventions spelled out for readers without M2D2M."""
        skeleton = SKELETONS[self.skeleton]
        return {
            "file": self.file,
            "shape": [self.num_frames, skeleton.num_joints, 3],
            "dtype": "float32",
            "skeleton": self.skeleton,
            "joint_names": list(skeleton.joint_names),
            "parents": skeleton.parents.tolist(),
            "units": UNITS.get(self.skeleton, "unknown"),
            "axes": AXES,
            "fps": self.fps,
            "num_frames": self.num_frames,
            "duration_s": self.num_frames / self.fps,
            "segments": [
                {"start_frame": int(s), "end_frame": int(e), "text": str(text)} for s, e, text in self.segments
            ],
            "segments_end": "exclusive",
            **({"quality": dict(self.quality)} if self.quality else {}),
            **({"root_motion": self.root_motion} if self.root_motion is not None else {}),
            **({"loop": True} if self.loop else {}),
        }

    @classmethod
    def read(cls, npy: str | Path) -> Sidecar | None:
        """The sidecar beside ``npy`` (None: a file without one), each field as its readers take it,
        so that a broken one is :class:`SidecarError` here and not a traceback in theirs."""
        path = sidecar_path(npy)
        if not path.is_file():
            return None
        try:
            record = json.loads(path.read_text(encoding="utf-8"))
            return cls(
                file=str(record.get("file", path.with_suffix(".npy").name)),
                skeleton=str(record["skeleton"]),
                fps=float(record["fps"]),
                num_frames=int(record["num_frames"]),
                segments=[(int(s["start_frame"]), int(s["end_frame"]), str(s["text"])) for s in record["segments"]],
                quality=dict(record.get("quality", {})),
                root_motion=None if record.get("root_motion") is None else str(record["root_motion"]),
                loop=bool(record.get("loop", False)),
            )
        except (ValueError, KeyError, TypeError, AttributeError) as error:
            raise SidecarError(
                f"{path}: not the sidecar m2d2m writes beside a .npy ({error}); fix or move it"
            ) from error
