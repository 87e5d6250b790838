"""Two-Phase Sampling wall time against the number of actions N (each 196 frames = 49 tokens),
paper-size denoiser (12 × 512, 16 heads), K = 512, T = 100, T_s = 90, guidance on (two passes
per step, batched).

A step costs the same whatever T is, so each phase's step time is measured on a short schedule
(joint phase: the N actions as one row; independent phase: N rows) and TPS at T = 100 is
10 joint + 90 independent steps. For small N a full T = 100 run is also timed, which checks the
sum. The fit of time against N says whether TPS grows linearly, and the fitted line gives the
time for MMM's long-sequence figure (10.9 minutes of motion in 1.66 s on an RTX A5000). On a GPU
that sequence (67 actions) is also sampled whole at T = 100.

``--compile`` is the sampler's option (docs/generation.md, "Compiled sampling"); by default the
denoiser is compiled on a GPU and eager on the CPU. A compiled sampler is warmed up on every
shape it times first, so compiling is not in the figures. Prints Markdown.
"""

from __future__ import annotations

import argparse
import os

import numpy as np
import torch
from timing import wall_time

from m2d2m.generators.m2d2m.options import M2D2MOptions
from m2d2m.generators.m2d2m.sampling import TokenRequest, TokenSampler
from m2d2m.generators.options import COMPILE
from m2d2m.networks.m2d2m_denoiser import DenoiserConfig, MotionDenoiser
from m2d2m.processes.discrete_diffusion import TransitionSchedule
from m2d2m.text import LearnedTextEncoder

CODES, STEPS, TS, TOKENS = 512, 100, 90, 49
SHORT = 4  # steps of the short schedules used to time one step of each phase
MMM_SECONDS, MMM_WALL = 10.873 * 60, 1.658  # MMM's long-sequence figure (RTX A5000)


def sampler(steps: int, device: torch.device) -> TokenSampler:
    torch.manual_seed(0)
    words = LearnedTextEncoder.build_vocabulary(["a person walks forward and jumps"])
    text = LearnedTextEncoder(words, dim=512, layers=2, heads=8, dropout=0.0)
    denoiser = MotionDenoiser(DenoiserConfig(codebook_size=CODES, steps=steps, text_dim=512))
    schedule = TransitionSchedule.build(torch.randn(CODES, 512, device=device), steps=steps)
    return TokenSampler(denoiser.to(device), text.to(device), schedule)


def actions(n: int) -> list[TokenRequest]:
    return [TokenRequest([["a person walks forward"]] * n, [TOKENS] * n, seed=0)]


def main() -> None:
    parser = argparse.ArgumentParser(description="Two-Phase Sampling time against the number of actions")
    parser.add_argument("--compile", choices=COMPILE, default="auto", help="the sampler's compile option")
    compile_option = parser.parse_args().compile
    gpu = torch.cuda.is_available()
    device = torch.device("cuda" if gpu else "cpu")
    torch.set_num_threads(2)
    name = torch.cuda.get_device_name() if gpu else f"CPU, {os.cpu_count()} cores, 2 torch threads"
    short, full = sampler(SHORT, device), sampler(STEPS, device)
    autocast = torch.autocast("cuda", dtype=torch.bfloat16, enabled=gpu)
    warm = compile_option == "on" or (compile_option == "auto" and gpu)  # time the full runs after a warm-up

    def options(ts: int) -> M2D2MOptions:
        return M2D2MOptions(ts=ts, compile=compile_option)

    counts = [1, 2, 4, 8, 16, 32]
    print(
        f"device: {name}; {TOKENS} tokens (196 frames) per action, T = {STEPS}, T_s = {TS}, guidance 2, "
        f"compile {compile_option}{' (compiled)' if warm else ''}"
    )
    print(
        "| N actions | motion (s) | joint step (ms) | independent step (ms) | TPS, T = 100 (s) | measured full run (s) |"
    )
    print("| --- | --- | --- | --- | --- | --- |")
    totals = []
    for n in counts:
        request = actions(n)
        with autocast:
            short.sample(request, options(0))  # warm-up
            short.sample(request, options(SHORT))
            joint = min(wall_time(lambda: short.sample(request, options(0)), device) for _ in range(2)) / SHORT
            indep = min(wall_time(lambda: short.sample(request, options(SHORT)), device) for _ in range(2)) / SHORT
            measured = None
            if gpu or n <= 2:
                if warm:
                    full.sample(request, options(TS))
                measured = wall_time(lambda: full.sample(request, options(TS)), device)
        total = (STEPS - TS) * joint + TS * indep
        totals.append(total)
        shown = f"{measured:.2f}" if measured is not None else "–"
        print(f"| {n} | {n * 196 / 20:.0f} | {1e3 * joint:.1f} | {1e3 * indep:.1f} | {total:.2f} | {shown} |")
    slope, intercept = np.polyfit(counts, totals, 1)
    predicted = slope * np.asarray(counts) + intercept
    r2 = 1.0 - np.sum((np.asarray(totals) - predicted) ** 2) / np.sum((np.asarray(totals) - np.mean(totals)) ** 2)
    long = round(MMM_SECONDS / (196 / 20))
    print(f"\nlinear fit: time = {slope:.3f} s × N + {intercept:.3f} s (R² = {r2:.4f})")
    print(
        f"MMM's {MMM_SECONDS / 60:.3f} min of motion = {long} actions of 196 frames: {slope * long + intercept:.2f} s "
        f"by the fit (MMM: {MMM_WALL} s on an RTX A5000)"
    )
    if gpu:
        with autocast:
            full.sample(actions(long), options(TS))  # warm-up (and compiling)
            measured = min(wall_time(lambda: full.sample(actions(long), options(TS)), device) for _ in range(3))
        print(f"measured: {long} actions at T = {STEPS}, T_s = {TS}: {measured:.3f} s (best of 3)")


if __name__ == "__main__":
    main()
