"""DDP on one machine, as Lightning runs it on a GPU node, for M2D2M, MMM and MotionDiffuse: it starts the second
rank by re-running the command, and both ranks train one run (one directory, one MLflow run) whose files only rank 0
writes. Two CPU processes with gloo stand in for two GPUs."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import mlflow
import pytest
import yaml

from m2d2m.generators.m2d2m.checkpoint import load_m2d2m
from m2d2m.generators.mmm.checkpoint import load_mmm
from m2d2m.generators.motiondiffuse.checkpoint import load_motiondiffuse
from tests.helpers import TINY_MMM, TINY_MOTIONDIFFUSE

WIDTHS = {"m2d2m": 16, "mmm": TINY_MMM["transformer"]["width"], "motiondiffuse": TINY_MOTIONDIFFUSE["network"]["width"]}


def width(model: str, path) -> int:
    if model == "m2d2m":
        return load_m2d2m(path).denoiser.config.width
    if model == "mmm":
        return load_mmm(path).transformer.config.width
    return load_motiondiffuse(path).network.config.width


# MMM's and MotionDiffuse's runs take the same code path as M2D2M's (orchestration/train.py's fit)
@pytest.mark.parametrize(
    "model, verb",
    [
        ("m2d2m", "train-diffusion"),
        pytest.param("mmm", "train-mmm", marks=pytest.mark.slow),
        pytest.param("motiondiffuse", "train-motiondiffuse", marks=pytest.mark.slow),
    ],
)
def test_two_ddp_ranks_train_one_run(trained_project, model, verb):
    runs = trained_project / "runs" / "tiny" / model
    before = {path for path in runs.iterdir() if path.is_dir()} if runs.exists() else set()
    config = trained_project / f"{model}-ddp.yaml"
    if model == "mmm":
        config.write_text(yaml.safe_dump(TINY_MMM), encoding="utf-8")
    elif model == "motiondiffuse":
        data = {**TINY_MOTIONDIFFUSE["data"], "dir": str(trained_project / "data")}
        config.write_text(yaml.safe_dump({**TINY_MOTIONDIFFUSE, "data": data}), encoding="utf-8")
    else:
        config = trained_project / "diffusion.yaml"
    env = {key: value for key, value in os.environ.items() if key != "MLFLOW_TRACKING_URI"}
    command = [
        sys.executable,
        "-m",
        "orchestration.cli",
        verb,
        "--config",
        str(config),
        "--set",
        "trainer.accelerator=cpu",
        "--set",
        "trainer.devices=2",
    ]
    result = subprocess.run(
        command, cwd=trained_project, env={**env, "OMP_NUM_THREADS": "1"}, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, result.stderr[-3000:]

    (run_dir,) = {path for path in runs.iterdir() if path.is_dir()} - before
    info = json.loads((run_dir / "run.json").read_text(encoding="utf-8"))
    assert info["status"] == "finished" and info["world_size"] == 2
    assert width(model, run_dir / "model.pt") == WIDTHS[model]
    assert (runs / "latest").read_text(encoding="utf-8").strip() == run_dir.name

    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{trained_project / 'mlflow.db'}")
    experiment = client.get_experiment_by_name(f"tiny/{model}")
    (run,) = client.search_runs([experiment.experiment_id], f"attributes.run_name = '{run_dir.name}'")
    assert run.info.run_id == info["mlflow_run_id"] and run.info.status == "FINISHED"
    assert run.data.params["world_size"] == "2" and "val/loss" in run.data.metrics
