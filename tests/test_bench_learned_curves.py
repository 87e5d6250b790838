"""bench/learned_curves.py: the curves come from the latest run's MLflow history, nothing else."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
from bench.learned_curves import draw, smoothed  # noqa: E402
from orchestration.runs import mark_latest, write_run_info  # noqa: E402
from orchestration.tracking import client, ensure_experiment  # noqa: E402


def test_the_smoothing_is_a_trailing_mean_over_the_points_so_far():
    np.testing.assert_allclose(smoothed(np.array([4.0, 2.0, 6.0, 0.0]), window=2), [4.0, 3.0, 4.0, 3.0])
    np.testing.assert_allclose(smoothed(np.array([3.0, 6.0, 9.0]), window=5), [3.0, 4.5, 6.0])
    assert len(smoothed(np.zeros(0))) == 0


def test_the_figure_reads_the_latest_runs_histories(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    store = client()
    run_id = store.create_run(ensure_experiment("real/vq")).info.run_id
    for step, (loss, mpjpe) in enumerate([(0.9, 80.0), (0.5, 50.0), (0.3, 36.4)]):
        store.log_metric(run_id, "val/recon_loss", loss, step=500 * (step + 1))
        store.log_metric(run_id, "val/mpjpe_root_aligned_mm", mpjpe, step=500 * (step + 1))
    run_dir = tmp_path / "runs" / "real" / "vq" / "20990101-000000-abcd"
    run_dir.mkdir(parents=True)
    write_run_info(run_dir, status="finished", mlflow_run_id=run_id)
    mark_latest(run_dir)
    out = tmp_path / "curves.png"
    lines = draw("real", out)
    assert out.stat().st_size > 0
    assert lines == [f"wrote {out}", "vq 20990101-000000-abcd: val/recon_loss 0.3, val/mpjpe_root_aligned_mm 36.4"]


def test_a_dataset_without_trained_models_is_one_line(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    with pytest.raises(SystemExit, match="runs/nothing: no trained model"):
        draw("nothing", tmp_path / "curves.png")
