"""Previews are drawn off the training path (training/callbacks.py, Drawing): training goes on
while a picture is drawn, every picture is logged to MLflow by the end of training, and a failed
drawing fails the run as it did drawn in place."""

from __future__ import annotations

import time
from pathlib import Path

import lightning.pytorch as pl
import pytest
import torch
from lightning.pytorch.loggers import MLFlowLogger
from torch.utils.data import DataLoader

from training.callbacks import Drawing

pytestmark = pytest.mark.slow  # trains and spawns the drawing process


def picture_after(flag: Path, path: Path) -> Path:
    """A picture drawn only once training has written ``flag`` (at a step after the one that asked
    for it): drawn in the training process, it would wait for a step that never comes."""
    deadline = time.monotonic() + 120
    while not flag.exists():
        if time.monotonic() > deadline:
            raise TimeoutError("training did not go on while the picture was drawn")
        time.sleep(0.05)
    path.write_bytes(b"GIF89a")
    return path


def broken_picture(path: Path) -> Path:
    raise ValueError("no frames to draw")


class Tiny(pl.LightningModule):
    def __init__(self, flag: Path, at_step: int) -> None:
        super().__init__()
        self.weight = torch.nn.Parameter(torch.zeros(1))
        self.flag, self.at_step = flag, at_step

    def training_step(self, batch, batch_idx):
        if self.global_step == self.at_step:
            self.flag.touch()
        return (self.weight * batch).sum()

    def validation_step(self, batch, batch_idx):
        return None

    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), lr=0.1)


class Preview(Drawing):
    def __init__(self, draw_args) -> None:
        super().__init__()
        self.draw_args = draw_args
        self.asked = False

    def on_validation_epoch_end(self, trainer, module) -> None:
        super().on_validation_epoch_end(trainer, module)
        if not self.asked:
            self.asked = True
            self.draw(*self.draw_args)


def _fit(tmp_path: Path, preview: Preview, flag: Path) -> MLFlowLogger:
    logger = MLFlowLogger(experiment_name="drawing", tracking_uri=f"sqlite:///{tmp_path / 'mlflow.db'}")
    trainer = pl.Trainer(
        accelerator="cpu",
        max_steps=6,
        val_check_interval=2,
        limit_val_batches=1,
        num_sanity_val_steps=0,
        logger=logger,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=[preview],
        default_root_dir=tmp_path,
    )
    data = DataLoader([torch.ones(1)] * 6, batch_size=None)
    trainer.fit(Tiny(flag, at_step=4), data, DataLoader([torch.ones(1)], batch_size=None))
    return logger


def test_training_goes_on_while_a_preview_is_drawn_and_every_preview_is_logged_by_the_end(tmp_path):
    flag, picture = tmp_path / "step-4", tmp_path / "preview.gif"
    logger = _fit(tmp_path, Preview((picture_after, flag, picture)), flag)
    assert picture.read_bytes() == b"GIF89a"
    logged = logger.experiment.list_artifacts(logger.run_id, "previews")
    assert [Path(artifact.path).name for artifact in logged] == ["preview.gif"]


def test_a_drawing_that_fails_fails_training(tmp_path):
    with pytest.raises(ValueError, match="no frames to draw"):
        _fit(tmp_path, Preview((broken_picture, tmp_path / "x.gif")), tmp_path / "flag")
