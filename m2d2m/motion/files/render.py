"""Stick-figure pictures of joint positions: animations (GIF, MP4) and PNG contact sheets.

Speed comes from never touching matplotlib's 3D machinery: a fixed-orientation perspective
camera that follows the smoothed root is computed with NumPy, and each frame only updates the
2D segments of a few ``LineCollection``s on one Agg canvas. The view is fitted to the data
(any units: metres for T2M, KIT's ~640 per metre), the ground is a grid on y = 0 around the
figure, and ``segments`` — ``(start, end, text)`` with ``end`` exclusive — caption and colour
each action of a multi-action clip; frames outside every segment are drawn as transitions.
"""

from __future__ import annotations

import itertools
import shutil
import subprocess
import textwrap
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Polygon
from PIL import GifImagePlugin, Image

from m2d2m.atomic import atomic_path
from m2d2m.motion.representation.skeleton import T2M, Skeleton
from m2d2m.motion.representation.smoothing import gaussian_smooth

Segment = tuple[int, int, str]

_DPI = 100.0
# Fixed camera: 30° to the character's left of its initial facing (+Z), 20° above the ground.
_AZIMUTH, _ELEVATION = np.radians(30.0), np.radians(20.0)
_DISTANCE = 5.0  # camera distance, in figure heights: mild perspective
_GROUND_HALF = 1.5  # half-size of the ground square around the figure, in figure heights
_FOLLOW_SIGMA_S = 0.5  # the camera follows the root smoothed over this many seconds

# Without segments: the usual left = blue, right = red, spine = dark grey.
_PLAIN_COLOURS = np.array([[0.13, 0.40, 0.75], [0.82, 0.21, 0.17], [0.20, 0.20, 0.20]])
# With segments each action gets a hue; left and right are its dark and light shades.
_SEGMENT_HUES = np.array(
    [
        [0.12, 0.47, 0.71],
        [1.00, 0.50, 0.05],
        [0.17, 0.63, 0.17],
        [0.58, 0.40, 0.74],
        [0.55, 0.34, 0.29],
        [0.89, 0.47, 0.76],
        [0.09, 0.75, 0.81],
        [0.74, 0.74, 0.13],
    ]
)
_TRANSITION_HUE = np.array([0.42, 0.42, 0.42])


def render_motion(
    joints: np.ndarray,
    path: str | Path,
    skeleton: Skeleton = T2M,
    fps: float | None = None,
    segments: Sequence[Segment] | None = None,
    title: str | None = None,
    size: int = 480,
    progress: Callable[[int], None] | None = None,
) -> Path:
    """Write an animation of ``joints`` (T, J, 3) to ``path``; ``.gif`` or ``.mp4`` by suffix.

    MP4 needs an ``ffmpeg`` binary (on PATH, or the one bundled with ``imageio-ffmpeg``); without
    one a ``RuntimeError`` is raised before anything is written. ``progress(t)`` is called after
    frame ``t`` is drawn. Frames are encoded as they are drawn, so memory does not grow with the
    clip's length, and the file appears under its name only when complete.
    """
    joints = skeleton.check_joints(joints)
    fps = float(skeleton.fps if fps is None else fps)
    size = int(size) + int(size) % 2  # H.264 wants even sizes
    fig = Figure(figsize=(size / _DPI, size / _DPI), dpi=_DPI)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    panel = _Panel(
        ax, _View(joints, skeleton, fps), _Timeline(segments, len(joints)), size, title=title, with_legend=True
    )
    return _animate(fig, [panel], len(joints), path, fps, progress)


def render_comparison(
    motions: Sequence[np.ndarray],
    labels: Sequence[str],
    path: str | Path,
    skeleton: Skeleton = T2M,
    fps: float | None = None,
    size: int = 360,
) -> Path:
    """Several motions side by side, played in sync, one labelled panel each — e.g. ground truth
    beside a reconstruction. All panels share the first motion's camera, so a drifting root shows
    as drift. A shorter motion holds its last frame."""
    if len(motions) != len(labels) or not motions:
        raise ValueError("give one label per motion, and at least one motion")
    checked = [skeleton.check_joints(m) for m in motions]
    fps = float(skeleton.fps if fps is None else fps)
    size = int(size) + int(size) % 2
    n_frames = max(len(m) for m in checked)
    fig = Figure(figsize=(len(checked) * size / _DPI, size / _DPI), dpi=_DPI)
    panels: list[_Panel] = []
    for n, (joints, label) in enumerate(zip(checked, labels)):
        ax = fig.add_axes((n / len(checked), 0.0, 1.0 / len(checked), 1.0))
        held = np.concatenate([joints, np.repeat(joints[-1:], n_frames - len(joints), axis=0)])
        view = _View(held, skeleton, fps, follow=panels[0].view.target if panels else None)
        panels.append(_Panel(ax, view, _Timeline(None, n_frames), size, title=label, with_legend=n == 0))
    return _animate(fig, panels, n_frames, path, fps)


def _animate(
    fig: Figure,
    panels: Sequence[_Panel],
    n_frames: int,
    path: str | Path,
    fps: float,
    progress: Callable[[int], None] | None = None,
) -> Path:
    """Draw every frame of the panels and encode them as GIF or MP4 (by the path's suffix)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise ValueError(f"unknown animation format {path.suffix!r}: use .gif or .mp4")
    ffmpeg = _find_ffmpeg() if suffix == ".mp4" else None
    if suffix == ".mp4" and ffmpeg is None:
        raise RuntimeError("cannot write .mp4: no ffmpeg found; pip install imageio-ffmpeg or use .gif")
    canvas = FigureCanvasAgg(fig)

    def frames() -> Iterator[np.ndarray]:
        for t in range(n_frames):
            for panel in panels:
                panel.draw(t)
            with warnings.catch_warnings():
                # a caption in a script the font lacks (CJK, emoji) draws as boxes: once per glyph and
                # frame Matplotlib would say so on stderr, burying the command's one-line summary
                warnings.filterwarnings("ignore", message="Glyph .* missing from font", category=UserWarning)
                canvas.draw()
            yield np.asarray(canvas.buffer_rgba())[..., :3]
            if progress is not None:
                progress(t)

    with atomic_path(path) as partial:
        if ffmpeg is None:
            _write_gif(frames(), partial, fps)
        else:
            _write_mp4(frames(), partial, fps, ffmpeg)
    return path


def render_frames(
    joints: np.ndarray,
    path: str | Path,
    frames: Sequence[int] | None = None,
    skeleton: Skeleton = T2M,
    fps: float | None = None,
    segments: Sequence[Segment] | None = None,
    title: str | None = None,
    size: int = 320,
    columns: int = 4,
) -> Path:
    """Write a PNG contact sheet of the chosen ``frames`` (default: 8 evenly spaced), one
    ``size``-pixel tile per frame, for docs, tests and experiment tracking."""
    joints = skeleton.check_joints(joints)
    n_frames = len(joints)
    if frames is None:
        frames = np.linspace(0, n_frames - 1, min(8, n_frames)).round().astype(int)
    frames = [int(f) for f in frames]
    if not frames or min(frames) < 0 or max(frames) >= n_frames:
        raise ValueError(f"frames must be a non-empty list of indices in [0, {n_frames})")
    fps = float(skeleton.fps if fps is None else fps)
    view = _View(joints, skeleton, fps)
    timeline = _Timeline(segments, n_frames)

    columns = max(1, min(columns, len(frames)))
    rows = -(-len(frames) // columns)
    title_px = size // 6 if title else 0
    width, height = columns * size, rows * size + title_px
    fig = Figure(figsize=(width / _DPI, height / _DPI), dpi=_DPI, facecolor="white")
    canvas = FigureCanvasAgg(fig)
    for n, t in enumerate(frames):
        row, col = divmod(n, columns)
        bottom = (rows - 1 - row) * size / height
        ax = fig.add_axes((col / columns, bottom, 1.0 / columns, size / height))
        _Panel(ax, view, timeline, size, title=None, with_legend=n == 0).draw(t)
    if title:
        fig.text(
            0.5,
            1.0 - 0.5 * title_px / height,
            title,
            ha="center",
            va="center",
            fontsize=_points(size, 12, smallest=10),
            weight="bold",
        )
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    canvas.print_png(path)
    return path


def _points(size: int, points_at_480: float, smallest: float = 0.0) -> float:
    """Size in points that keeps the same proportion to the picture at every ``size``
    (``smallest`` keeps text readable on small tiles)."""
    return max(points_at_480 * size / 480.0, smallest)


def _nice_step(x: float) -> float:
    """The 1-2-5 number nearest below ``x``: readable grid spacing in any units."""
    magnitude = 10.0 ** np.floor(np.log10(x))
    return float(magnitude * max(s for s in (1.0, 2.0, 5.0) if s * magnitude <= x))


class _View:
    """Camera and scene geometry of one clip: a perspective camera with fixed orientation that
    looks at the smoothed root, and axis limits that contain the figure in every frame."""

    def __init__(self, joints: np.ndarray, skeleton: Skeleton, fps: float, follow: np.ndarray | None = None) -> None:
        """``follow`` (T, 3) overrides the point the camera tracks, so that several panels can
        share one camera and show where their motions part ways."""
        self.joints = joints
        self.skeleton = skeleton
        self.fps = fps
        extent = np.ptp(joints, axis=1).max()
        self.height = float(extent) if extent > 0 else 1.0
        self.distance = _DISTANCE * self.height
        self.ground_half = _GROUND_HALF * self.height
        self.grid_step = _nice_step(self.height / 3.0)

        back = np.array(
            [np.sin(_AZIMUTH) * np.cos(_ELEVATION), np.sin(_ELEVATION), np.cos(_AZIMUTH) * np.cos(_ELEVATION)]
        )
        right = np.cross([0.0, 1.0, 0.0], back)
        right /= np.linalg.norm(right)
        self.basis = np.stack([right, np.cross(back, right), back])  # rows: screen x, y, depth

        if follow is None:
            centre_y = 0.5 * (min(joints[..., 1].min(), 0.0) + joints[..., 1].max())
            root = gaussian_smooth(joints[:, 0, [0, 2]], _FOLLOW_SIGMA_S * fps, truncate=3.0)
            follow = np.stack([root[:, 0], np.full(len(joints), centre_y), root[:, 1]], 1)
        self.target = follow

        screen = self.project(joints, np.arange(len(joints))[:, None])
        self.bounds = np.concatenate([screen.min(axis=(0, 1)), screen.max(axis=(0, 1))])

    def project(self, points: np.ndarray, t: np.ndarray | int) -> np.ndarray:
        """Screen coordinates (..., 2), in data units at the target's depth, of world points
        (..., 3) seen by the camera of frame(s) ``t`` (broadcast against the points' leading
        axes)."""
        cam = (points - self.target[t]) @ self.basis.T
        depth = np.maximum(self.distance - cam[..., 2], 0.1 * self.distance)
        return cam[..., :2] * (self.distance / depth)[..., None]

    def ground_lines(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """World-space outline (4, 3) and grid lines (N, 2, 3) of the ground square of frame ``t``;
        the lines stay at fixed world positions so the grid scrolls as the figure travels."""
        cx, cz = self.target[t, 0], self.target[t, 2]
        h, step = self.ground_half, self.grid_step
        lo_x, hi_x, lo_z, hi_z = cx - h, cx + h, cz - h, cz + h
        xs = np.arange(np.ceil(lo_x / step), np.floor(hi_x / step) + 1) * step
        zs = np.arange(np.ceil(lo_z / step), np.floor(hi_z / step) + 1) * step
        along_z = [[(x, 0.0, lo_z), (x, 0.0, hi_z)] for x in xs]
        along_x = [[(lo_x, 0.0, z), (hi_x, 0.0, z)] for z in zs]
        outline = np.array([(lo_x, 0.0, lo_z), (hi_x, 0.0, lo_z), (hi_x, 0.0, hi_z), (lo_x, 0.0, hi_z)])
        return outline, np.array(along_z + along_x).reshape(-1, 2, 3)


class _Timeline:
    """Per-frame colour and caption of a clip split into ``(start, end, text)`` segments."""

    def __init__(self, segments: Sequence[Segment] | None, n_frames: int) -> None:
        self.segments = list(segments or [])
        for start, end, _ in self.segments:
            if not 0 <= start < end:
                raise ValueError(f"segment ({start}, {end}) must satisfy 0 <= start < end")
        member = np.zeros((n_frames, len(self.segments)), dtype=bool)
        for n, (start, end, _) in enumerate(self.segments):
            member[start:end, n] = True
        self.member = member
        hues = _SEGMENT_HUES[np.arange(len(self.segments)) % len(_SEGMENT_HUES)]
        count = member.sum(axis=1, keepdims=True)
        blended = (member @ hues) / np.maximum(count, 1)  # overlapping segments blend
        self.hue = np.where(count > 0, blended, _TRANSITION_HUE)

    def colours(self, t: int) -> np.ndarray:
        """Left, right and centre bone colours (3, 3) of frame ``t``."""
        if not self.segments:
            return _PLAIN_COLOURS
        hue = self.hue[t]
        return np.stack([0.6 * hue, hue + 0.45 * (1.0 - hue), 0.15 + 0.35 * hue])

    def caption(self, t: int) -> str | None:
        """The text of the segment(s) playing at frame ``t``, or a transition marker."""
        if not self.segments:
            return None
        playing = np.flatnonzero(self.member[t])
        if len(playing) == 0:
            return "(transition)"
        total = len(self.segments)
        return " → ".join(f"{n + 1}/{total}: {self.segments[n][2]}" for n in playing)


class _Panel:
    """The artists of one picture (ground, trajectory, shadow, skeleton, texts) on one Axes."""

    def __init__(
        self,
        ax: Axes,
        view: _View,
        timeline: _Timeline,
        size: int,
        title: str | None,
        with_legend: bool,
    ) -> None:
        self.view, self.timeline = view, timeline
        skeleton = view.skeleton
        self.bones = skeleton.bones
        self.bone_parents = skeleton.parents[self.bones]
        side = np.full(skeleton.num_joints, 2)
        side[list(skeleton.left_joints)] = 0
        side[list(skeleton.right_joints)] = 1
        self.bone_side = side[self.bones]
        self.root_path = view.joints[:, 0] * [1.0, 0.0, 1.0]
        self.head = skeleton.head_joint
        caption_points = _points(size, 11, smallest=7)
        self.wrap = max(16, int(size * 0.92 / (caption_points * _DPI / 72 * 0.5)))
        lw = _points(size, 3.2)

        title_points = _points(size, 13, smallest=8)
        if title:  # long captions wrap instead of running off the picture
            title = textwrap.fill(title, max(16, int(size * 0.92 / (title_points * _DPI / 72 * 0.58))))
        title_lines = title.count("\n") + 1 if title else 0
        ax.set_axis_off()
        top = 0.14 + 0.06 * title_lines if (title or timeline.segments) else 0.06
        pixels_per_unit = self._fit_limits(ax, top=top, bottom=0.08)
        self.ground = Polygon(
            np.zeros((4, 2)), closed=True, facecolor="#eef0f2", edgecolor="#b8bec6", lw=lw / 3, zorder=0
        )
        ax.add_patch(self.ground)
        self.grid = LineCollection([], colors="#cfd4da", linewidths=lw / 4, zorder=1)
        self.path = LineCollection([], linewidths=lw * 0.6, capstyle="round", zorder=2)
        self.shadow = LineCollection([], colors=[(0, 0, 0, 0.15)], linewidths=lw, capstyle="round", zorder=3)
        self.body = LineCollection([], linewidths=lw, capstyle="round", zorder=4)
        for artist in (self.grid, self.path, self.shadow, self.body):
            ax.add_collection(artist)
        head_points = view.height / 9.0 * pixels_per_unit * 72.0 / _DPI
        (self.head_dot,) = ax.plot([], [], "o", ms=head_points, zorder=5)

        small = _points(size, 8, smallest=6)
        self.clock = ax.text(0.03, 0.03, "", transform=ax.transAxes, fontsize=small, color="#555")
        self.legend = (
            [
                ax.text(
                    0.97, 0.03 + 0.045 * k, label, transform=ax.transAxes, ha="right", fontsize=small, weight="bold"
                )
                for k, label in enumerate(("left", "right"))
            ]
            if with_legend
            else []
        )
        y_caption = 0.97
        if title:
            ax.text(
                0.5,
                0.975,
                title,
                transform=ax.transAxes,
                ha="center",
                va="top",
                fontsize=title_points,
                weight="bold",
                linespacing=1.15,
            )
            y_caption = 0.975 - 0.07 * title_lines
        self.caption = ax.text(
            0.5,
            y_caption,
            "",
            transform=ax.transAxes,
            ha="center",
            va="top",
            fontsize=caption_points,
            linespacing=1.2,
            bbox={"boxstyle": "round,pad=0.35", "facecolor": "white", "edgecolor": "none"},
        )

    def _fit_limits(self, ax: Axes, top: float, bottom: float) -> float:
        """Set equal-aspect limits that put the figure's screen bounds between the caption band
        at the top and the clock at the bottom, whatever the data's units; return pixels per
        data unit."""
        x0, y0, x1, y1 = self.view.bounds
        pos = ax.get_position()
        aspect = (pos.height * ax.figure.get_figheight()) / (pos.width * ax.figure.get_figwidth())
        side = 0.06
        scale = max((x1 - x0) / (1 - 2 * side), (y1 - y0) / ((1 - top - bottom) * aspect))
        width, height = scale, scale * aspect  # data units spanned by the axes
        cx = 0.5 * (x0 + x1)
        ylo = y0 - bottom * height - 0.5 * ((1 - top - bottom) * height - (y1 - y0))
        ax.set_xlim(cx - 0.5 * width, cx + 0.5 * width)
        ax.set_ylim(ylo, ylo + height)
        return pos.width * ax.figure.get_figwidth() * _DPI / width

    def draw(self, t: int) -> None:
        """Move every artist to frame ``t``."""
        view = self.view
        outline, grid = view.ground_lines(t)
        self.ground.set_xy(view.project(outline, t))
        self.grid.set_segments(view.project(grid, t))

        colours = self.timeline.colours(t)
        n_frames = len(self.root_path)
        hue = self.timeline.hue if self.timeline.segments else np.tile(colours[0], (n_frames, 1))
        path = view.project(self.root_path, t)
        from_target = self.root_path[:, [0, 2]] - view.target[t, [0, 2]]
        near = np.abs(from_target).max(axis=1) <= view.ground_half  # on the visible ground
        keep = np.flatnonzero(near[:-1] & near[1:])
        alpha = np.where(keep < t, 0.9, 0.25)
        self.path.set_segments(np.stack([path[keep], path[keep + 1]], axis=1))
        self.path.set_color(np.column_stack([hue[keep], alpha]))

        pose = view.joints[t]
        self.shadow.set_segments(self._bone_segments(view.project(pose * [1.0, 0.0, 1.0], t)))
        screen = view.project(pose, t)
        depth = (pose - view.target[t]) @ view.basis[2]
        order = np.argsort(depth[self.bones] + depth[self.bone_parents])  # far bones first
        self.body.set_segments(self._bone_segments(screen)[order])
        self.body.set_color(colours[self.bone_side[order]])
        self.head_dot.set_data(screen[self.head : self.head + 1].T)
        self.head_dot.set_color(colours[2])

        self.clock.set_text(f"{t / view.fps:5.2f} s   frame {t + 1}/{n_frames}")
        for text, colour in zip(self.legend, colours[:2]):
            text.set_color(colour)
        caption = self.timeline.caption(t)
        if caption is not None:
            self.caption.set_text(textwrap.fill(caption, self.wrap))
            pastel = 0.75 + 0.25 * self.timeline.hue[t]
            self.caption.get_bbox_patch().set_facecolor((*pastel, 0.9))

    def _bone_segments(self, screen: np.ndarray) -> np.ndarray:
        return np.stack([screen[self.bone_parents], screen[self.bones]], axis=1)


def can_write_mp4() -> bool:
    """Whether an MP4 can be written here, for callers that check before they start work."""
    return _find_ffmpeg() is not None


def _find_ffmpeg() -> str | None:
    """An ffmpeg executable: the one on PATH, else imageio-ffmpeg's bundled binary."""
    found = shutil.which("ffmpeg")
    if found:
        return found
    try:
        import imageio_ffmpeg
    except ImportError:
        return None
    return imageio_ffmpeg.get_ffmpeg_exe()


def _write_gif(frames: Iterator[np.ndarray], path: Path, fps: float) -> None:
    """Animated GIF written one frame at a time, each with an adaptive 256-colour palette.

    Pillow's ``save(save_all=True)`` keeps every frame until the end (it compares neighbours),
    which took 2.1 GB for a long clip; its frame-level writers (``GifImagePlugin.getheader`` and
    ``getdata``, Pillow's documented GIF utilities) let each frame go once it is written.
    """
    duration = 1000.0 / fps
    with path.open("wb") as f:
        for n, rgb in enumerate(frames):
            image = Image.fromarray(rgb).quantize(256, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE)
            if n == 0:  # the first frame's palette is the global one; the header also loops forever
                header, _ = GifImagePlugin.getheader(image, info={"loop": 0, "duration": duration})
                f.writelines(header)
            f.writelines(GifImagePlugin.getdata(image, duration=duration, include_color_table=n > 0))
        f.write(b";")  # the GIF trailer


def _write_mp4(frames: Iterator[np.ndarray], path: Path, fps: float, ffmpeg: str) -> None:
    """H.264 MP4 by piping raw RGB frames to ffmpeg (into a temporary file: :func:`_animate`)."""
    frames = iter(frames)
    first = next(frames)
    height, width = first.shape[:2]
    frames = itertools.chain([first], frames)
    command = [
        ffmpeg,
        "-y",
        "-loglevel",
        "error",
        "-f",
        "rawvideo",
        "-pix_fmt",
        "rgb24",
        "-s",
        f"{width}x{height}",
        "-r",
        f"{fps:g}",
        "-i",
        "-",
        "-c:v",
        "libx264",
        "-pix_fmt",
        "yuv420p",
        "-f",
        "mp4",
        str(path),
    ]
    process = subprocess.Popen(command, stdin=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        for rgb in frames:
            process.stdin.write(np.ascontiguousarray(rgb).tobytes())
    except BrokenPipeError:
        pass  # ffmpeg stopped early: its error message is reported below
    except BaseException:
        process.kill()
        process.communicate()
        raise
    _, stderr = process.communicate()
    if process.returncode != 0:
        message = stderr.decode(errors="replace").strip()
        raise RuntimeError(f"ffmpeg failed writing {path}: {message}")
