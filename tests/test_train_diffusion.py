"""`m2d2m train-diffusion` end to end at toy size: tokenizes first, trains, previews, tracks."""

from pathlib import Path

import mlflow
import pytest
import torch
import yaml

from orchestration.errors import UserError
from orchestration.runs import latest_run, read_run_info
from orchestration.train import train_diffusion, train_vq

TINY_DIFFUSION = {
    "dataset": "tiny",
    "seed": 1,
    "vq": "latest",
    "data": {"batch_size": 4, "num_workers": 0, "max_tokens": None},
    "text": {"kind": "learned", "dim": 16, "layers": 1, "heads": 2},
    "denoiser": {"layers": 1, "heads": 2, "width": 16, "ffn": 32, "dropout": 0.0, "max_distance": 16,
                 "num_buckets": 8, "condition_drop": 0.1},
    "diffusion": {"steps": 8, "kind": "dynamic", "eta": 0.5, "distance": "l2_rank", "schedule": "linear",
                  "aux_weight": 5e-4, "timestep_sampling": "uniform"},
    "optim": {"lr": 1e-3, "betas": [0.9, 0.99], "weight_decay": 0.0, "warmup_steps": 1, "milestones": [100],
              "gamma": 0.1, "grad_clip": 1.0},
    "trainer": {"max_steps": 4, "val_every_steps": 2, "val_batches": 1, "gif_every": 2, "accelerator": "cpu",
                "devices": 1, "precision": "auto"},
    "preview": {"prompts": ["a person walks forward"], "seconds": [1.0], "guidance": 2.0},
}


def test_the_denoiser_trains_on_tokens_it_makes_first_and_is_tracked(project, tiny_data):
    (project / "diffusion.yaml").write_text(yaml.safe_dump(TINY_DIFFUSION), encoding="utf-8")
    with pytest.raises(UserError, match="run `make train-vq` first"):
        train_diffusion(str(project / "diffusion.yaml"))
    train_vq(str(project / "tiny.yaml"))

    run_dir = train_diffusion(str(project / "diffusion.yaml"))
    info = read_run_info(run_dir)
    assert info["status"] == "finished" and latest_run("tiny", "diffusion", "make train-diffusion") == run_dir
    assert (Path(info["tokens"]) / "manifest.json").exists()
    checkpoint = torch.load(run_dir / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=True)
    assert checkpoint["state_dict"]["codebook"].shape == (16, 8)  # the VQ codebook travels with it
    assert checkpoint["hyper_parameters"]["diffusion"]["kind"] == "dynamic"
    assert any(run_dir.joinpath("previews").glob("*.gif"))

    mlflow.set_tracking_uri(f"sqlite:///{project / 'mlflow.db'}")
    run = mlflow.get_run(info["mlflow_run_id"])
    for metric in ("train/loss", "train/vlb", "train/aux", "val/loss", "val/token_accuracy"):
        assert metric in run.data.metrics, metric
    assert run.data.params["diffusion.kind"] == "dynamic" and run.data.tags["stage"] == "diffusion"
    samples = mlflow.MlflowClient().list_artifacts(run.info.run_id, "samples")
    assert samples and all(a.path.endswith(".gif") for a in samples)

    ablation = train_diffusion(str(project / "diffusion.yaml"), overrides=["diffusion.kind=uniform"])
    assert read_run_info(ablation)["config"]["diffusion"]["kind"] == "uniform"
