"""Throughput of ``m2d2m data`` on the synthetic corpus: the per-motion stages (read, validate,
features + mirror, language) with 1 and 2 Ray workers, and the whole command's wall time.

Run with ``make bench``; prints a Markdown table. The corpus is generated first when absent.
"""

from __future__ import annotations

import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import ray

from pipelines.corpora import list_corpus
from pipelines.features import DataConfig, run_stages

ROOT = Path(__file__).resolve().parents[1]
RAW = ROOT / "data" / "raw" / "synthetic"


def _m2d2m(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "orchestration.cli", *args], check=True, cwd=ROOT, stdout=subprocess.DEVNULL)


def stage_throughput(workers: int, rows: list[dict]) -> float:
    """Motions per second through the per-motion stages (Ray already started, results drained)."""
    config = DataConfig(dataset="synthetic", raw=str(RAW), out="unused", workers=workers)
    started = time.perf_counter()
    consumed = sum(1 for _ in run_stages(config, rows, make_mirror=True))
    elapsed = time.perf_counter() - started
    assert consumed >= len(rows)
    return len(rows) / elapsed


def main() -> None:
    if not (RAW / "corpus.json").exists():
        _m2d2m("synthesize", "--out", str(RAW))
    rows = list_corpus(RAW)
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="ERROR")
    ray.data.DataContext.get_current().enable_progress_bars = False
    stage_throughput(2, rows[:64])  # warm up the workers
    one = stage_throughput(1, rows)
    two = stage_throughput(2, rows)
    ray.shutdown()
    with tempfile.TemporaryDirectory() as out:
        started = time.perf_counter()
        _m2d2m("data", "--raw", str(RAW), "--out", out, "--force")
        whole = time.perf_counter() - started
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores; corpus: {len(rows)} motions (+ mirrors)")
    print("| measurement | value |\n| --- | --- |")
    print(f"| per-motion stages, 1 worker | {one:.0f} motions/s |")
    print(f"| per-motion stages, 2 workers | {two:.0f} motions/s ({two / one:.2f}x) |")
    print(f"| whole `m2d2m data` (Ray start, stages, shards, stats, tagger) | {whole:.1f} s |")


if __name__ == "__main__":
    main()
