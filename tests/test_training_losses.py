"""What every training step does with its loss (training/losses.py): the per-quarter averages
against hand-computed ones, both ways of numbering t, and the stop on a non-finite loss."""

from __future__ import annotations

import math

import pytest
import torch

from training.losses import NonFiniteLossError, check_finite, log_by_quarter


class Recorder:
    def __init__(self) -> None:
        self.logged: dict[str, tuple[float, int]] = {}

    def log(self, name: str, value: torch.Tensor, batch_size: int, **options: object) -> None:
        self.logged[name] = (float(value), batch_size)


def test_a_gaussian_processes_quarters_from_zero():
    recorder = Recorder()
    t = torch.tensor([0, 249, 250, 999, 998])
    log_by_quarter(recorder, "val/loss", torch.tensor([1.0, 3.0, 5.0, 7.0, 9.0]), t, first=0, steps=1000)
    assert recorder.logged == {
        "val/loss_t0-249": (2.0, 2),
        "val/loss_t250-499": (5.0, 1),
        "val/loss_t750-999": (8.0, 2),
    }  # no sample in the third quarter: nothing logged


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


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_a_non_finite_loss_stops_training_with_its_step(value):
    check_finite(torch.tensor(1.5), 3)
    with pytest.raises(NonFiniteLossError, match="at step 7"):
        check_finite(torch.tensor(value), 7)
