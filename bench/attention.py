"""Linear against softmax attention: time and memory against sequence length up to 32 actions' worth
of frames, for MotionDiffuse's claim that Efficient Attention (Shen et al. 2021) costs O(n·d²) where
softmax attention costs O(n²·d) (Zhang et al. 2022, §3.4, eq. 8; Table 3 ablates the two).

Two scopes, each with ``attention: linear`` (:func:`efficient_attention`) and ``softmax``
(:func:`softmax_attention`, PyTorch's scaled_dot_product_attention) at every length:

- ``attention``: one call of the attention function alone at the paper's size (width 512 in 8 heads
  of 64, batch 1, every key valid), q, k and v drawn once per length.
- ``network``: one forward pass of the whole :class:`MotionDiffuseTransformer` at the paper's size
  (8 layers of width 512, 8 heads, FFN 1024; a 4-layer text transformer of width 256 over 512-d
  token features), batch 1: one denoising step. The sentence (``TEXT_TOKENS`` tokens) is encoded once
  outside the timed call, as the sampler does once per run. Both kinds share one set of weights.

Lengths are ``--lengths-actions`` actions (1, 2, 4, 8, 16, 32) of ``--action-frames`` frames each
(98: 4.9 s at 20 fps, the median HumanML3D action the issue quotes; not derived here from the data.
HumanML3D's own totals, 14,616 motions in 28.59 h (Guo et al. 2022, §3), give a mean of 7.0 s =
141 frames, and its longest clip is 196 frames: pass either to see those). 32 actions of 98 frames
are 3,136 frames, 16 times the longest single pass (196) a HumanML3D model is trained on: the
question is what one pass over a whole long sequence would cost, as the time-varied method's
intervals stay one action each.

- **Time**: every (scope, kind, length) gets ``--warmup`` untimed calls, then ``--repeats`` timed
  ones, in interleaved rounds (``timing.interleaved_times``: load that comes and goes on a shared
  machine slows every setting alike); reported are the median and the range.
- **Memory**: each (scope, kind, length) runs once more in a fresh spawned process, which builds its
  inputs (and network), reads its peak resident set size (``getrusage(RUSAGE_SELF).ru_maxrss``),
  makes the one call and reads it again: the growth is the call's peak working memory beyond what
  was already held (activations, the attention matrix), plus a few MiB of first-call set-up (thread
  pools, kernel caches) that shows at small lengths. A fresh process so that no earlier, larger call
  has already raised the peak or left freed memory for the allocator to reuse.
- **Analytic**: the attention state one head group holds, in fp32 bytes: softmax's n × n
  probabilities per head (B·H·n²·4), what a kernel that materialises them allocates per layer, and
  linear attention's d × d global context F_g per head (B·H·d²·4, d = width / heads), independent
  of n. A fused softmax kernel (flash attention) may never hold the n × n matrix: then the measured
  growth stays below the analytic size while the time still grows as n². PyTorch 2.13's CPU kernel
  does so here: one 3,136-frame call at the paper's size grew the peak RSS by 10 MiB, against 300 MiB
  of analytic matrix (and 23 MiB for linear attention's softmaxed q, k and masked v).

CPU only (peak RSS is host memory).

    python bench/attention.py [--lengths-actions 1 2 4 8 16 32] [--action-frames 98] [--warmup 1] [--repeats 5]
                              [--network-max-actions 32] [--threads N] [--out runs/bench/attention]
                              [--width 512] [--heads 8] [--layers 8] [--text-dim 512] [--text-layers 4]

Writes ``attention.json`` and ``attention.png`` (time and memory against frames, log-log) into ``--out``
and prints Markdown. About 3 minutes on 2 cores by an estimate from single passes at up to 784 frames
(a paper-size pass of 3,136 frames: about 3 s linear, 7 s softmax on one thread); should it run longer,
``--network-max-actions`` caps the whole-network rows (the attention-call rows always reach the longest).
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import platform
import resource
import statistics
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from datetime import datetime
from functools import partial
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import torch
from timing import interleaved_times, publish
from tqdm import tqdm

from m2d2m.networks.motiondiffuse_transformer import (
    MotionDiffuseConfig,
    MotionDiffuseTransformer,
    efficient_attention,
    softmax_attention,
)

KINDS = ("linear", "softmax")  # MotionDiffuseConfig.attention's values, in plotting order
SCOPES = ("attention", "network")
ATTEND = {"linear": efficient_attention, "softmax": softmax_attention}
TEXT_TOKENS = 20  # tokens of the encoded sentence the decoder cross-attends to (a short caption)
FLOAT_BYTES = 4  # fp32
BATCH = 1


@dataclass(frozen=True)
class Size:
    """The network's sizes: the paper's by default (MotionDiffuseConfig's); the FFN and the text
    transformer follow the width at the paper's ratios (FFN 2 × width, text width / 2, text FFN
    4 × width, half the heads), so a test can shrink everything with the width alone."""

    width: int = 512
    heads: int = 8
    layers: int = 8
    text_dim: int = 512
    text_layers: int = 4

    def config(self, kind: str, max_frames: int) -> MotionDiffuseConfig:
        text_width = max(1, self.width // 2)
        return MotionDiffuseConfig(
            width=self.width,
            heads=self.heads,
            layers=self.layers,
            ffn=2 * self.width,
            text_dim=self.text_dim,
            text_width=text_width,
            text_heads=math.gcd(text_width, max(1, self.heads // 2)),
            text_ffn=4 * self.width,
            text_layers=self.text_layers,
            max_frames=max_frames,
            attention=kind,
        )


@dataclass(frozen=True)
class Setting:
    """One measured call: the attention function or the whole network, of one kind, over ``frames``."""

    scope: str
    kind: str
    actions: int
    frames: int


def matrix_bytes(kind: str, frames: int, size: Size) -> int:
    """The attention state of one call in fp32 bytes: softmax's n × n probabilities per head, linear
    attention's d × d global context per head (eq. 8's F_g)."""
    side = frames if kind == "softmax" else size.width // size.heads
    return BATCH * size.heads * side * side * FLOAT_BYTES


def attention_call(kind: str, frames: int, size: Size) -> partial:
    """One call of ``kind``'s attention over ``frames`` positions, on inputs drawn once."""
    generator = torch.Generator().manual_seed(frames)
    q, k, v = (torch.randn(BATCH, size.heads, frames, size.width // size.heads, generator=generator) for _ in range(3))
    return partial(ATTEND[kind], q, k, v, torch.ones(BATCH, frames, dtype=torch.bool))


def network_call(network: MotionDiffuseTransformer, frames: int) -> partial:
    """One forward pass (one denoising step) of ``network`` over a noisy motion of ``frames`` frames."""
    config = network.config
    generator = torch.Generator().manual_seed(frames)
    words = torch.randn(BATCH, TEXT_TOKENS, config.text_dim, generator=generator)
    with torch.no_grad():
        text = network.encode_text(words, torch.ones(BATCH, TEXT_TOKENS, dtype=torch.bool))
    x = torch.randn(BATCH, frames, config.feature_dim, generator=generator)
    return partial(network, x, torch.full((BATCH,), 500), torch.full((BATCH,), frames), text)


def build_network(kind: str, size: Size, max_frames: int) -> MotionDiffuseTransformer:
    """The network with ``kind`` of attention, weights drawn from one seed whatever the kind (the
    attention has no weights of its own, so both kinds compute with the same ones)."""
    torch.manual_seed(0)
    return MotionDiffuseTransformer(size.config(kind, max_frames)).eval()


def peak_rss() -> int:
    """This process's peak resident set size in bytes (Linux reports KiB, macOS bytes)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak if sys.platform == "darwin" else 1024 * peak


def probe_memory(setting: Setting, size: Size, max_frames: int, threads: int) -> dict[str, int]:
    """In a fresh process: the peak RSS before and after one call of ``setting``, its inputs (and
    network) already built."""
    torch.set_num_threads(threads)
    if setting.scope == "attention":
        run = attention_call(setting.kind, setting.frames, size)
    else:
        run = network_call(build_network(setting.kind, size, max_frames), setting.frames)
    gc.collect()
    before = peak_rss()
    with torch.no_grad():
        run()
    return {"rss_before": before, "rss_growth": peak_rss() - before}


def measure_memory(settings: list[Setting], size: Size, max_frames: int, threads: int) -> list[dict[str, int]]:
    """:func:`probe_memory` of every setting, each in its own spawned process (no fork: the child
    must not inherit this process's peak)."""
    context = get_context("spawn")
    probes = []
    for setting in tqdm(settings, desc="peak memory", unit="process"):
        with ProcessPoolExecutor(max_workers=1, mp_context=context) as pool:
            probes.append(pool.submit(probe_memory, setting, size, max_frames, threads).result())
    return probes


def measure_times(settings: list[Setting], size: Size, max_frames: int, warmup: int, repeats: int) -> list[list[float]]:
    """Seconds per call of every setting, in interleaved rounds after the warm-up calls."""
    networks = (
        {kind: build_network(kind, size, max_frames) for kind in KINDS}
        if any(s.scope == "network" for s in settings)
        else {}
    )
    if networks:
        networks["softmax"].load_state_dict(networks["linear"].state_dict())
    runs = [
        attention_call(s.kind, s.frames, size) if s.scope == "attention" else network_call(networks[s.kind], s.frames)
        for s in settings
    ]
    with torch.no_grad():
        return interleaved_times(runs, warmup, repeats, torch.device("cpu"), desc="time")


def machine() -> dict[str, Any]:
    """What the times were measured on, and how loaded it was (the machine may be shared)."""
    return {
        "device": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "load": list(os.getloadavg()),
    }


def settings_of(args: argparse.Namespace) -> list[Setting]:
    """Every (scope, kind, length); the network's only up to ``--network-max-actions`` actions."""
    cap = args.network_max_actions or max(args.lengths_actions)
    return [
        Setting(scope, kind, actions, actions * args.action_frames)
        for scope in SCOPES
        for actions in args.lengths_actions
        for kind in KINDS
        if scope == "attention" or actions <= cap
    ]


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """Every measurement, as the JSON written next to the figure."""
    size = Size(args.width, args.heads, args.layers, args.text_dim, args.text_layers)
    settings = settings_of(args)
    max_frames = max(s.frames for s in settings)
    started = machine()
    probes = measure_memory(settings, size, max_frames, args.threads)
    times = measure_times(settings, size, max_frames, args.warmup, args.repeats)
    with torch.device("meta"):  # shapes alone: nothing allocated or initialised
        parameters = sum(p.numel() for p in MotionDiffuseTransformer(size.config("linear", max_frames)).parameters())
    rows = [
        {
            **asdict(s),
            "times": seconds,
            "median": statistics.median(seconds),
            "spread": [min(seconds), max(seconds)],
            **probe,
            "matrix_bytes": matrix_bytes(s.kind, s.frames, size),
        }
        for s, seconds, probe in zip(settings, times, probes)
    ]
    return {
        "date": datetime.now().isoformat(timespec="minutes"),
        "machine": {**started, "load_after": list(os.getloadavg())},
        "size": {
            **asdict(size),
            "network_config": size.config("linear", max_frames).to_dict(),
            "parameters": parameters,
            "batch": BATCH,
            "text_tokens": TEXT_TOKENS,
        },
        "settings": {
            "action_frames": args.action_frames,
            "lengths_actions": args.lengths_actions,
            "network_max_actions": args.network_max_actions,
            "warmup": args.warmup,
            "repeats": args.repeats,
        },
        "rows": rows,
    }


def mib(n: float) -> str:
    return f"{n / 2**20:.2f}"


def report(result: dict[str, Any]) -> str:
    """The measurements as Markdown: one table per scope, the kinds side by side."""
    info, size = result["machine"], result["size"]
    lines = [
        f"{result['date']}; {info['device']}, {info['cores']} cores, {info['torch_threads']} torch threads, "
        f"torch {info['torch']}; load average {info['load'][0]:.2f} before, {info['load_after'][0]:.2f} after; "
        f"median [min–max] of {result['settings']['repeats']} calls after {result['settings']['warmup']} "
        f"warm-up(s); peak RSS growth of one call in a fresh process",
        f"- width {size['width']}, {size['heads']} heads, {size['layers']} layers, text {size['text_dim']}-d "
        f"through {size['text_layers']} layers; network {size['parameters']:,} parameters; batch {size['batch']}",
    ]
    for scope, title in (("attention", "One attention call"), ("network", "One forward pass of the whole network")):
        rows = {(row["kind"], row["frames"]): row for row in result["rows"] if row["scope"] == scope}
        lines += [
            "",
            title,
            "",
            "| actions | frames | linear (ms) | softmax (ms) | softmax / linear | linear RSS growth (MiB) | "
            "softmax RSS growth (MiB) | softmax n×n matrix (MiB) |",
            "| --- " * 8 + "|",
        ]
        for frames in dict.fromkeys(frames for _, frames in rows):
            linear, softmax = rows[("linear", frames)], rows[("softmax", frames)]
            cells = [
                f"{1e3 * row['median']:.2f} [{1e3 * row['spread'][0]:.2f}–{1e3 * row['spread'][1]:.2f}]"
                for row in (linear, softmax)
            ]
            lines.append(
                f"| {linear['actions']} | {frames} | {' | '.join(cells)} | "
                f"{softmax['median'] / linear['median']:.2f} | {mib(linear['rss_growth'])} | "
                f"{mib(softmax['rss_growth'])} | {mib(softmax['matrix_bytes'])} |"
            )
    if result["settings"]["network_max_actions"]:
        lines += [
            "",
            f"Whole-network rows capped at {result['settings']['network_max_actions']} actions "
            "(--network-max-actions).",
        ]
    return "\n".join(lines + [""])


def plot(path: Path, result: dict[str, Any]) -> None:
    """Time and memory against frames, log-log: one curve per kind and scope, with softmax's n × n
    matrix beside the measured memory."""
    from matplotlib.figure import Figure

    figure = Figure(figsize=(10.0, 4.2), dpi=110, layout="constrained")
    timing, memory = figure.subplots(1, 2)
    colours = {kind: f"C{i}" for i, kind in enumerate(KINDS)}
    styles = {"attention": ("o", "-"), "network": ("s", "--")}
    for scope in SCOPES:
        for kind in KINDS:
            rows = [row for row in result["rows"] if row["scope"] == scope and row["kind"] == kind]
            if not rows:
                continue
            marker, line = styles[scope]
            x = [row["frames"] for row in rows]
            error = [
                [row["median"] - row["spread"][0] for row in rows],
                [row["spread"][1] - row["median"] for row in rows],
            ]
            timing.errorbar(
                x,
                [row["median"] for row in rows],
                yerr=error,
                marker=marker,
                linestyle=line,
                capsize=3,
                color=colours[kind],
                label=f"{kind}, {scope}",
            )
            memory.plot(
                x,
                [max(row["rss_growth"], 1) / 2**20 for row in rows],
                marker=marker,
                linestyle=line,
                color=colours[kind],
                label=f"{kind}, {scope}: peak RSS growth",
            )
    analytic = [row for row in result["rows"] if row["scope"] == "attention" and row["kind"] == "softmax"]
    memory.plot(
        [row["frames"] for row in analytic],
        [row["matrix_bytes"] / 2**20 for row in analytic],
        color="k",
        linestyle=":",
        label="softmax n×n matrix (analytic; one call, one layer)",
    )
    frames = result["settings"]["action_frames"]
    info, size = result["machine"], result["size"]
    for axes, label in ((timing, "seconds per call: median, range"), (memory, "MiB")):
        axes.set(xscale="log", yscale="log", xlabel=f"frames ({frames} per action)", ylabel=label)
        axes.grid(alpha=0.3, which="both")
        axes.legend(fontsize="x-small")
    timing.set_title("time", fontsize="medium")
    memory.set_title("memory of one call", fontsize="medium")
    figure.suptitle(
        f"linear (eq. 8) against softmax attention, width {size['width']}, {size['heads']} heads, "
        f"{size['layers']} layers; {info['device']}, {info['torch_threads']} torch thread(s)",
        fontsize="medium",
    )
    figure.savefig(path)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--lengths-actions", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32], help="sequence lengths in actions"
    )
    parser.add_argument(
        "--action-frames",
        type=int,
        default=98,
        help="frames per action (98 = 4.9 s at 20 fps, a median HumanML3D action)",
    )
    parser.add_argument(
        "--network-max-actions",
        type=int,
        default=None,
        help="time the whole network only up to this many actions (default: every length)",
    )
    parser.add_argument("--warmup", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=os.cpu_count(), help="torch threads")
    size = Size()
    for name in ("width", "heads", "layers", "text_dim", "text_layers"):
        parser.add_argument(
            f"--{name.replace('_', '-')}", type=int, default=getattr(size, name), help="the paper's by default"
        )
    parser.add_argument("--out", default="runs/bench/attention", help="where attention.json and attention.png go")
    args = parser.parse_args(argv)
    if (
        min(
            args.lengths_actions
            + [
                args.action_frames,
                args.repeats,
                args.threads,
                args.width,
                args.heads,
                args.layers,
                args.text_dim,
                args.network_max_actions or 1,
            ]
        )
        < 1
        or min(args.warmup, args.text_layers) < 0
    ):
        parser.error(
            "lengths, frames, repeats, threads and sizes must be at least 1, --warmup and --text-layers at least 0"
        )
    if args.width % args.heads:
        parser.error(f"--width ({args.width}) must be divisible by --heads ({args.heads})")
    args.lengths_actions = sorted(set(args.lengths_actions))

    torch.set_num_threads(args.threads)
    result = measure(args)
    publish(Path(args.out), "attention", result, plot, report)


if __name__ == "__main__":
    main()
