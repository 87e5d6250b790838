"""Wall-clock timing for the benchmarks that also holds on a GPU (kernels are asynchronous)."""

from __future__ import annotations

import time
from collections.abc import Callable

import torch
from tqdm import tqdm


def wall_time(run: Callable[[], object], device: torch.device) -> float:
    """Seconds one call of ``run`` takes, waiting for the device to finish its queued work."""
    if device.type == "cuda":
        torch.cuda.synchronize()
    started = time.perf_counter()
    run()
    if device.type == "cuda":
        torch.cuda.synchronize()
    return time.perf_counter() - started


def best_time(run: Callable[[], object], repeats: int, device: torch.device) -> float:
    """Best wall time of ``repeats`` calls after one warm-up call, in seconds."""
    run()
    return min(wall_time(run, device) for _ in range(repeats))


def interleaved_times(runs: list[Callable[[], object]], warmup: int, repeats: int, device: torch.device,
                      desc: str = "timing") -> list[list[float]]:
    """Each run's wall times over ``repeats`` rounds that call every run once, after ``warmup``
    untimed calls of each (first calls allocate and pick kernels), in seconds: on a shared
    machine, load that comes and goes then slows every run alike rather than all the calls of a few."""
    with tqdm(total=len(runs) * (warmup + repeats), desc=desc, unit="call") as bar:
        for run in runs:
            for _ in range(warmup):
                run()
                bar.update()
        times: list[list[float]] = [[] for _ in runs]
        for _ in range(repeats):
            for run, collected in zip(runs, times):
                collected.append(wall_time(run, device))
                bar.update()
    return times
