"""Discrete-diffusion cost at paper size: one training step of the 12-layer denoiser with the
L_vlb + aux loss, the loss alone, one reverse sampling step, and rebuilding the transition
matrices for a new η — for the dynamic β(t, d) against VQ-Diffusion's uniform β_t.

Synthetic inputs (random codebook, tokens and text features) at the paper's sizes: K = 512 codes,
T = 100, 49 tokens (196 frames / 4), 512-d text features of two 16-token action sentences. CPU
figures use 2 torch threads; on a GPU the step runs in bf16 autocast. The loss and the posterior
run as the training step and the sampler run them, without the range checks that read tensors on
the host (``validate=False``): one batched product over the samples' Q̄_{t−1}, no host sync.
Prints a Markdown table.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import torch
from timing import best_time

from m2d2m.networks.m2d2m_denoiser import DenoiserConfig, MotionDenoiser, guided_logits
from m2d2m.processes.discrete_diffusion import TransitionSchedule
from m2d2m.processes.discrete_diffusion_loss import diffusion_loss

CODES, STEPS, TOKENS, TEXT_TOKENS, TEXT_DIM = 512, 100, 49, 32, 512


class Bench:
    """The paper-size denoiser, an optimiser and one synthetic batch on ``device``."""

    def __init__(self, batch: int, device: torch.device) -> None:
        generator = torch.Generator().manual_seed(0)
        self.device = device
        self.batch = batch
        self.codebook = torch.randn(CODES, 512, generator=generator).double().to(device)
        self.denoiser = MotionDenoiser(DenoiserConfig(codebook_size=CODES, steps=STEPS, text_dim=TEXT_DIM)).to(device)
        self.optimizer = torch.optim.AdamW(self.denoiser.parameters(), lr=2e-4)
        self.z0 = torch.randint(CODES, (batch, TOKENS), generator=generator).to(device)
        self.t = torch.randint(1, STEPS + 1, (batch,), generator=generator).to(device)
        self.text = torch.randn(batch, TEXT_TOKENS, TEXT_DIM, generator=generator).to(device)
        self.autocast = torch.autocast("cuda", dtype=torch.bfloat16, enabled=device.type == "cuda")

    def schedule(self, kind: str) -> TransitionSchedule:
        return TransitionSchedule.build(self.codebook, steps=STEPS, kind=kind)

    def training_step(self, schedule: TransitionSchedule) -> Callable[[], None]:
        z_t = schedule.q_sample(self.z0, self.t[:, None])

        def step() -> None:
            self.optimizer.zero_grad(set_to_none=True)
            with self.autocast:
                logits = self.denoiser(z_t, None, self.t, self.text)
            diffusion_loss(schedule, logits.float(), self.z0, z_t, self.t, validate=False).loss.backward()
            self.optimizer.step()

        return step

    def loss_only(self, schedule: TransitionSchedule) -> Callable[[], None]:
        z_t = schedule.q_sample(self.z0, self.t[:, None])
        logits = torch.randn(self.batch, TOKENS, CODES, device=self.device, requires_grad=True)
        return lambda: diffusion_loss(schedule, logits, self.z0, z_t, self.t, validate=False).loss.backward()

    def sampling_step(self, schedule: TransitionSchedule, step: int = 50) -> Callable[[], None]:
        """One guided reverse step: conditional and null forward passes, posterior, categorical draw."""
        z = schedule.sample_prior((self.batch, TOKENS))
        t = torch.full((self.batch,), step, device=self.device)

        @torch.no_grad()
        def run() -> None:
            with self.autocast:
                cond = self.denoiser(z, None, t, self.text)
                uncond = self.denoiser(z, None, t, None)
            x0 = guided_logits(cond.float(), uncond.float(), 2.0).exp()
            probs = schedule.posterior_probs(z, x0, step, validate=False).clamp_min(0.0)
            torch.multinomial(probs.reshape(-1, CODES + 1), 1)

        return run


def main() -> None:
    gpu = torch.cuda.is_available()
    device = torch.device("cuda" if gpu else "cpu")
    torch.set_num_threads(2)
    torch.manual_seed(0)
    name = torch.cuda.get_device_name() if gpu else f"CPU, {os.cpu_count()} cores, 2 torch threads"
    print(
        f"device: {name}; paper-size denoiser (12 layers x 512, 16 heads), K = {CODES}, T = {STEPS}, "
        f"{TOKENS} tokens, {'bf16 autocast' if gpu else 'float32'}"
    )
    print("| measurement | dynamic β(t, d) | uniform β_t | dynamic / uniform |\n| --- | --- | --- | --- |")
    repeats = 10 if gpu else 3
    for batch in [32, 256] if gpu else [32]:
        bench = Bench(batch, device)
        schedules = {kind: bench.schedule(kind) for kind in ("dynamic", "uniform")}
        rows = {
            f"training step, batch {batch} (ms)": bench.training_step,
            f"loss forward + backward alone, batch {batch} (ms)": bench.loss_only,
            f"one guided sampling step, batch {batch} (ms)": bench.sampling_step,
        }
        for label, make in rows.items():
            times = {kind: best_time(make(schedule), repeats, device) for kind, schedule in schedules.items()}
            print(
                f"| {label} | {1e3 * times['dynamic']:.1f} | {1e3 * times['uniform']:.1f} | "
                f"{times['dynamic'] / times['uniform']:.2f} |"
            )
        if batch == 32:
            single = Bench(1, device)
            step = best_time(single.sampling_step(single.schedule("dynamic")), repeats, device)
            print(f"| one guided sampling step, batch 1 (ms) | {1e3 * step:.1f} | | |")
    dynamic = Bench(1, device).schedule("dynamic")
    rebuild = best_time(lambda: dynamic.with_eta(0.25), repeats, device)
    build = best_time(lambda: TransitionSchedule.build(bench.codebook, steps=STEPS, kind="dynamic"), repeats, device)
    print(f"| rebuild Q_t, Q̄_t for a new η, K = {CODES}, T = {STEPS} (ms) | {1e3 * rebuild:.1f} | | |")
    print(f"| build from the codebook (distances + matrices) (ms) | {1e3 * build:.1f} | | |")


if __name__ == "__main__":
    main()
