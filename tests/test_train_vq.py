"""`m2d2m train-vq` end to end on a tiny dataset: MLflow contents, resume after a kill, NaN stop."""

import copy
from pathlib import Path

import lightning.pytorch as pl
import mlflow
import pytest
import torch

from m2d2m.networks.vqvae import load_vq
from orchestration.errors import UserError
from orchestration.recipes.vq import train_vq
from orchestration.runs import latest_run, read_run_info


class KillAt(pl.Callback):
    """Stands in for a killed process: fails hard in the middle of training."""

    def __init__(self, step: int) -> None:
        self.step = step

    def on_train_batch_start(self, trainer, module, batch, batch_idx) -> None:
        if trainer.global_step == self.step:
            raise RuntimeError("killed")


class RecordStart(pl.Callback):
    def on_train_start(self, trainer, module) -> None:
        self.step = trainer.global_step
        self.optimizer_state = copy.deepcopy(trainer.optimizers[0].state_dict())  # live tensors move on


def test_a_run_is_tracked_in_mlflow_and_exports_a_model_file(project):
    run_dir = train_vq(str(project / "tiny.yaml"))
    info = read_run_info(run_dir)
    assert info["status"] == "finished" and latest_run("tiny", "vq", "make train-vq") == run_dir
    model, normalizer, meta = load_vq(run_dir / "vq.pt")
    assert model.config.codebook_size == 16 and meta["skeleton"] == "t2m" and meta["extra"]["run"] == run_dir.name
    assert normalizer.mean.shape == (263,)

    mlflow.set_tracking_uri(f"sqlite:///{project / 'mlflow.db'}")
    run = mlflow.get_run(info["mlflow_run_id"])
    assert run.info.status == "FINISHED"
    assert run.data.params["model.codebook_size"] == "16" and run.data.params["optim.lr"] == "0.001"
    assert run.data.tags["dataset"] == "tiny" and run.data.tags["stage"] == "vq"
    for metric in (
        "train/loss",
        "train/perplexity",
        "train/active_codes",
        "val/mpjpe_mm",
        "val/mpjpe_root_aligned_mm",
        "val/recon_loss",
        "val/active_codes",
    ):
        assert metric in run.data.metrics, metric
    client = mlflow.MlflowClient()
    model_files = {Path(a.path).name for a in client.list_artifacts(run.info.run_id, "model")}
    assert {"vq.pt", "best.ckpt", "last.ckpt", "config.yaml", "stats.npz"} <= model_files
    previews = client.list_artifacts(run.info.run_id, "previews")
    assert previews and all(a.path.endswith(".gif") for a in previews)
    assert mlflow.get_experiment(run.info.experiment_id).name == "tiny/vq"


def test_resume_after_a_kill_continues_at_the_same_step_with_the_optimizer_state(project):
    with pytest.raises(RuntimeError, match="killed"):
        train_vq(str(project / "tiny.yaml"), extra_callbacks=[KillAt(step=4)])
    run_dir = next((project / "runs" / "tiny" / "vq").iterdir())
    last = torch.load(run_dir / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert last["global_step"] == 3  # written by the validation after step 3

    started = RecordStart()
    resumed = train_vq(str(project / "tiny.yaml"), resume=True, extra_callbacks=[started])
    assert resumed.resolve() == run_dir.resolve() and started.step == 3
    saved_state = last["optimizer_states"][0]["state"]
    for key, value in saved_state[0].items():
        assert torch.equal(started.optimizer_state["state"][0][key], value), key
    assert read_run_info(run_dir)["status"] == "finished"
    assert torch.load(run_dir / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)["global_step"] == 6
    with pytest.raises(UserError, match="already finished"):
        train_vq(str(project / "tiny.yaml"), resume=True)


def test_resume_of_a_named_run_continues_that_run_not_the_newest(project):
    """`--resume RUN`: a bench resumes the run it started even when another run began later."""
    for _ in range(2):
        with pytest.raises(RuntimeError, match="killed"):
            train_vq(str(project / "tiny.yaml"), extra_callbacks=[KillAt(step=4)])
    first, newest = sorted((project / "runs" / "tiny" / "vq").iterdir(), key=lambda p: read_run_info(p)["started"])
    assert train_vq(str(project / "tiny.yaml"), resume=first.name).resolve() == first.resolve()
    assert read_run_info(first)["status"] == "finished" and read_run_info(newest)["status"] != "finished"
    with pytest.raises(UserError, match="no vq run 'elsewhere'"):
        train_vq(str(project / "tiny.yaml"), resume="elsewhere")


class PoisonAt(pl.Callback):
    def __init__(self, step: int) -> None:
        self.step = step

    def on_train_batch_start(self, trainer, module, batch, batch_idx) -> None:
        if trainer.global_step == self.step:
            batch["motion"][:] = float("nan")


def test_a_nan_loss_stops_the_run_and_keeps_the_last_good_checkpoint(project):
    with pytest.raises(UserError, match=r"the training loss is nan at step 4.*last good checkpoint"):
        train_vq(str(project / "tiny.yaml"), extra_callbacks=[PoisonAt(step=4)])
    run_dir = next((project / "runs" / "tiny" / "vq").iterdir())
    assert read_run_info(run_dir)["status"] == "failed"
    last = torch.load(run_dir / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert last["global_step"] == 3
    assert all(torch.isfinite(v).all() for v in last["state_dict"].values() if v.is_floating_point())


def test_a_missing_dataset_says_what_to_run(project):
    with pytest.raises(UserError, match="m2d2m data"):
        train_vq(str(project / "tiny.yaml"), overrides=[f"data.dir={project / 'nowhere'}"])


def test_a_smoke_run_shorter_than_one_validation_interval_still_finishes(project):
    """max_steps below val_every_steps (3 in the tiny config): the run validates once at its end,
    keeps a best checkpoint and exports its model file (issue: it used to die loading '')."""
    run_dir = train_vq(str(project / "tiny.yaml"), overrides=["trainer.max_steps=2"])
    assert read_run_info(run_dir)["status"] == "finished" and (run_dir / "vq.pt").is_file()
    assert (run_dir / "checkpoints" / "best.ckpt").is_file()


@pytest.mark.parametrize("override", ["trainer.max_steps=0", "trainer.val_every_steps=-1", "trainer.max_steps=2.5"])
def test_step_counts_no_run_can_use_are_refused_before_a_run_exists(project, override):
    with pytest.raises(UserError, match=f"{override.split('=')[0]} must be a whole number of steps"):
        train_vq(str(project / "tiny.yaml"), overrides=[override])
    assert not (project / "runs").exists()
