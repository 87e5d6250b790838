"""The files a motion is written as: one table, suffix → :class:`Format` (its writer, what it can
carry, what this machine needs to write it), read by everything that lists, checks or writes a
format: :meth:`Motion.save <m2d2m.motion.clip.Motion.save>`, the command line's choices, help and
checks, the web app's files and the notes on what was written. A new format is a writer and one
entry in :data:`FORMATS` (as Pillow's ``register_save`` and trimesh's exporter table do).

Every format states its frame rate (BVH's Frame Time, glTF's key times, the sidecar's ``fps``, the
animations' frame durations). Each writer imports its library where it writes: a machine that
only trains (bench/gpu.py's GPU box) has no pygltflib or Matplotlib, and reading this table (as
the command line does to list its choices, before it imports anything else) needs not even NumPy.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from m2d2m.motion.clip import Motion
    from m2d2m.motion.rigs.retarget import Target


@dataclass(frozen=True)
class Writing:
    """What a writer is told beside the motion and the path: the bind pose of a file on our
    skeleton (``rest_pose``, one of :data:`~m2d2m.motion.representation.pose.REST_POSES`), the rig ``target`` to
    write on (read once for every format written on it; None: our skeleton), and an animation's
    frame ``size`` and ``progress(t)`` per frame drawn."""

    rest_pose: str
    target: Target | None = None
    size: int = 480
    progress: Callable[[int], None] | None = None


Writer = Callable[["Motion", Path, Writing], Path]
DEFAULT_FORMATS = ("npy", "bvh", "gif")  # what a generation writes unless asked for others


@dataclass(frozen=True)
class Format:
    """One kind of file (docs/generation.md, "Output formats", says what each is). ``title``: its
    name in sentences; ``write(motion, path, writing)``: the writer, returning the path written. What it can carry:
    ``on_rig``: written on a user's rig when one is given (the rest keep our skeleton);
    ``root_motion``: where it keeps an in-place clip's root track (None: it has no place for it;
    none on a rig, whose root is the rig's own); ``actions``: each action's text and frames;
    ``loop``: one cycle of a loop, said or closed by a key on the first frame again.
    ``animation``: drawn frame by frame (`m2d2m render`'s rather than `export`'s); ``slow``: seconds
    to write (drawing every frame, or starting Blender), so the web app writes it when first asked;
    ``companions``: the files it writes beside it, a key (the web app's) → their suffix;
    ``needs()``: what this machine lacks to write it, in a sentence or None (:meth:`lacking`)."""

    suffix: str
    title: str
    write: Writer
    on_rig: bool = False
    root_motion: str | None = None
    actions: bool = False
    loop: bool = False
    animation: bool = False
    slow: bool = False
    companions: Mapping[str, str] = field(default_factory=dict)
    needs: Callable[[], str | None] | None = None

    def lacking(self) -> str | None:
        """What this machine lacks to write this format, in a sentence (None: nothing): checked before any work."""
        return None if self.needs is None else self.needs()

    def file_names(self, stem: str) -> tuple[str, ...]:
        """Every file a write of this format under ``stem`` may make (a ``.npy`` its sidecar,
        features and root track, when it has them)."""
        return (f"{stem}.{self.suffix}", *(f"{stem}.{suffix}" for suffix in self.companions.values()))


def _write_npy(motion: Motion, path: Path, writing: Writing) -> Path:
    """The joints, their sidecar, an in-place clip's root track and the model's features (none for
    a motion known only by its joints, as `m2d2m export` reads one)."""
    import numpy as np

    from m2d2m.atomic import atomic_path
    from m2d2m.motion.files.export import save_motion_npy

    npy = save_motion_npy(
        path,
        motion.joints,
        motion.fps,
        motion.skeleton,
        motion.segments,
        motion.quality,
        motion.root_track,
        motion.loop,
    )
    if motion.features.size:
        with atomic_path(npy.with_suffix(".features.npy")) as partial:
            np.save(partial, motion.features.astype(np.float32))
    return npy


def _write_bvh(motion: Motion, path: Path, writing: Writing) -> Path:
    if writing.target is not None:
        return writing.target.write_bvh(path, motion.joints, motion.fps, motion.skeleton)
    from m2d2m.motion.files.export import save_bvh

    return save_bvh(path, motion.joints, motion.skeleton, motion.fps, rest_pose=writing.rest_pose)


def _write_glb(motion: Motion, path: Path, writing: Writing) -> Path:
    """Our GLB keeps an in-place clip's root track as its own animation over the clip's path."""
    joints, track, closing = motion.keyed()
    if writing.target is not None:
        from m2d2m.motion.rigs.gltf_export import save_rig_glb

        return save_rig_glb(
            path, writing.target, joints, motion.fps, motion.segments, motion.skeleton, closing_key=closing
        )
    from m2d2m.motion.files.gltf import save_glb

    rest_pose = writing.rest_pose
    if track is None:
        return save_glb(path, joints, motion.skeleton, motion.fps, motion.segments, rest_pose, closing_key=closing)
    path_kept = joints + track[:, None]
    return save_glb(
        path, path_kept, motion.skeleton, motion.fps, motion.segments, rest_pose, joints[:, 0], closing_key=closing
    )


def _write_fbx(motion: Motion, path: Path, writing: Writing) -> Path:
    joints, _, closing = motion.keyed()
    if writing.target is not None:
        from m2d2m.motion.rigs.gltf_export import save_rig_fbx

        return save_rig_fbx(
            path, writing.target, joints, motion.fps, motion.segments, motion.skeleton, closing_key=closing
        )
    from m2d2m.motion.files.gltf import save_fbx

    return save_fbx(path, joints, motion.skeleton, motion.fps, motion.segments, writing.rest_pose, closing_key=closing)


def _draw(motion: Motion, path: Path, writing: Writing) -> Path:
    """A stick-figure animation, each action's text over its frames (GIF or MP4 by the suffix)."""
    from m2d2m.motion.files.render import render_motion

    return render_motion(
        motion.joints,
        path,
        motion.skeleton,
        motion.fps,
        motion.segments,
        size=writing.size,
        progress=writing.progress,
    )


def _blender_missing() -> str | None:
    from m2d2m.motion.files.blender import find_blender

    try:
        find_blender()
    except FileNotFoundError as error:
        return str(error)
    return None


def _ffmpeg_missing() -> str | None:
    from m2d2m.motion.files.render import can_write_mp4

    if can_write_mp4():
        return None
    return (
        "mp4 needs ffmpeg, and none is here (on PATH or from imageio-ffmpeg): pip install imageio-ffmpeg, or choose gif"
    )


FORMATS: dict[str, Format] = {
    fmt.suffix: fmt
    for fmt in (
        Format(
            "npy",
            "NPY",
            _write_npy,
            root_motion="root_motion.npy beside the npy",
            actions=True,
            loop=True,
            companions={"json": "json", "features": "features.npy", "root_motion": "root_motion.npy"},
        ),
        Format("bvh", "BVH", _write_bvh, on_rig=True),
        Format(
            "glb",
            "GLB",
            _write_glb,
            on_rig=True,
            root_motion="the GLB's 'root motion' animation",
            actions=True,
            loop=True,
        ),
        Format(
            "fbx",
            "FBX",
            _write_fbx,
            on_rig=True,
            actions=True,
            loop=True,
            slow=True,
            needs=_blender_missing,
        ),
        Format(
            "gif",
            "GIF",
            _draw,
            actions=True,
            animation=True,
            slow=True,
        ),
        Format(
            "mp4",
            "MP4",
            _draw,
            actions=True,
            animation=True,
            slow=True,
            needs=_ffmpeg_missing,
        ),
    )
}


def formats_named(names: Iterable[str]) -> list[Format]:
    """The formats of ``names`` in order; ValueError in one line naming the unknown ones and the choices."""
    names = list(names)
    unknown = [name for name in names if name not in FORMATS]
    if unknown:
        raise ValueError(
            f"unknown format{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}: choose from {', '.join(FORMATS)}"
        )
    return [FORMATS[name] for name in names]


def suffixes(formats: Iterable[Format]) -> str:
    """``.npy, .bvh, ...``: the formats as a person types them."""
    return ", ".join(f".{fmt.suffix}" for fmt in formats)


def spoken(items: Iterable[Format | str], last: str = "or") -> str:
    """``BVH, GLB or FBX``: formats (by their titles), or any words, in a sentence."""
    words = [item.title if isinstance(item, Format) else item for item in items]
    return words[0] if len(words) == 1 else f"{', '.join(words[:-1])} {last} {words[-1]}"


def on_rig() -> list[Format]:
    """The formats written on a user's rig (docs/generation.md, "On your own rig")."""
    return [fmt for fmt in FORMATS.values() if fmt.on_rig]


def animations() -> list[Format]:
    """The drawn formats: `m2d2m render`'s."""
    return [fmt for fmt in FORMATS.values() if fmt.animation]


def exported() -> list[Format]:
    """What `m2d2m export` writes: every format that is not drawn."""
    return [fmt for fmt in FORMATS.values() if not fmt.animation]
