"""Calibrate the synthetic corpus's high-frequency texture against real HumanML3D motion.

Real capture is never as smooth as eased animation curves: its joint accelerations keep a flat
spectrum up to the Nyquist rate, and the transition metrics (the M2D2M paper's Jerk, eq. 10;
FlowMDM's PJ and AUJ) are dominated by that band. This script measures, per joint group, the
acceleration spectrum of the real HumanML3D clip 012314 (`--real`) and of synthetic clips,
and solves for the texture levels (:class:`pipelines.synthetic.program.Texture`) that give the
synthetic clips the real clip's ratio of high-band (5–10 Hz) to low-band (1.25–2.5 Hz) power:
a ratio, so that the real clip's livelier pace (it moves about twice as fast as the corpus's
average) does not count as texture. Noise power adds, so the levels solve a non-negative linear
least-squares problem in level², with each channel's response measured once.

    python bench/calibrate_corpus.py [--clips 300] [--figure docs/corpus-calibration.png]

prints the spectra, the solved levels, and the statistics the metrics see (Jerk in 40-frame
windows, FlowMDM's mean frame jerk, speeds at the clips' ends) before and after.
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from m2d2m.evaluation.metrics import frame_jerk, jerk
from pipelines.synthetic import FPS, Texture, make_clip

GROUPS = {
    "root": [0],
    "spine, head": [3, 6, 9, 12, 15],
    "arms": [16, 17, 18, 19, 20, 21],
    "legs": [4, 5, 7, 8, 10, 11],
}
CALIBRATED = ("root", "spine, head", "arms")  # the legs already match (see the printed table)
SEGMENT = 32  # frames per spectral segment (1.6 s), half-overlapping, Hann-windowed
FREQS = np.fft.rfftfreq(SEGMENT, 1.0 / FPS)
LOW_BAND = (FREQS >= 1.2) & (FREQS <= 2.6)
HIGH_BAND = FREQS >= 5.0
FLOWMDM_HUMANML3D_MEAN_FRAME_JERK = 0.033031363  # BarqueroGerman/FlowMDM, the HumanML3D constant
REAL = Path(__file__).resolve().parents[1] / "tests/fixtures/humanml3d-sample/new_joints/012314.npy"


def group_spectra(clips: list[np.ndarray]) -> dict[str, np.ndarray]:
    """Mean power spectrum of joint acceleration (second difference, m/frame²) per joint group,
    over every half-overlapping segment of every clip, all joints and axes of the group."""
    window = np.hanning(SEGMENT)[:, None, None]
    sums = {g: np.zeros(len(FREQS)) for g in GROUPS}
    count = 0
    for joints in clips:
        acceleration = np.diff(joints.astype(np.float64), n=2, axis=0)
        for start in range(0, len(acceleration) - SEGMENT + 1, SEGMENT // 2):
            segment = acceleration[start : start + SEGMENT] * window
            power = np.abs(np.fft.rfft(segment, axis=0)) ** 2
            for g, idx in GROUPS.items():
                sums[g] += power[:, idx].mean(axis=(1, 2))
            count += 1
    return {g: s / max(count, 1) for g, s in sums.items()}


def band_ratio(spectrum: np.ndarray) -> float:
    return float(spectrum[HIGH_BAND].mean() / spectrum[LOW_BAND].mean())


def clip_statistics(clips: list[np.ndarray]) -> dict[str, float]:
    """What the metrics see: Jerk (eq. 10, fps 1, as `m2d2m evaluate`) in 40-frame windows every
    20 frames, FlowMDM's mean frame jerk, and mean joint speed at the first, middle and last frames."""
    windows = np.array([jerk(c, 1.0, [centre], 40) for c in clips for centre in range(20, len(c) - 19, 20)])
    speed = [np.linalg.norm(np.diff(c, axis=0), axis=-1).mean(axis=-1) * FPS for c in clips]
    return {
        "windows": len(windows),
        "jerk_mean": float(np.nanmean(windows)),
        "jerk_p10": float(np.nanpercentile(windows, 10)),
        "jerk_p90": float(np.nanpercentile(windows, 90)),
        "mean_frame_jerk": float(np.concatenate([frame_jerk(c) for c in clips]).mean()),
        "speed_start": float(np.mean([s[0] for s in speed])),
        "speed_middle": float(np.mean([s.mean() for s in speed])),
        "speed_end": float(np.mean([s[-1] for s in speed])),
    }


def synthetic(texture: Texture, clips: int, seed: int) -> list[np.ndarray]:
    return [make_clip(i, seed, texture=texture).joints.astype(np.float64) for i in range(clips)]


def solve_levels(clips: int, seed: int, real: dict[str, np.ndarray]) -> tuple[Texture, dict]:
    """Texture levels whose added high-band power brings each calibrated group's band ratio to
    the real clip's: the smooth corpus's spectra, one probe per channel, then NNLS in level²."""
    smooth = group_spectra(synthetic(Texture(), clips, seed))
    probe = 1e-3
    channels = ("pelvis", "angles", "wrists")
    response = np.zeros((len(CALIBRATED), len(channels)))
    for j, channel in enumerate(channels):
        probed = group_spectra(synthetic(replace(Texture(), **{channel: probe}), clips, seed))
        for i, g in enumerate(CALIBRATED):
            response[i, j] = (probed[g][HIGH_BAND].mean() - smooth[g][HIGH_BAND].mean()) / probe**2
    target = np.array(
        [band_ratio(real[g]) * smooth[g][LOW_BAND].mean() - smooth[g][HIGH_BAND].mean() for g in CALIBRATED]
    )
    squares = _nnls(response, np.maximum(target, 0.0))
    levels = dict(zip(channels, np.sqrt(squares)))
    return Texture(**{k: float(f"{v:.3g}") for k, v in levels.items()}), smooth


def _nnls(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Non-negative least squares for a handful of unknowns: the best of every active set."""
    best, best_error = np.zeros(a.shape[1]), float(np.sum(b**2))
    for mask in range(1, 2 ** a.shape[1]):
        active = [j for j in range(a.shape[1]) if mask >> j & 1]
        x_active, *_ = np.linalg.lstsq(a[:, active], b, rcond=None)
        if np.any(x_active < 0):
            continue
        x = np.zeros(a.shape[1])
        x[active] = x_active
        error = float(np.sum((a @ x - b) ** 2))
        if error < best_error:
            best, best_error = x, error
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clips", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--real", type=Path, default=REAL)
    parser.add_argument("--figure", type=Path, default=None, help="write the spectra as a PNG")
    args = parser.parse_args()

    real_joints = np.load(args.real).astype(np.float64)
    real = group_spectra([real_joints])
    texture, smooth = solve_levels(args.clips, args.seed, real)
    textured_clips = synthetic(texture, args.clips, args.seed)
    textured = group_spectra(textured_clips)
    print(f"solved texture: {texture}")
    print("\nhigh-band (5-10 Hz) / low-band (1.25-2.5 Hz) acceleration power per joint group")
    print("| group | real 012314 | synthetic, smooth | synthetic, textured |\n| --- | --- | --- | --- |")
    for g in GROUPS:
        print(f"| {g} | {band_ratio(real[g]):.3f} | {band_ratio(smooth[g]):.3f} | {band_ratio(textured[g]):.3f} |")

    print("\nwhat the metrics see")
    rows = {
        "real 012314": clip_statistics([real_joints]),
        "synthetic, smooth": clip_statistics(synthetic(Texture(), args.clips, args.seed)),
        "synthetic, textured": clip_statistics(textured_clips),
    }
    print(
        "| clips | Jerk windows | Jerk mean [p10, p90] | mean frame jerk (m/frame³) | speed first / middle / last (m/s) |"
    )
    print("| --- | --- | --- | --- | --- |")
    for name, s in rows.items():
        print(
            f"| {name} | {s['windows']} | {s['jerk_mean']:.2f} [{s['jerk_p10']:.2f}, {s['jerk_p90']:.2f}] | "
            f"{s['mean_frame_jerk']:.4f} | {s['speed_start']:.2f} / {s['speed_middle']:.2f} / {s['speed_end']:.2f} |"
        )
    print(f"(FlowMDM's HumanML3D test-set mean frame jerk: {FLOWMDM_HUMANML3D_MEAN_FRAME_JERK})")
    if args.figure:
        _plot(args.figure, real, smooth, textured)
        print(f"figure: {args.figure}")


def _plot(path: Path, real: dict, smooth: dict, textured: dict) -> None:
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    figure = Figure(figsize=(10, 2.8), dpi=110)
    FigureCanvasAgg(figure)
    for i, g in enumerate(GROUPS):
        ax = figure.add_subplot(1, len(GROUPS), i + 1)
        for spectra, label, style in (
            (real, "real (012314)", "k-"),
            (smooth, "synthetic, smooth", "C0--"),
            (textured, "synthetic, textured", "C1-"),
        ):
            s = spectra[g] / spectra[g][LOW_BAND].mean()
            ax.semilogy(FREQS[1:], s[1:], style, label=label)
        ax.set_title(g)
        ax.set_xlabel("Hz")
        if i == 0:
            ax.set_ylabel("acceleration power / low band")
            ax.legend(fontsize=7)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path)


if __name__ == "__main__":
    main()
