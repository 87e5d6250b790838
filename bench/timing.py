"""Wall-clock timing for the benchmarks that also holds on a GPU (kernels are asynchronous)."""

from __future__ import annotations

import time
from collections.abc import Callable

import torch


def wall_time(run: Callable[[], object], device: torch.device) -> float:
    """Seconds one call of ``run`` takes, waiting for the device to finish its queued work."""
    if device.type == "cuda":
        torch.cuda.synchronize()
    started = time.perf_counter()
    run()
    if device.type == "cuda":
        torch.cuda.synchronize()
    return time.perf_counter() - started


def call_times(run: Callable[[], object], warmup: int, repeats: int, device: torch.device) -> list[float]:
    """Wall times of ``repeats`` calls after ``warmup`` untimed ones (first calls allocate and pick
    kernels), in seconds."""
    for _ in range(warmup):
        run()
    return [wall_time(run, device) for _ in range(repeats)]


def best_time(run: Callable[[], object], repeats: int, device: torch.device) -> float:
    """Best wall time of ``repeats`` calls after one warm-up call, in seconds."""
    return min(call_times(run, 1, repeats, device))
