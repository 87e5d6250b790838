"""`m2d2m train-diffusion` end to end at toy size: tokenizes first, trains, previews, tracks."""

import json
from pathlib import Path

import lightning.pytorch as pl
import mlflow
import pytest
import torch
import yaml

from orchestration.errors import UserError
from orchestration.recipe import train
from orchestration.recipes.vq import train_vq
from orchestration.runs import latest_run, read_run_info
from tests.helpers import TINY_DIFFUSION
from tests.test_train_vq import KillAt, RecordStart


def test_the_denoiser_trains_on_tokens_it_makes_first_and_is_tracked(project, tiny_data):
    (project / "diffusion.yaml").write_text(yaml.safe_dump(TINY_DIFFUSION), encoding="utf-8")
    with pytest.raises(UserError, match="run `make train-vq` first"):
        train("m2d2m", str(project / "diffusion.yaml"))
    train_vq(str(project / "tiny.yaml"))

    run_dir = train("m2d2m", str(project / "diffusion.yaml"))
    info = read_run_info(run_dir)
    assert info["status"] == "finished" and latest_run("tiny", "m2d2m", "make train-diffusion") == run_dir
    assert (Path(info["tokens"]) / "manifest.json").exists()
    checkpoint = torch.load(run_dir / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=True)
    assert checkpoint["state_dict"]["codebook"].shape == (16, 8)  # the VQ codebook travels with it
    assert checkpoint["hyper_parameters"]["diffusion"]["kind"] == "dynamic"
    assert any(run_dir.joinpath("previews").glob("*.gif"))
    assert info["model"] == f"runs/tiny/m2d2m/{run_dir.name}/model.pt"  # relative to the project, which can move

    mlflow.set_tracking_uri(f"sqlite:///{project / 'mlflow.db'}")
    run = mlflow.get_run(info["mlflow_run_id"])
    for metric in ("train/loss", "train/vlb", "train/aux", "val/loss", "val/token_accuracy"):
        assert metric in run.data.metrics, metric
    assert run.data.params["diffusion.kind"] == "dynamic" and run.data.tags["stage"] == "m2d2m"
    samples = mlflow.MlflowClient().list_artifacts(run.info.run_id, "samples")
    assert samples and all(a.path.endswith(".gif") for a in samples)
    model_files = {Path(a.path).name for a in mlflow.MlflowClient().list_artifacts(run.info.run_id, "model")}
    assert {"model.pt", "best.ckpt", "last.ckpt", "config.yaml"} <= model_files

    ablation = train(
        "m2d2m",
        str(project / "diffusion.yaml"),
        overrides=["diffusion.kind=uniform", "denoiser.positions=action", "trainer.ema=0.5", "trainer.snapshots=[1,3]"],
    )
    assert read_run_info(ablation)["config"]["diffusion"]["kind"] == "uniform"
    # snapshots: a model file per step, each loading as a generator, the weights differing between steps
    from m2d2m.generators.m2d2m.generator import M2D2MGenerator

    seconds = json.loads((ablation / "snapshots" / "seconds.json").read_text(encoding="utf-8"))
    assert sorted(seconds) == ["1", "3"] and 0 < seconds["1"] < seconds["3"]
    snapshots = [M2D2MGenerator.load(ablation / "snapshots" / f"model-step{step}.pt") for step in (1, 3)]
    assert snapshots[0].checkpoint.denoiser.config.positions == "action"
    first, last = (dict(g.checkpoint.denoiser.state_dict()) for g in snapshots)
    assert any(not torch.equal(first[name], last[name]) for name in first)
    # the weight average is what validation and the checkpoints hold: the saved state is not the raw one
    final = torch.load(ablation / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    averaged = final["state_dict"]["denoiser.head.bias"]
    assert not torch.equal(averaged, final["current_model_state"]["denoiser.head.bias"])
    with pytest.raises(UserError, match="trainer.snapshots must be a list of steps"):
        train("m2d2m", str(project / "diffusion.yaml"), overrides=["trainer.snapshots=[9]"])
    with pytest.raises(UserError, match=r"trainer.ema must be a decay in \[0, 1\)"):
        train("m2d2m", str(project / "diffusion.yaml"), overrides=["trainer.ema=1.5"])


def test_resume_after_a_kill_continues_at_the_same_step(project):
    (project / "diffusion.yaml").write_text(yaml.safe_dump(TINY_DIFFUSION), encoding="utf-8")
    train_vq(str(project / "tiny.yaml"))
    with pytest.raises(RuntimeError, match="killed"):
        train("m2d2m", str(project / "diffusion.yaml"), extra_callbacks=[KillAt(step=3)])
    run_dir = next((project / "runs" / "tiny" / "m2d2m").iterdir())
    assert torch.load(run_dir / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)["global_step"] == 2
    started = RecordStart()
    resumed = train("m2d2m", str(project / "diffusion.yaml"), resume=True, extra_callbacks=[started])
    assert resumed.resolve() == run_dir.resolve() and started.step == 2
    assert read_run_info(run_dir)["status"] == "finished" and (run_dir / "model.pt").exists()


class PoisonWeightsAt(pl.Callback):
    def __init__(self, step: int) -> None:
        self.step = step

    def on_train_batch_start(self, trainer, module, batch, batch_idx) -> None:
        if trainer.global_step == self.step:
            with torch.no_grad():
                module.denoiser.head.bias.fill_(float("nan"))


def test_a_nan_loss_stops_the_run_and_keeps_the_last_good_checkpoint(project):
    (project / "diffusion.yaml").write_text(yaml.safe_dump(TINY_DIFFUSION), encoding="utf-8")
    train_vq(str(project / "tiny.yaml"))
    with pytest.raises(UserError, match=r"the training loss is nan at step 3.*last good checkpoint"):
        train("m2d2m", str(project / "diffusion.yaml"), extra_callbacks=[PoisonWeightsAt(step=3)])
    run_dir = next((project / "runs" / "tiny" / "m2d2m").iterdir())
    assert read_run_info(run_dir)["status"] == "failed"
    last = torch.load(run_dir / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert last["global_step"] == 2
    assert all(
        torch.isfinite(v).all() for v in last["state_dict"].values() if torch.is_tensor(v) and v.is_floating_point()
    )
