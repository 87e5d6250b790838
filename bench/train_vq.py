"""VQ-VAE training throughput: the paper-size model (T2M-GPT's) at batch 32 on this CPU (batch
256 on a GPU when there is one), through the real Lightning loop with the WebDataset loader, and
the loader alone. T2M-GPT's own training runs at 52 samples/s at batch 32 with 2 threads here.

Run with ``make bench`` after ``make data``; prints a Markdown table.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import lightning.pytorch as pl
import torch

from m2d2m.networks.vqvae import VQConfig
from training.data.motion_windows import MotionWindowDataModule
from training.vq_module import VQVAEModule

DATA = Path(__file__).resolve().parents[1] / "data" / "synthetic"
WARMUP, MEASURED = 5, 30


class _StepTimer(pl.Callback):
    """Wall time between the end of batch WARMUP and the end of the last batch."""

    def __init__(self) -> None:
        self.started = self.finished = 0.0

    def on_train_batch_end(self, trainer, module, outputs, batch, batch_idx) -> None:
        if trainer.global_step == WARMUP:
            self.started = time.perf_counter()
        self.finished = time.perf_counter()


def loader_throughput(datamodule: MotionWindowDataModule, batches: int) -> float:
    iterator = iter(datamodule.train_dataloader())
    next(iterator)  # worker start-up is not throughput
    started = time.perf_counter()
    for _ in range(batches):
        next(iterator)
    return batches * datamodule.batch_size / (time.perf_counter() - started)


def training_throughput(datamodule: MotionWindowDataModule, gpu: bool) -> float:
    defaults = VQConfig().to_dict()
    defaults.pop("feature_dim")
    module = VQVAEModule(
        defaults,
        {
            "lr": 2e-4,
            "betas": [0.9, 0.99],
            "weight_decay": 0.0,
            "warmup_steps": 1000,
            "milestones": [200000],
            "gamma": 0.05,
        },
        {"recon": 1.0, "joint": 0.5, "commit": 0.02},
        datamodule.feature_dim,
        datamodule.skeleton,
    )
    module.set_normalizer(datamodule.normalizer)
    timer = _StepTimer()
    trainer = pl.Trainer(
        max_steps=WARMUP + MEASURED,
        accelerator="gpu" if gpu else "cpu",
        devices=1,
        precision="bf16-mixed" if gpu else "32-true",
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        limit_val_batches=0,
        callbacks=[timer],
    )
    trainer.fit(module, datamodule=datamodule)
    return MEASURED * datamodule.batch_size / (timer.finished - timer.started)


def main() -> None:
    gpu = torch.cuda.is_available()
    torch.set_num_threads(2)
    batch = 256 if gpu else 32
    workers = min(8, os.cpu_count() or 1) if gpu else 2
    device = torch.cuda.get_device_name() if gpu else f"CPU, {os.cpu_count()} cores, 2 torch threads"
    print(
        f"device: {device}; batch {batch}, window 64; paper-size VQ-VAE "
        f"(width {VQConfig().width}, {VQConfig().codebook_size} codes)"
    )
    print("| measurement | samples/s |\n| --- | --- |")
    for num_workers in sorted({0, workers}):
        datamodule = MotionWindowDataModule(
            DATA, window=64, batch_size=batch, num_workers=num_workers, steps_per_epoch=10_000
        )
        training = training_throughput(datamodule, gpu)
        loader = loader_throughput(datamodule, batches=100)
        print(f"| training, Lightning loop with the WebDataset loader, {num_workers} loader workers | {training:.1f} |")
        print(
            f"| data loader alone, {num_workers} workers | {loader:.0f} ({loader / training:.0f}× what training consumes) |"
        )


if __name__ == "__main__":
    main()
