"""What every training step does with its loss (training/losses.py): the per-quarter averages
against hand-computed ones, both ways of numbering t, and the stop on a non-finite loss, which
reads the device only at the steps Lightning logs (and so does the progress display)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import lightning.pytorch as pl
import pytest
import torch

from training.callbacks import LoggedLoss
from training.losses import FiniteLossGuard, NonFiniteLossError, log_by_quarter


class Recorder:
    def __init__(self) -> None:
        self.logged: dict[str, tuple[float, int]] = {}

    def log(self, name: str, value: torch.Tensor, batch_size: torch.Tensor, **options: object) -> None:
        assert options == {"on_step": False, "on_epoch": True}  # accumulated over the epoch, read at its end
        self.logged[name] = (float(value), int(batch_size))


def test_a_gaussian_processes_quarters_from_zero():
    recorder = Recorder()
    t = torch.tensor([0, 249, 250, 999, 998])
    log_by_quarter(recorder, "val/loss", torch.tensor([1.0, 3.0, 5.0, 7.0, 9.0]), t, first=0, steps=1000)
    assert recorder.logged == {
        "val/loss_t0-249": (2.0, 2),
        "val/loss_t250-499": (5.0, 1),
        "val/loss_t500-749": (0.0, 0),  # no sample in the third quarter: it weighs nothing in the epoch's mean
        "val/loss_t750-999": (8.0, 2),
    }


def test_a_discrete_processes_quarters_from_one_cover_every_step_once():
    recorder = Recorder()
    t = torch.arange(1, 11)
    log_by_quarter(recorder, "train/vlb", t.double(), t, first=1, steps=10)
    assert recorder.logged == {
        "train/vlb_t1-3": (2.0, 3),
        "train/vlb_t4-5": (4.5, 2),
        "train/vlb_t6-8": (7.0, 3),
        "train/vlb_t9-10": (9.5, 2),
    }


class PoisonedAt(FiniteLossGuard):
    """One weight, whose loss is ``value`` at training step ``step``, and from then on it stays so."""

    def __init__(self, step: int, value: float = math.nan) -> None:
        super().__init__()
        self.weight = torch.nn.Parameter(torch.ones(1))
        self.step, self.value, self.steps_run = step, value, []

    def training_step(self, batch: torch.Tensor, batch_idx: int) -> torch.Tensor:
        self.steps_run.append(self.global_step)
        loss = (self.weight * batch).pow(2).mean() * (self.value if self.global_step >= self.step else 1.0)
        self.guard_finite(loss)
        return loss

    def configure_optimizers(self) -> torch.optim.Optimizer:
        return torch.optim.SGD(self.parameters(), lr=0.1)


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_a_non_finite_loss_is_raised_at_the_next_logging_step_and_before_any_checkpoint(value, tmp_path):
    module = PoisonedAt(step=2, value=value)
    trainer = pl.Trainer(
        max_steps=10, log_every_n_steps=4, logger=False, enable_checkpointing=False, enable_progress_bar=False
    )
    loader = torch.utils.data.DataLoader(torch.ones(10, 3), batch_size=None)
    with pytest.raises(NonFiniteLossError, match=f"the training loss is {value} at step 2"):  # the first one
        trainer.fit(module, train_dataloaders=loader)
    assert module.steps_run == [0, 1, 2, 3]  # noted on the device at step 2, read after step 4's optimiser step
    with pytest.raises(NonFiniteLossError):
        trainer.save_checkpoint(tmp_path / "after.ckpt")
    assert not (tmp_path / "after.ckpt").exists()


def test_the_progress_display_reads_the_loss_only_at_the_steps_lightning_logs():
    shown, loss = [], LoggedLoss()
    for step in range(1, 8):
        loss.update(SimpleNamespace(log_every_n_steps=3, global_step=step, callback_metrics={"train/loss": step / 10}))
        shown.append(loss.value)
    assert shown == [None, None, 0.3, 0.3, 0.3, 0.6, 0.6]
    never = LoggedLoss()
    never.update(SimpleNamespace(log_every_n_steps=0, global_step=3, callback_metrics={"train/loss": 1.0}))
    assert never.value is None
