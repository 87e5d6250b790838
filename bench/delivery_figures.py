"""Pictures of what each delivery option does to a clip (docs/generation.md, "Delivering a clip"),
drawn on real data so that the docs show what an animator gets, not a sketch of it.

The clip is HumanML3D's sample 012314 (170 frames at 20 fps, T2M's 22 joints) put on one rigid
skeleton, as ``m2d2m generate`` hands its clips to :func:`m2d2m.motion.transforms.delivery.deliver`, with
its features for the contact channels. Each figure shows one option against the default delivery
(feet planted), made by ``deliver`` itself where its output says enough, else by the function it
runs:

* ``delivery-feet.png``: the foot fix (``--no-foot-fix`` turns it off) on the clip with its planted
  feet made to slide as a generated clip's do (:func:`bench.foot_fix.slide_feet`: the real clip's
  own feet do not, and the fix leaves them be): a toe's horizontal speed and height, sliding and
  planted, its contact runs shaded, GMD's skating thresholds drawn;
* ``delivery-fps.png``: ``--fps 30`` and ``--fps 60``: a wrist's height at the three rates;
* ``delivery-root.png``: ``--root in-place``: the pelvis's and toes' paths seen from above;
* ``delivery-loop.png``: ``--loop``: a wrist's height over two cycles, cut without a fade and
  made by :func:`m2d2m.motion.transforms.retime.make_loop`, with the jerk at the seam;
* ``delivery-rig.png``: ``--rig tests/fixtures/cmu-bvh/131_01.bvh --joint-map cmu``: the clip on
  our skeleton and on CMU's 31-joint rig at three frames.

    python bench/delivery_figures.py [--out docs]

prints each figure's path and its figures. Deterministic; a few seconds on a CPU.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from m2d2m.motion.files.bvh_reader import read_bvh
from m2d2m.motion.representation.rigid import on_rigid_skeleton
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.motion.rigs.joint_map import joint_map_for
from m2d2m.motion.rigs.retarget import Rig, retarget
from m2d2m.motion.transforms.delivery import Delivered, Delivery, deliver
from m2d2m.motion.transforms.feet import (
    SKATING_HEIGHT_M,
    SKATING_SPEED_M_S,
    contact_runs,
    foot_contacts,
    skating_ratio,
    step_speeds,
)
from m2d2m.motion.transforms.retime import make_loop

try:
    from bench.foot_fix import slide_feet
except ModuleNotFoundError:  # run as `python bench/delivery_figures.py`: this folder is on the path
    from foot_fix import slide_feet

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "tests" / "fixtures" / "humanml3d-sample"
CLIP_ID = "012314"
CMU_RIG = ROOT / "tests" / "fixtures" / "cmu-bvh" / "131_01.bvh"
CMU_METRES_PER_UNIT = 0.056444  # cgspeed's conversions: 1/0.45 inch a unit (tests/fixtures/cmu-bvh/README.md)
SIZE_INCHES, DPI = (9.0, 5.0), 100  # 900 × 500 px
SLIDE_M_S, SLIDE_M = 0.6, 0.15  # how the feet figure's clip slides: speed and distance a stance
FEET_SCALE = (1.6, 12.0)  # m/s and cm: the feet figure's scales, over GMD's thresholds; a swing goes off them
TOE = T2M.feet_right[1]  # the right toe: the foot that skates in clip 012314 (GMD measures the toes)
TOE_CONTACT = 3  # its column in foot_contacts' (left ankle, left toe, right ankle, right toe)
WRIST = T2M.joint_names.index("left_wrist")  # the arm clip 012314 raises highest
FPS_WINDOW_S = (0.6, 1.4)  # the stretch of the fps figure: the left arm going up and down again
RATES = (30.0, 60.0)  # the rates resampled to, besides the model's 20
RIG_FRAMES = (10, 40, 140)  # a step with an arm swung, a squat, an arm out: poses far apart
RAW, OURS, THEIRS = "0.55", "C0", "C1"  # colours: as generated, as delivered, on the other rig


@dataclass(frozen=True)
class Clip:
    """The sample clip on one rigid skeleton (``raw``), as ``m2d2m generate`` hands a clip to
    :func:`~m2d2m.motion.transforms.delivery.deliver`, with the model's features beside it."""

    raw: np.ndarray
    features: np.ndarray
    fps: float

    def delivered(self, delivery: Delivery = Delivery()) -> Delivered:
        """The clip as ``delivery`` asks for it, the whole clip one action."""
        return deliver(self.raw, self.fps, T2M, [(0, len(self.raw))], delivery, self.features)

    @cached_property
    def planted(self) -> np.ndarray:
        """The joints the default delivery gives (the feet planted), float32 as the files hold them."""
        return self.delivered().joints

    @cached_property
    def sliding(self) -> Clip:
        """The clip with each planted stretch of its feet made to slide 15 cm at 0.6 m/s, as a
        generated clip's feet slide (its features, and so its contact channels, kept)."""
        return Clip(slide_feet(self.raw, SLIDE_M_S, SLIDE_M).astype(np.float32), self.features, self.fps)

    def seconds(self, frames: int, start: float = 0.0) -> np.ndarray:
        """The instants of ``frames`` frames at the clip's rate, from frame ``start`` on."""
        return (np.arange(frames) + start) / self.fps


def load_clip() -> Clip:
    """Clip 012314 on one rigid skeleton, as ``m2d2m generate`` puts every clip before delivery."""
    raw = on_rigid_skeleton(np.load(SAMPLE / "new_joints" / f"{CLIP_ID}.npy"), T2M)
    return Clip(raw, np.load(SAMPLE / "new_joint_vecs" / f"{CLIP_ID}.npy"), T2M.fps)


def new_figure(columns: int = 1, rows: int = 1, **options: bool) -> tuple[Figure, list[Axes]]:
    """A 900 × 500 px figure drawn by Agg (no display needed) and its axes, row by row."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=SIZE_INCHES, dpi=DPI, layout="constrained")
    FigureCanvasAgg(figure)
    return figure, list(figure.subplots(rows, columns, squeeze=False, **options).ravel())


def within(metres: float) -> str:
    """How closely two sets of joints agree, in words for a title."""
    return "exactly" if metres == 0 else f"to {metres:.1g} m"


def shade_runs(axes: Axes, flags: np.ndarray, fps: float, label: str) -> None:
    """The runs of True in ``flags`` (T,) as grey bands over the frames they cover."""
    for index, (first, end) in enumerate(contact_runs(flags)):
        axes.axvspan(first / fps, (end - 1) / fps, color="0.9", zorder=0, label=label if index == 0 else None)


def feet_figure(clip: Clip) -> tuple[Figure, dict[str, float]]:
    """How fast the toe slides while it touches the ground, before and after the fix, on the clip
    made to slide; and how far the fix moves the real clip (not at all)."""
    sliding = clip.sliding
    contacts = foot_contacts(sliding.raw, T2M, clip.fps, clip.features)[:, TOE_CONTACT]
    steps = len(clip.raw) - 1
    in_contact = contacts[:-1] & contacts[1:]
    quality = sliding.delivered().quality
    numbers = {
        "skating_before": quality["skating_before_fix"],
        "skating_after": quality["skating"],
        "skating_clean": skating_ratio(clip.raw, T2M, clip.fps),
        "real_clip_moved_m": float(np.abs(clip.planted - clip.raw).max()),
    }
    figure, (speed_axes, height_axes) = new_figure(rows=2, sharex=True)
    for joints, colour, label, key in (
        (sliding.raw, RAW, "sliding", "before"),
        (sliding.planted, OURS, "feet planted", "after"),
    ):
        toe = joints[:, TOE]
        speed = step_speeds(toe, clip.fps)
        numbers[f"toe_speed_in_contact_{key}_m_s"] = float(speed[in_contact].mean())
        speed_axes.plot(clip.seconds(steps, 0.5), speed, color=colour, label=label)
        height_axes.plot(clip.seconds(len(toe)), toe[:, 1] * 100.0, color=colour, label=label)
    for axes in (speed_axes, height_axes):
        shade_runs(axes, contacts, clip.fps, "contact")
    threshold = "GMD's skating: > 0.5 m/s below 5 cm"
    speed_axes.axhline(SKATING_SPEED_M_S, color="k", linestyle="--", linewidth=1, label=threshold)
    height_axes.axhline(SKATING_HEIGHT_M * 100.0, color="k", linestyle="--", linewidth=1)
    speed_axes.set(ylabel="horizontal speed (m/s)", ylim=(0, FEET_SCALE[0]))
    height_axes.set(ylabel="height (cm)", xlabel="time (s)", ylim=(-0.5, FEET_SCALE[1]), xlim=(0, steps / clip.fps))
    figure.legend(*speed_axes.get_legend_handles_labels(), fontsize="small", ncols=4, loc="outside lower center")
    speed_axes.set_title(
        f"Right toe of clip {CLIP_ID}, each stance made to slide {SLIDE_M * 100:.0f} cm at {SLIDE_M_S} m/s\n"
        f"skating {numbers['skating_before']:.1%} → {numbers['skating_after']:.1%} "
        f"(clean: {numbers['skating_clean']:.1%}); in contact "
        f"{numbers['toe_speed_in_contact_before_m_s']:.2f} → {numbers['toe_speed_in_contact_after_m_s']:.2f} m/s"
    )
    return figure, numbers


def shared_error(source: np.ndarray, fps: float, resampled: np.ndarray, rate: float) -> float:
    """The largest joint difference (m) at the instants both rates have a frame."""
    common = math.gcd(round(fps), round(rate))
    source_step, target_step = round(fps) // common, round(rate) // common
    shared = min(len(source[::source_step]), len(resampled[::target_step]))
    return float(np.abs(resampled[::target_step][:shared] - source[::source_step][:shared]).max())


def fps_figure(clip: Clip) -> tuple[Figure, dict[str, float]]:
    """Frames at the asked rate fall between the model's, on the same motion: where both rates
    have a frame (every 0.1 s here) they are the same pose."""
    first, last = FPS_WINDOW_S
    figure, (axes,) = new_figure()
    numbers: dict[str, float] = {f"frames_{clip.fps:g}": len(clip.planted)}
    for rate, style, layer in ((RATES[0], "s", 3), (RATES[1], ".-", 2)):  # 30 fps's squares over 60's line
        joints = clip.delivered(Delivery(fps=rate)).joints
        times = np.arange(len(joints)) / rate
        shown = (times >= first) & (times <= last)
        axes.plot(times[shown], joints[shown, WRIST, 1], style, markersize=7, zorder=layer, label=f"--fps {rate:g}")
        numbers[f"frames_{rate:g}"] = len(joints)
        numbers[f"shared_error_{rate:g}_m"] = shared_error(clip.planted, clip.fps, joints, rate)
    times = clip.seconds(len(clip.planted))
    shown = (times >= first) & (times <= last)
    model = f"{clip.fps:g} fps (the model's)"
    axes.plot(times[shown], clip.planted[shown, WRIST, 1], "o", color="k", fillstyle="none", markersize=14, label=model)
    for instant in np.arange(first, last + 1e-9, 0.1):
        axes.axvline(instant, color="0.85", linewidth=0.8, zorder=0)
    axes.set(xlabel="time (s); grey lines every 0.1 s, where 20, 30 and 60 fps all have a frame", ylabel="height (m)")
    axes.legend()
    worst = max(numbers[f"shared_error_{rate:g}_m"] for rate in RATES)
    counts = ", ".join(f"{numbers[f'frames_{rate:g}']:.0f} at {rate:g}" for rate in RATES)
    axes.set_title(
        f"Left wrist of clip {CLIP_ID}: {len(clip.planted)} frames at {clip.fps:g} fps → {counts} (slerp)\n"
        f"at the instants two rates share, every joint is the model's frame's {within(worst)}"
    )
    return figure, numbers


def root_figure(clip: Clip) -> tuple[Figure, dict[str, float]]:
    """Seen from above: the path the body walks, and an in-place clip whose path is a separate track
    (both float32, as the npy and its ``root_motion.npy`` hold them)."""
    kept = clip.planted
    done = clip.delivered(Delivery(root="in-place"))
    in_place, track = done.joints, done.root_track.astype(np.float32)
    numbers = {
        "pelvis_path_m": float(step_speeds(track, 1.0).sum()),
        "in_place_drift_m": float(np.abs(in_place[:, 0, [0, 2]]).max()),
        "restored_m": float(np.abs(in_place + track[:, None] - kept).max()),
    }
    titles = (
        f"--root keep (default): the pelvis walks {numbers['pelvis_path_m']:.2f} m",
        f"--root in-place: the pelvis stays on the origin {within(numbers['in_place_drift_m'])}",
    )
    figure, axes = new_figure(rows=2, sharex=True, sharey=True)
    for side, joints, title in zip(axes, (kept, in_place), titles):
        for toe, name in ((T2M.feet_left[1], "left toe"), (TOE, "right toe")):
            side.plot(joints[:, toe, 0], joints[:, toe, 2], linewidth=0.8, alpha=0.6, label=name)
        side.plot(joints[:, 0, 0], joints[:, 0, 2], "o-", color="k", markersize=3, linewidth=1.2, label="pelvis")
        side.set(title=title, ylabel="z (m)", aspect="equal")
    axes[0].plot(*kept[0, 0, [0, 2]], "^", color="C2", markersize=9, label="first frame")
    kept_beside = f"root-motion track, kept beside:\nclip + track = the clip {within(numbers['restored_m'])}"
    axes[1].plot(track[:, 0], track[:, 2], "--", color="C3", label=kept_beside)
    axes[1].set_xlabel("x (m); seen from above: +y towards you, +z down")
    axes[1].annotate(
        "the pelvis, in every frame", (0.0, 0.0), (0.8, -0.25), arrowprops={"arrowstyle": "->"}, va="center"
    )
    axes[0].invert_yaxis()
    handles = {label: handle for side in axes for handle, label in zip(*side.get_legend_handles_labels())}
    figure.legend(handles.values(), handles.keys(), fontsize="small", loc="outside right center")
    return figure, numbers


def jerk(joints: np.ndarray, fps: float) -> np.ndarray:
    """Per step t, the mean over joints of |x[t+3] − 3x[t+2] + 3x[t+1] − x[t]|·fps³ (m/s³): the
    measure tests/test_retime.py holds a loop's seam to."""
    return np.linalg.norm(np.diff(joints, 3, axis=0), axis=-1).mean(axis=1) * fps**3


def twice(cycle: np.ndarray, travel: np.ndarray) -> np.ndarray:
    """A cycle played twice, the second time moved on by the distance it travels."""
    return np.concatenate([cycle, cycle + travel])


def loop_figure(clip: Clip) -> tuple[Figure, dict[str, float]]:
    """Two repetitions of the same frames: cut and repeated, the pose jumps at the seam; looped
    by ``make_loop``, the end is faded into the start and the seam is as smooth as the clip."""
    loop = make_loop(clip.planted, clip.fps, T2M)
    first, end = loop.span
    frames = end - first
    cut = twice(clip.planted[first:end], loop.travel)
    looped = twice(loop.joints, loop.travel)
    seam = slice(frames - 3, frames)  # the third differences that reach across the seam
    numbers = {
        "first_frame": first,
        "end_frame": end,
        "fade_s": first / clip.fps,
        "travel_m": float(np.linalg.norm(loop.travel)),
        "seam_jerk_loop": float(jerk(looped, clip.fps)[seam].max()),
        "seam_jerk_cut": float(jerk(cut, clip.fps)[seam].max()),
        "clip_jerk_p95": float(np.percentile(jerk(clip.planted, clip.fps), 95)),
    }
    figure, (axes,) = new_figure()
    times = clip.seconds(2 * frames)
    axes.plot(times, cut[:, WRIST, 1], "--", color=RAW, label=f"frames {first}–{end - 1} cut and repeated")
    axes.plot(times, looped[:, WRIST, 1], color=OURS, label="--loop (make_loop)")
    for repeat in (1, 2):
        axes.axvspan((repeat * frames - first) / clip.fps, (repeat * frames - 1) / clip.fps, color="0.9", zorder=0)
    axes.plot([], [], color="0.9", linewidth=8, label=f"the {numbers['fade_s']:.2f}-s fade into the start")
    axes.axvline(frames / clip.fps, color="k", linewidth=1)
    axes.annotate(" seam", (frames / clip.fps, 0.98), xycoords=("data", "axes fraction"), ha="left", va="top")
    axes.set(xlabel="time (s), two repetitions", ylabel="left wrist height (m)")
    axes.legend(loc="upper right", fontsize="small")
    axes.set_title(
        f"Clip {CLIP_ID} as a {frames / clip.fps:.2f}-s loop, travelling {numbers['travel_m']:.2f} m a cycle\n"
        f"jerk at the seam {numbers['seam_jerk_loop']:.0f} m/s³ against the clip's 95th percentile "
        f"{numbers['clip_jerk_p95']:.0f}; cut without the fade {numbers['seam_jerk_cut']:,.0f}"
    )
    return figure, numbers


def facing_front(pose: np.ndarray, hips: tuple[int, int]) -> np.ndarray:
    """The rotation (3, 3) about +Y that turns a pose (J, 3) to face +Z, judged from its (left, right) hips."""
    forward = np.cross(pose[hips[0]] - pose[hips[1]], [0.0, 1.0, 0.0])
    angle = math.atan2(forward[0], forward[2])
    cos, sin = math.cos(angle), math.sin(angle)
    return np.array([[cos, 0.0, -sin], [0.0, 1.0, 0.0], [sin, 0.0, cos]])


def draw_skeleton(axes: Axes, points: np.ndarray, parents: np.ndarray, colour: str, label: str) -> None:
    """Bones from each joint to its parent, and the joints, in the x–y plane (a front view)."""
    for joint, parent in enumerate(parents):
        if parent >= 0:
            axes.plot(*points[[parent, joint], :2].T, color=colour, linewidth=2)
    axes.plot(points[:, 0], points[:, 1], "o", color=colour, markersize=3, label=label)


def leg_length(pose: np.ndarray, chain: list[int]) -> float:
    """Hip to ankle (m) along the bones of ``chain`` in a pose (J, 3)."""
    return float(np.linalg.norm(np.diff(pose[chain], axis=0), axis=-1).sum())


def rig_figure(clip: Clip) -> tuple[Figure, dict[str, float]]:
    """The same frames on our skeleton and on CMU's rig, with its own bone lengths and joints."""
    take = read_bvh(CMU_RIG, CMU_METRES_PER_UNIT)
    rig = Rig.from_bvh(take)
    mapping = joint_map_for(take, "cmu")
    theirs = retarget(clip.planted, rig, mapping).positions()
    leg = ("left_hip", "left_knee", "left_ankle")
    numbers = {
        "rig_joints": len(rig.names),
        "leg_ours_m": leg_length(clip.planted[0], [T2M.joint_names.index(name) for name in leg]),
        "leg_theirs_m": leg_length(rig.rest_positions(), [rig.names.index(mapping.sources[name][0]) for name in leg]),
    }
    hips = (T2M.joint_names.index("left_hip"), T2M.joint_names.index("right_hip"))
    root = int(np.flatnonzero(rig.parents < 0)[0])
    figures = (
        (clip.planted, T2M.parents, 0, OURS, f"ours (T2M, {len(T2M.parents)} joints)"),
        (theirs, rig.parents, root, THEIRS, f"on CMU 131_01's rig ({len(rig.names)} joints)"),
    )
    figure, axes = new_figure(columns=len(RIG_FRAMES), sharey=True)
    for side, frame in zip(axes, RIG_FRAMES):
        turn = facing_front(clip.planted[frame], hips)  # our pose's facing turns both: they face the same way
        for joints, parents, centre, colour, label in figures:  # each over its own root, on its own floor
            placed = (joints[frame] - joints[frame, centre] * [1.0, 0.0, 1.0]) @ turn.T
            draw_skeleton(side, placed, parents, colour, label)
        side.set(title=f"frame {frame} ({frame / clip.fps:.1f} s)", xlabel="across the body (m), front view")
        side.set_aspect("equal")
    axes[0].set_ylabel("height (m)")
    figure.legend(*axes[0].get_legend_handles_labels(), ncols=2, loc="outside lower center")
    figure.suptitle(
        f"--rig tests/fixtures/cmu-bvh/131_01.bvh --joint-map cmu: clip {CLIP_ID} on CMU's joints and bones\n"
        f"(hip to ankle {numbers['leg_theirs_m']:.2f} m against our {numbers['leg_ours_m']:.2f} m)"
    )
    return figure, numbers


FIGURES = {
    "delivery-feet.png": feet_figure,
    "delivery-fps.png": fps_figure,
    "delivery-root.png": root_figure,
    "delivery-loop.png": loop_figure,
    "delivery-rig.png": rig_figure,
}


def main(argv: list[str] | None = None) -> dict[str, dict[str, float]]:
    """Draw every figure into ``--out``; print and return each one's numbers, by file name."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("docs"), help="where the PNGs go (default docs)")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    clip = load_clip()
    results = {}
    for name, draw in FIGURES.items():
        figure, results[name] = draw(clip)
        figure.savefig(args.out / name)
        print(f"{args.out / name}: " + ", ".join(f"{key} {value:.4g}" for key, value in results[name].items()))
    return results


if __name__ == "__main__":
    main()
