"""How a loader hands its batches to training: the rank it serves, how many worker processes make
them and whether they are pinned, from the device and the cores (docs/training.md, "Data loading")."""

from __future__ import annotations

import os
from dataclasses import dataclass

import lightning.pytorch as pl
import torch
import webdataset as wds

AUTO_WORKERS = "auto"
MOST_AUTO_WORKERS = 8


def rank_and_world_size(trainer: pl.Trainer | None) -> tuple[int, int]:
    """The trainer's rank and world size when attached, else what webdataset's node splitter sees
    (env RANK and WORLD_SIZE, then torch.distributed)."""
    if trainer is not None:
        return trainer.global_rank, trainer.world_size
    rank, world_size, _, _ = wds.utils.pytorch_worker_info()
    return rank, world_size


def require_workers(num_workers: int | str) -> None:
    """Refuse a worker count that is neither a count of processes (0: none) nor ``auto``."""
    if num_workers != AUTO_WORKERS and not (
        isinstance(num_workers, int) and not isinstance(num_workers, bool) and num_workers >= 0
    ):
        raise ValueError(f"num_workers must be 0 or more worker processes, or {AUTO_WORKERS!r}; got {num_workers!r}")


def usable_cpus() -> int:
    """Cores this process may run on (its affinity, which a cluster's scheduler narrows)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


@dataclass(frozen=True)
class LoaderFeed:
    """How a DataLoader hands its batches over: made by ``num_workers`` worker processes (0: by the
    training process between steps), in pinned (page-locked) memory when ``pin_memory``, from which
    Lightning's ``non_blocking`` copy to the GPU runs asynchronously."""

    num_workers: int
    pin_memory: bool


def loader_feed(num_workers: int | str, device: torch.device, cpus: int, processes: int) -> LoaderFeed:
    """The feed of a loader whose batches train on ``device``, one of ``processes`` training
    processes (DDP ranks) sharing ``cpus`` cores. ``auto`` on a GPU: the cores left after the
    training processes, shared among them, at least one and at most ``MOST_AUTO_WORKERS`` a
    process (the paper configs' count before ``auto``; one process alone already makes token
    batches faster than a paper-size step takes them, ``bench/loader.py``, docs/training.md); on a
    CPU: none, since the step's own threads keep every core busy and loading in the training
    process measured fastest on 2 cores (``bench/train_vq.py``). A count is taken as it is. Memory
    is pinned for a CUDA device only."""
    on_gpu = device.type == "cuda"
    if num_workers != AUTO_WORKERS:
        workers = int(num_workers)
    elif on_gpu:
        workers = max(1, min(MOST_AUTO_WORKERS, (cpus - processes) // processes))
    else:
        workers = 0
    return LoaderFeed(workers, pin_memory=on_gpu)
