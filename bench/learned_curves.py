"""The learning curves of a dataset's latest trained models, as their trainings logged them to
MLflow: each model's training loss and its validation measures against training steps, one panel
a model (docs/reproduction.md, "On real motion", draws the Bandai Namco corpus's with it).

Nothing is trained or sampled here: the figure reads the ``latest`` run of each stage under
``runs/<dataset>/`` and that run's metric histories in the project's tracking store, so it shows
exactly the trainings a table was made with.

    python bench/learned_curves.py [--dataset bandai-namco] [--out docs/real-motion-curves.png]

prints, per model, its run and each curve's last value.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from orchestration.runs import LATEST, read_run_info, stage_dir  # noqa: E402
from orchestration.tracking import client  # noqa: E402

SMOOTHING = 50  # training losses are logged every few steps: a moving mean over this many points


@dataclass(frozen=True)
class Panel:
    """One model's panel: its stage, its title, the loss curves (left axis) and a validation
    measure on the right axis (``None``: none worth a second axis)."""

    stage: str
    title: str
    losses: tuple[str, ...]
    measure: str | None


PANELS = (
    Panel("vq", "VQ-VAE", ("train/loss", "val/recon_loss"), "val/mpjpe_root_aligned_mm"),
    Panel("m2d2m", "M2D2M denoiser", ("train/loss", "val/loss"), "val/token_accuracy"),
    Panel("mmm", "MMM masked transformer", ("train/loss", "val/loss"), "val/masked_accuracy"),
    Panel("motiondiffuse", "MotionDiffuse", ("train/loss", "val/loss"), None),
    Panel("evaluator", "text-motion evaluator", ("train/loss", "val/loss"), "val/top1"),
)


def history(mlflow_client, run_id: str, metric: str) -> tuple[np.ndarray, np.ndarray]:
    """(steps, values) of one metric of one run, by step; empty when the run never logged it."""
    points = sorted((m.step, m.value) for m in mlflow_client.get_metric_history(run_id, metric))
    if not points:
        return np.zeros(0), np.zeros(0)
    steps, values = zip(*points)
    return np.asarray(steps, dtype=float), np.asarray(values, dtype=float)


def smoothed(values: np.ndarray, window: int = SMOOTHING) -> np.ndarray:
    """A trailing moving mean (the first points average what came before them)."""
    if len(values) == 0:
        return values
    sums = np.cumsum(np.insert(values, 0, 0.0))
    counts = np.minimum(np.arange(1, len(values) + 1), window)
    return (sums[1:] - sums[np.arange(1, len(values) + 1) - counts]) / counts


def latest_run_id(dataset: str, stage: str) -> tuple[str, str] | None:
    """The latest finished run of ``stage`` and its MLflow run id, or None when it has none."""
    marker = stage_dir(dataset, stage) / LATEST
    if not marker.exists():
        return None
    name = marker.read_text(encoding="utf-8").strip()
    run_id = read_run_info(stage_dir(dataset, stage) / name).get("mlflow_run_id")
    return (name, run_id) if run_id else None


def draw(dataset: str, out: Path) -> list[str]:
    """The figure at ``out``; the lines that say what it shows."""
    mlflow_client = client()
    found = [(panel, latest_run_id(dataset, panel.stage)) for panel in PANELS]
    found = [(panel, run) for panel, run in found if run is not None]
    if not found:
        raise SystemExit(f"runs/{dataset}: no trained model; train one first (make demo-real for bandai-namco)")
    columns = min(3, len(found))
    rows = -(-len(found) // columns)
    figure, axes = plt.subplots(rows, columns, figsize=(4.6 * columns, 3.4 * rows), squeeze=False)
    for axis in axes.flat[len(found) :]:
        axis.set_visible(False)
    lines = []
    for axis, (panel, (name, run_id)) in zip(axes.flat, found):
        said = []
        for metric in panel.losses:
            steps, values = history(mlflow_client, run_id, metric)
            if len(steps):
                shown = smoothed(values) if metric.startswith("train/") else values
                axis.plot(steps, shown, label=metric, marker=None if metric.startswith("train/") else "o")
                said.append(f"{metric} {values[-1]:.4g}")
        axis.set_xlabel("training step")
        axis.set_title(f"{panel.title}\n{name}", fontsize="small")
        axis.legend(fontsize="x-small", loc="upper left")
        if panel.measure is not None:
            steps, values = history(mlflow_client, run_id, panel.measure)
            if len(steps):
                twin = axis.twinx()
                twin.plot(steps, values, color="tab:green", marker="s", label=panel.measure)
                twin.legend(fontsize="x-small", loc="upper right")
                said.append(f"{panel.measure} {values[-1]:.4g}")
        lines.append(f"{panel.stage} {name}: " + ", ".join(said))
    figure.suptitle(f"Learning curves on {dataset} (training loss smoothed over {SMOOTHING} logged points)")
    figure.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(out, dpi=110)
    return [f"wrote {out}", *lines]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", default="bandai-namco")
    parser.add_argument("--out", type=Path, default=Path("docs/real-motion-curves.png"))
    args = parser.parse_args()
    print("\n".join(draw(args.dataset, args.out)))


if __name__ == "__main__":
    main()
