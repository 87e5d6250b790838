"""The training loaders against what a paper-size step consumes (issue 37, §3): the token
sequences of M2D2M and MMM, MotionDiffuse's caption/motion features and the VQ-VAE's motion
windows, each at a paper-size batch and with 0, 1, 2, 4 and 8 loader workers (as many as the
machine has cores): batches and samples a second, seconds to the first batch, and the fraction of
the batches' positions that is padding. Each DataModule gets a Lightning trainer on this machine's
GPU (or CPU) attached, as in training, so on a GPU its batches are pinned.

A loader keeps up when it makes a step's samples faster than the step takes. The step times are
M2D2M's paper-size training step on an H200 (``bench/discrete_diffusion.py``, issue 37): 69 ms at
batch 32 and 136 ms at batch 256, the only paper-size steps measured so far.

    python bench/loader.py                        # data/synthetic and its newest token set
    python bench/loader.py --data DIR --tokens DIR --workers 0,2,8
    PYTHONPATH=/older/checkout python bench/loader.py --data DIR   # its loaders and configs, same data

Without ``data/synthetic`` (``make data``) the bench builds the embedded corpus in a temporary
folder first, and without a token set it tokenizes the data with an untrained VQ-VAE (the codes
differ, their number per clip does not). Prints a Markdown table.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import lightning.pytorch as pl
import torch
import yaml

import training
from m2d2m.layout import STATS, read_manifest
from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.networks.vqvae import VQ_FORMAT, MotionVQVAE, VQConfig
from training.data.motion_windows import MotionWindowDataModule
from training.data.tokens import TokenDataModule
from training.evaluator_module import CaptionMotionDataModule

ROOT = Path(training.__file__).resolve().parents[1]  # the checkout whose loaders and configs are measured
STEPS_PER_EPOCH = 100_000  # no epoch ends (and restarts the workers' streams) while measuring
M2D2M_STEP_SECONDS = {32: 0.069, 256: 0.136}  # paper-size training step on an H200, issue 37


def data_settings(stage: str, config: str) -> dict:
    """The data section of ``configs/<stage>/<config>.yaml``."""
    return yaml.safe_load((ROOT / "configs" / stage / f"{config}.yaml").read_text(encoding="utf-8"))["data"]


def bucketing(data: dict) -> dict:
    """The loader's ``bucket`` as the config sets it, when it does (an older checkout's do not)."""
    return {"bucket": data["bucket"]} if "bucket" in data else {}


@dataclass(frozen=True)
class LoaderCase:
    """One training loader at one batch size: ``make(workers)`` builds its DataModule."""

    name: str
    batch_size: int
    make: Callable[[int], pl.LightningDataModule]
    step_seconds: float | None


def loader_cases(data: Path, tokens: Path) -> list[LoaderCase]:
    """The token loader at the two batches whose step was timed, the feature loader at
    MotionDiffuse's paper batch (the demo's frame limits, which fit the embedded corpus) and the
    window loader at the VQ-VAE's paper batch and window; bucketed as the paper configs say."""
    tokens_bucket = bucketing(data_settings("m2d2m", "humanml3d"))
    demo, features = data_settings("motiondiffuse", "demo"), data_settings("motiondiffuse", "humanml3d")
    vq = data_settings("vq", "humanml3d")
    feature_batch, window_batch, window = features["batch_size"], vq["batch_size"], vq["window"]

    def token_case(batch: int) -> LoaderCase:
        return LoaderCase(
            "tokens (M2D2M, MMM)",
            batch,
            lambda workers: TokenDataModule(
                tokens, batch_size=batch, num_workers=workers, steps_per_epoch=STEPS_PER_EPOCH, **tokens_bucket
            ),
            M2D2M_STEP_SECONDS[batch],
        )

    return [
        token_case(32),
        token_case(256),
        LoaderCase(
            "features (MotionDiffuse)",
            feature_batch,
            lambda workers: CaptionMotionDataModule(
                data,
                batch_size=feature_batch,
                num_workers=workers,
                steps_per_epoch=STEPS_PER_EPOCH,
                min_frames=demo["min_frames"],
                max_frames=demo["max_frames"],
                **bucketing(features),
            ),
            None,
        ),
        LoaderCase(
            "windows (VQ-VAE)",
            window_batch,
            lambda workers: MotionWindowDataModule(
                data, window=window, batch_size=window_batch, num_workers=workers, steps_per_epoch=STEPS_PER_EPOCH
            ),
            None,
        ),
    ]


@dataclass(frozen=True)
class Measured:
    """One case's seconds to its first batch, batches a second, and padded fraction of positions."""

    first_batch_s: float
    batches_per_s: float
    padding: float


def padded_positions(batch: dict) -> tuple[int, int]:
    """(padding, all) positions of a batch: padded sequences carry their ``lengths``."""
    if "lengths" not in batch:
        return 0, 1
    lengths = batch["lengths"]
    total = len(lengths) * int(lengths.max())
    return total - int(lengths.sum()), total


def measure(datamodule: pl.LightningDataModule, trainer: pl.Trainer, warmup: int, batches: int) -> Measured:
    """Seconds from asking for the loader to its first batch (the DataModule's survey of the train
    clips, worker start-up, buffers filling), then the rate of ``batches`` after ``warmup`` more,
    and the padding of those."""
    datamodule.trainer = trainer  # as Trainer.fit attaches it: the loader sees the device
    started = time.perf_counter()
    iterator = iter(datamodule.train_dataloader())
    next(iterator)
    first = time.perf_counter() - started
    for _ in range(warmup):
        next(iterator)
    padding = positions = 0
    started = time.perf_counter()
    for _ in range(batches):
        padded, total = padded_positions(next(iterator))
        padding, positions = padding + padded, positions + total
    rate = batches / (time.perf_counter() - started)
    del iterator  # stops the workers before the next case starts its own
    return Measured(first, rate, padding / positions)


def newest_token_set(data: Path) -> Path | None:
    """The token set ``m2d2m tokenize`` wrote last for ``data``, if any."""
    manifests = sorted((data / "tokens").glob("*/manifest.json"), key=lambda path: path.stat().st_mtime)
    return manifests[-1].parent if manifests else None


def build_corpus_data(folder: Path, clips: int, workers: int) -> Path:
    """The embedded corpus of ``clips`` clips, processed into shards as ``make data`` does."""
    from pipelines.features import DataConfig, build_dataset
    from pipelines.synthetic import generate_corpus

    generate_corpus(folder / "raw", clips=clips, workers=workers)
    build_dataset(DataConfig(dataset="synthetic", raw=str(folder / "raw"), out=str(folder / "data"), workers=workers))
    return folder / "data"


def untrained_tokens(data: Path, folder: Path, workers: int) -> Path:
    """``data`` tokenized by an untrained small VQ-VAE with the paper's 4 frames a token."""
    from pipelines.tokenize import tokenize_dataset

    manifest = read_manifest(data)
    torch.manual_seed(0)
    model = MotionVQVAE(VQConfig(feature_dim=int(manifest["feature_dim"]), width=64, depth=1, code_dim=32))
    normalizer, skeleton = Normalizer.load(data / STATS), str(manifest["skeleton"])
    VQ_FORMAT.save(folder / "vq.pt", model=model.eval(), normalizer=normalizer, skeleton=skeleton, extra={})
    tokenize_dataset(data, folder / "vq.pt", folder / "tokens", workers=workers)
    return folder / "tokens"


def stop_ray() -> None:
    """The builds' local Ray, stopped before loader workers fork from this process."""
    import ray

    if ray.is_initialized():
        ray.shutdown()


def report(rows: list[tuple[LoaderCase, int, Measured]], device: str) -> str:
    """The Markdown table: a row per loader, batch and worker count."""
    lines = [
        f"device: {device}",
        "",
        "| loader | batch | workers | first batch (s) | batches/s | samples/s | padding "
        "| a paper-size M2D2M step needs (samples/s) | keeps up |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for case, workers, measured in rows:
        samples = measured.batches_per_s * case.batch_size
        needs = "—" if case.step_seconds is None else f"{case.batch_size / case.step_seconds:.0f}"
        keeps_up = (
            "—" if case.step_seconds is None else ("yes" if measured.batches_per_s * case.step_seconds >= 1 else "no")
        )
        lines.append(
            f"| {case.name} | {case.batch_size} | {workers} | {measured.first_batch_s:.2f} | "
            f"{measured.batches_per_s:.1f} | {samples:.0f} | {measured.padding:.1%} | {needs} | {keeps_up} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=ROOT / "data" / "synthetic", help="a processed dataset")
    parser.add_argument("--tokens", type=Path, help="its token set (default: the newest under DATA/tokens)")
    parser.add_argument("--workers", default="0,1,2,4,8", help="loader worker counts, up to the cores there are")
    # bucketed batches leave in pools of 8: time whole pools, or a pool's last batches look free
    parser.add_argument("--warmup", type=int, default=16, help="batches after the first before timing")
    parser.add_argument("--batches", type=int, default=48, help="batches timed per case (several pools of 8)")
    parser.add_argument("--clips", type=int, default=2000, help="clips of a corpus built when DATA is missing")
    args = parser.parse_args()
    # training.data.feed.usable_cpus, written out: an older checkout measured through PYTHONPATH lacks it
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    worker_counts = [count for count in map(int, args.workers.split(",")) if count <= cpus]
    gpu = torch.cuda.is_available()
    with tempfile.TemporaryDirectory(prefix="bench-loader-") as scratch:
        data = (
            args.data if (args.data / "manifest.json").exists() else build_corpus_data(Path(scratch), args.clips, cpus)
        )
        tokens = args.tokens or newest_token_set(data) or untrained_tokens(data, Path(scratch), cpus)
        stop_ray()
        trainer = pl.Trainer(
            accelerator="gpu" if gpu else "cpu",
            devices=1,
            logger=False,
            enable_progress_bar=False,
            enable_checkpointing=False,
        )
        rows = [
            (case, workers, measure(case.make(workers), trainer, args.warmup, args.batches))
            for case in loader_cases(data, tokens)
            for workers in worker_counts
        ]
    device = torch.cuda.get_device_name() if gpu else "CPU"
    print(report(rows, f"{device}, {cpus} cores; data {data}, tokens {tokens}"))


if __name__ == "__main__":
    main()
