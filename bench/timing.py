"""Wall-clock timing for the benchmarks that also holds on a GPU (kernels are asynchronous), and how a
bench publishes what it measured."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

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


def interleaved_times(
    runs: list[Callable[[], object]], warmup: int, repeats: int, device: torch.device, desc: str = "timing"
) -> list[list[float]]:
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


def publish(
    out: Path,
    name: str,
    result: dict[str, Any],
    plot: Callable[[Path, dict[str, Any]], None],
    report: Callable[[dict[str, Any]], str],
) -> None:
    """Write a bench's ``<name>.json`` and ``<name>.png`` into ``out`` and print its Markdown report."""
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    plot(out / f"{name}.png", result)
    print(report(result))
    print(f"wrote {out / f'{name}.json'} and {out / f'{name}.png'}")
