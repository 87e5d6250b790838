"""Where a VQ-VAE's reconstruction jitter comes from, and what removes it (issue: smooth decoding).

For a trained VQ model file and its dataset, every test clip of at least 60 frames is encoded and
decoded alone; on the middle 40 frames (as `m2d2m evaluate`'s ground-truth (single) row) this
prints the paper's Jerk (eq. 10, fps 1) of the ground truth and of the reconstruction, the
root-aligned MPJPE, what a Gaussian low-pass of σ frames on the decoded features would give, and
the reconstruction error's velocity spectrum at the frequencies a ×2 nearest-neighbour
upsampling would mark (1/4 and 1/2 cycle per frame) against their neighbours.

    python bench/vq_smoothness.py runs/synthetic/vq/<run>/vq.pt [--data data/synthetic] [--clips 120]
"""

from __future__ import annotations

import argparse
import io

import numpy as np
import torch
import webdataset as wds

from m2d2m.evaluation.metrics import jerk, mean_confidence_interval
from m2d2m.layout import shard_urls
from m2d2m.motion.representation.features import features_to_joints
from m2d2m.motion.representation.skeleton import SKELETONS
from m2d2m.motion.representation.smoothing import gaussian_smooth
from m2d2m.networks.vqvae import load_vq

SPECTRUM_FRAMES = 56  # the error spectrum's window: every clip of ≥ 60 frames has it


def held_out_clips(data: str, limit: int) -> list[np.ndarray]:
    """Whole test clips (features), mirrors left out, cut to whole tokens of 4 frames."""
    clips = []
    for url in shard_urls(data, "test"):
        for sample in wds.WebDataset(url, shardshuffle=False):
            features = np.load(io.BytesIO(sample["motion.npy"]))
            if len(features) >= 60 and not sample["__key__"].startswith("M"):
                clips.append(features[: len(features) // 4 * 4])
    return clips[:limit]


def middle_jerk(joints: np.ndarray) -> float:
    return jerk(joints, 1.0, [len(joints) // 2], 40)


def jerk_cell(jerks: np.ndarray) -> str:
    """Mean ± 95 % half-width (Student's t) of the clips' defined Jerks, as a table cell; one
    clip's spread says nothing, so it has a mean and no interval."""
    mean, half_width = mean_confidence_interval(jerks[np.isfinite(jerks)])
    return f"{mean:.2f} (n = 1: no interval)" if np.isnan(half_width) else f"{mean:.2f} ± {half_width:.2f}"


def aligned_mpjpe_mm(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm((a - a[:, :1]) - (b - b[:, :1]), axis=-1).mean() * 1000)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("vq")
    parser.add_argument("--data", default="data/synthetic")
    parser.add_argument("--clips", type=int, default=120)
    parser.add_argument("--sigmas", type=float, nargs="*", default=[0.5, 0.75, 1.0, 1.5])
    args = parser.parse_args()

    model, normalizer, info = load_vq(args.vq)
    skeleton = SKELETONS[info["skeleton"]]
    clips = held_out_clips(args.data, args.clips)
    rows: dict[str, list[tuple[float, float]]] = {"ground truth": [], "reconstruction": []}
    rows.update({f"reconstruction, features low-passed σ={s:g}": [] for s in args.sigmas})
    spectra = []
    for features in clips:
        with torch.no_grad():
            x = torch.as_tensor(normalizer.normalize(features), dtype=torch.float32)[None]
            decoded = normalizer.denormalize(model.decode(model.encode(x))[0].numpy()).astype(np.float32)
        truth, joints = features_to_joints(features, skeleton), features_to_joints(decoded, skeleton)
        rows["ground truth"].append((middle_jerk(truth), 0.0))
        rows["reconstruction"].append((middle_jerk(joints), aligned_mpjpe_mm(joints, truth)))
        for s in args.sigmas:
            smoothed = features_to_joints(gaussian_smooth(decoded, s).astype(np.float32), skeleton)
            rows[f"reconstruction, features low-passed σ={s:g}"].append(
                (middle_jerk(smoothed), aligned_mpjpe_mm(smoothed, truth))
            )
        error_velocity = np.diff(joints - truth, axis=0)
        if len(error_velocity) >= SPECTRUM_FRAMES:
            segment = error_velocity[:SPECTRUM_FRAMES].reshape(SPECTRUM_FRAMES, -1)
            spectra.append((np.abs(np.fft.rfft(segment, axis=0)) ** 2).mean(axis=1))

    print(f"{len(clips)} test clips, {args.vq}")
    print("| decoding | Jerk (middle 40 frames) | root-aligned MPJPE (mm) |\n| --- | --- | --- |")
    for name, values in rows.items():
        jerks, errors = np.array(values).T
        print(f"| {name} | {jerk_cell(jerks)} | {np.mean(errors):.1f} |")
    spectrum = np.mean(spectra, axis=0)
    frequencies = np.fft.rfftfreq(SPECTRUM_FRAMES)
    for f in (0.25, 0.5):
        i = int(np.argmin(np.abs(frequencies - f)))
        neighbours = spectrum[[max(i - 2, 0), min(i + 2, len(spectrum) - 1)]].mean() if f < 0.5 else spectrum[i - 2]
        print(
            f"error velocity power at {frequencies[i]:.3f} cycle/frame: {spectrum[i] / neighbours:.2f} × its neighbours"
        )


if __name__ == "__main__":
    main()
