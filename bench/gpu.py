"""One command that measures whatever machine it runs on, a GPU above all: ``make bench-gpu``.

For each model (the VQ-VAE, M2D2M, MMM, MotionDiffuse) at its demo size and at the paper's size:

- **training**: a bounded number of steps of its real LightningModule in Lightning's Trainer, at the
  precision a training run picks (bf16-mixed on a GPU that has it), on synthetic batches shaped as
  the DataModules give them (random codes or features, the demo's action sentences, lengths of
  196 frames or less): steps/s, samples/s, the GPU's utilisation sampled every 0.2 s by
  ``nvidia-smi``, peak memory, and the FLOPs of one step (PyTorch's ``FlopCounterMode``: forward
  and backward matrix products) over its time against the card's bf16 peak; each step eager and,
  on a GPU (``--train-compile``), compiled as ``trainer.compile: on`` runs it (training/step.py),
  with the warm-up that compiles it;
- **sampling**: AITS (one call's time over its sentences, MMM's Table 7 metric) at batch 1 and
  32 for 196-frame actions with the model's single-action preset, through its generator, from a
  model file of random weights written by its training recipe;
- **the long sequence**: MMM's 10.873 minutes (67 actions) as one sequence by each model's
  multi-action method at the last size asked (the paper's) (bench/aits.py's ``long_plan``; MotionDiffuse at ``--md-long-steps`` of
  its 1000 steps, the time at 1000 extrapolated, as bench/aits.py does);
- **serving**: bench/serve.py's load test, when the project has the demo's trained models;
- **the command line** (``--cli-project DIR``): each model's training verb run as a user runs it,
  ``--cli-steps`` steps of its demo config with two validations and a preview each, in a project
  that has the demo's data and tokens, beside the synthetic batches' steps/s at the demo size, and
  the seconds from its ``finished`` line to its exit (bench/exit_time.py's clock).

Random weights take as long as trained ones: a step's work does not depend on the values. The
paper's frozen CLIP text tower is a randomly initialised tower of its shape (ViT-B/32's: 12
layers of width 512) with a tokenizer of the prompts' words, written under the output folder, so
nothing is downloaded. ``--quick`` (what CI runs, on a CPU) takes the demo sizes alone, 2 steps,
batches of 2 and a 0.1-minute sequence, and skips serving: it proves the command works, not how
fast anything is (the paper sizes take minutes on a CPU).

    python bench/gpu.py [--quick] [--models vq m2d2m mmm motiondiffuse] [--sizes demo paper]
                        [--steps 30] [--warmup 5] [--train-compile off on] [--batches 1 32]
                        [--paper-batches 64 256]
                        [--long-minutes 10.873] [--long-compiled] [--cli-project DIR]
                        [--cli-steps 200] [--out DIR]

Writes ``gpu.json`` and ``gpu.md`` into ``--out`` (``runs/bench/gpu/<machine>-<time>``) after every
figure, so a stopped run keeps what it measured; a figure that fails is recorded, the others are
still measured, and the command then exits 1. It prints the Markdown at the end. Of the project's
dependencies it needs torch, Lightning, transformers, PyYAML, Matplotlib and WebDataset, not Ray,
spaCy or MLflow (what a bare GPU machine must be given); ``--cli-project`` runs the command line,
which needs MLflow too. ``make gpu-carry`` (bench/gpu_carry.py) prepares those packages and a demo
project for such a machine, and ``bench/gpu_run.sh`` runs this there in two parts.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import json
import logging
import math
import os
import platform
import re
import shutil
import statistics
import subprocess
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import lightning.pytorch as pl
import numpy as np
import torch
from aits import LONG_METHODS, STEP_SERIES, long_plan, trained_steps
from exit_time import from_this_checkout, timed
from timing import wall_time
from torch.utils.flop_counter import FlopCounterMode

from m2d2m.generators.options import MULTI, SINGLE
from m2d2m.model_files import LengthPrior
from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.networks.vqvae import VQ_FORMAT
from m2d2m.text import LearnedTextEncoder
from orchestration.config import load_config
from orchestration.recipe import TrainingData
from orchestration.recipes.token_data import TokenTraining
from orchestration.registry import model
from orchestration.train import TRAINING_DEFAULTS, lightning_precision

PROJECT = Path(__file__).resolve().parents[1]
MODELS = ("vq", "m2d2m", "mmm", "motiondiffuse")
SIZES = ("demo", "paper")
# (configs folder, config name) of each model at each size; M2D2M's paper size is the paper's exact denoiser
CONFIGS = {
    "vq": {"demo": ("vq", "demo"), "paper": ("vq", "humanml3d")},
    "m2d2m": {"demo": ("m2d2m", "demo"), "paper": ("m2d2m", "paper-humanml3d")},
    "mmm": {"demo": ("mmm", "demo"), "paper": ("mmm", "humanml3d")},
    "motiondiffuse": {"demo": ("motiondiffuse", "demo"), "paper": ("motiondiffuse", "humanml3d")},
}
# the tokenizer each token model reads at each size: MMM's paper size has its own (8192 codes of 32)
TOKENIZERS = {("m2d2m", "paper"): "humanml3d", ("mmm", "paper"): "mmm-humanml3d"}
WORK = "work"  # the folder under --out for the random model files and CLIP's tower, removed at the end
PROMPTS = ("a person walks forward", "a person jumps", "a person waves their right hand", "a person sits down")
FEATURES, FPS, FRAMES, FRAMES_PER_TOKEN = 263, 20.0, 196, 4
# dense bf16 tensor-core peaks (TFLOP/s) from NVIDIA's data sheets, matched in the device's name, most specific first
BF16_PEAKS = (
    ("H100 PCIe", 756.0),
    ("H100 NVL", 835.0),
    ("H100", 989.0),
    ("H200", 989.0),
    ("GH200", 989.0),
    ("A100", 312.0),
    ("L40S", 362.0),
    ("L40", 181.0),
    ("L4", 121.0),
    ("A10", 125.0),
    ("RTX A6000", 155.0),
    ("RTX A5000", 111.0),
)


# ----------------------------------------------------------------------------------- the machine
def machine(device: torch.device) -> dict[str, Any]:
    """What was measured on: the device's name, its bf16 peak when known, the software."""
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else platform.processor() or platform.machine()
    peak = next((tflops for key, tflops in BF16_PEAKS if key in name), None) if device.type == "cuda" else None
    return {
        "device": name,
        "kind": device.type,
        "bf16_peak_tflops": peak,
        "cores": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "lightning": pl.__version__,
        "python": platform.python_version(),
    }


class Utilisation:
    """The GPU's utilisation (%) sampled every ``period`` seconds by ``nvidia-smi`` while the
    block runs; nothing on a machine without it."""

    def __init__(self, device: torch.device, period: float = 0.2) -> None:
        self.command = shutil.which("nvidia-smi") if device.type == "cuda" else None
        self.index = device.index or 0
        self.period = period
        self.samples: list[float] = []
        self._stop = threading.Event()

    def _sample(self) -> None:
        query = [self.command, "--query-gpu=utilization.gpu", "--format=csv,noheader,nounits", f"--id={self.index}"]
        while not self._stop.wait(self.period):
            answer = subprocess.run(query, capture_output=True, text=True, check=False).stdout.strip()
            if answer.isdigit():
                self.samples.append(float(answer))

    @contextlib.contextmanager
    def sampling(self) -> Iterator[Utilisation]:
        thread = threading.Thread(target=self._sample, daemon=True) if self.command else None
        if thread:
            thread.start()
        try:
            yield self
        finally:
            self._stop.set()
            if thread:
                thread.join()

    @property
    def mean(self) -> float | None:
        return statistics.fmean(self.samples) if self.samples else None


@contextlib.contextmanager
def peak_memory(device: torch.device) -> Iterator[dict[str, float | None]]:
    """The block's peak allocated GPU memory in GiB (None on a CPU)."""
    found: dict[str, float | None] = {"gib": None}
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
    yield found
    if device.type == "cuda":
        found["gib"] = torch.cuda.max_memory_allocated(device) / 2**30


# --------------------------------------------------------------------- synthetic inputs, random models
def random_clip(directory: Path) -> Path:
    """A randomly initialised CLIP ViT-B/32 text tower (its default shape) with a tokenizer of the
    prompts' words, saved where ``text.kind: clip`` can load it without a download."""
    import transformers

    if (directory / "config.json").exists():
        return directory
    words = sorted({word for prompt in PROMPTS for word in prompt.split()})
    tokens = ["<|startoftext|>", "<|endoftext|>", *(word + "</w>" for word in words)]
    vocabulary = {token: i for i, token in enumerate(tokens)}
    tokenizer = transformers.CLIPTokenizer(vocab=vocabulary, merges=[])
    config = transformers.CLIPTextConfig(vocab_size=len(vocabulary), bos_token_id=0, eos_token_id=1, pad_token_id=1)
    torch.manual_seed(0)
    transformers.CLIPTextModel(config).save_pretrained(directory)
    tokenizer.save_pretrained(directory)
    return directory


def frames_of_batch(batch: int, generator: torch.Generator) -> list[int]:
    """Clip lengths of one batch as a length-bucketing loader gives them: within a quarter of the
    batch's longest, itself 40–196 frames, in whole tokens."""
    longest = int(torch.randint(10, FRAMES // FRAMES_PER_TOKEN + 1, (1,), generator=generator))
    low = max(1, math.ceil(0.75 * longest))
    return [FRAMES_PER_TOKEN * int(n) for n in torch.randint(low, longest + 1, (batch,), generator=generator)]


def synthetic_batch(name: str, config: dict[str, Any], batch: int, codes: int, seed: int) -> dict[str, Any]:
    """One batch in the shape the model's DataModule gives (the collate functions of training/data/)."""
    generator = torch.Generator().manual_seed(seed)
    if name == "vq":
        return {"motion": torch.randn(batch, config["data"]["window"], FEATURES, generator=generator)}
    frames = frames_of_batch(batch, generator)
    captions = [PROMPTS[(seed + i) % len(PROMPTS)] for i in range(batch)]
    if name == "motiondiffuse":
        lengths = torch.tensor(frames)
        return {
            "motion": torch.randn(batch, max(frames), FEATURES, generator=generator),
            "lengths": lengths,
            "text": captions,
        }
    lengths = torch.tensor(frames) // FRAMES_PER_TOKEN
    tokens = torch.randint(codes, (batch, int(lengths.max())), generator=generator)
    return {
        "tokens": tokens,
        "padding_mask": torch.arange(tokens.shape[1])[None] < lengths[:, None],
        "lengths": lengths,
        "actions": [[caption] for caption in captions],
        "text": captions,
        "keys": [f"{seed}-{i}" for i in range(batch)],
    }


@dataclass
class Built:
    """A model at one size: its config, LightningModule, codebook size, and how to write its model file."""

    config: dict[str, Any]
    module: pl.LightningModule
    codes: int
    save: Callable[[Path], Path]


def _config(folder: str, name: str, clip: Path) -> dict[str, Any]:
    path = str(PROJECT / "configs" / folder / f"{name}.yaml")
    if folder == "vq":
        config = load_config(folder, path, [], TRAINING_DEFAULTS)
    else:
        entry = model(folder)
        config = entry.load("recipe").load_config(entry, path)
    if config.get("text", {}).get("kind") == "clip":
        config["text"] = {**config["text"], "path": str(clip)}
    return config


def _vq(tokenizer: str, out: Path, clip: Path) -> tuple[Path, Any]:
    """A random VQ-VAE of configs/vq/<tokenizer>.yaml written as a model file, and its module."""
    from training.vq_module import VQVAEModule

    config = _config("vq", tokenizer, clip)
    module = VQVAEModule(config["model"], config["optim"], config["loss"], FEATURES, "t2m")
    path = save_vq_file(out / f"vq-{tokenizer}.pt", module)
    return path, module


def save_vq_file(path: Path, module: Any) -> Path:
    normalizer = Normalizer(np.zeros(FEATURES, dtype=np.float32), np.ones(FEATURES, dtype=np.float32))
    return VQ_FORMAT.save(path, **module.model_parts(), normalizer=normalizer, skeleton="t2m", extra={"run": "bench"})


def build(name: str, size: str, out: Path, clip: Path) -> Built:
    """``name`` at ``size`` with random weights, by its own recipe where it has one."""
    folder, config_name = CONFIGS[name][size]
    config = _config(folder, config_name, clip)
    if name == "vq":
        _, module = _vq(config_name, out, clip)
        return Built(config, module, module.model.config.codebook_size, lambda path: save_vq_file(path, module))
    vocabulary = LearnedTextEncoder.build_vocabulary(PROMPTS) if config["text"]["kind"] == "learned" else None
    recipe = model(name).load("recipe")
    extra = {"run": "bench", "dataset": "bench"}
    if name == "motiondiffuse":
        normalizer = Normalizer(np.zeros(FEATURES, dtype=np.float32), np.ones(FEATURES, dtype=np.float32))
        loader = SimpleNamespace(feature_dim=FEATURES, normalizer=normalizer, skeleton="t2m")
        data = TrainingData(loader, out, vocabulary)
        module = recipe.module(config, data)
        data.lengths = LengthPrior({}, median=FRAMES, longest=FRAMES)  # no shards to read it from
        return Built(config, module, 0, lambda path: recipe.save(path, module, config, data, extra))
    vq_path, vq = _vq(TOKENIZERS.get((name, size), "demo"), out, clip)
    prior = LengthPrior({}, median=FRAMES // FRAMES_PER_TOKEN, longest=FRAMES // FRAMES_PER_TOKEN)
    codebook = vq.model.codebook.detach().clone()
    data = TokenTraining(None, out, vocabulary, vq_path, codebook, out)
    data.lengths = prior  # no shards to read it from
    module = recipe.module(config, data)
    return Built(config, module, codebook.shape[0], lambda path: recipe.save(path, module, config, data, extra))


# ------------------------------------------------------------------------------------------ training
class StepClock(pl.Callback):
    """Times the training steps after ``warmup`` (waiting for the device at both ends only), the
    warm-up itself (where a compiled step compiles), and counts the FLOPs of the first step after
    the warm-up unless ``count`` is False (FlopCounterMode sees no operators inside a compiled pass)."""

    def __init__(self, warmup: int, device: torch.device, count: bool = True) -> None:
        self.warmup, self.device, self.count = warmup, device, count
        self.began = self.started = self.stopped = 0.0
        self.flops = 0
        self._counter: FlopCounterMode | None = None

    def _now(self) -> float:
        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)
        return time.perf_counter()

    def on_train_start(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        self.began = self._now()

    def on_train_batch_start(self, trainer: pl.Trainer, module: pl.LightningModule, batch: Any, index: int) -> None:
        if trainer.global_step == self.warmup:
            self.warmed = self._now()
            self._counter = FlopCounterMode(display=False) if self.count else contextlib.nullcontext()
            self._counter.__enter__()

    def on_train_batch_end(self, trainer: pl.Trainer, module: pl.LightningModule, *args: Any) -> None:
        if self._counter is not None:
            self._counter.__exit__(None, None, None)
            self.flops = self._counter.get_total_flops() if self.count else 0
            self._counter = None
            self.started = self._now()  # the counted step is not timed: counting slows it

    def on_train_end(self, trainer: pl.Trainer, module: pl.LightningModule) -> None:
        self.stopped = self._now()


@dataclass
class TrainingFigure:
    model: str
    size: str
    parameters: int
    batch: int
    precision: str
    compiled: bool  # trainer.compile on: forward, loss and backward through torch.compile (CUDA graphs on a GPU)
    warmup_s: float  # the untimed warm-up steps, compiling included
    steps_per_s: float
    samples_per_s: float
    gpu_utilisation: float | None
    peak_memory_gib: float | None
    gflop_per_step: float
    tflops: float
    share_of_peak: float | None


def measure_training(
    name: str,
    size: str,
    built: Built,
    batch: int,
    steps: int,
    warmup: int,
    device: torch.device,
    peak: float | None,
    compiled: bool = False,
    flops: int | None = None,
) -> TrainingFigure:
    """``warmup`` + 1 (counted) + ``steps`` (timed) training steps of the built model, its step
    ``compiled`` or eager. A compiled step's FLOPs are not counted (FlopCounterMode sees no
    operator inside a compiled pass): ``flops`` gives them, as counted eagerly (None: unknown)."""
    batches = [synthetic_batch(name, built.config, batch, built.codes, seed) for seed in range(8)]
    total = warmup + 1 + steps
    loader = torch.utils.data.DataLoader(
        [batches[i % len(batches)] for i in range(total)], batch_size=None, pin_memory=device.type == "cuda"
    )
    clock = StepClock(warmup, device, count=not compiled)
    built.module.compile_steps = "on" if compiled else "off"
    precision = lightning_precision("auto")
    trainer = pl.Trainer(
        accelerator=device.type,
        devices=1,
        max_steps=total,
        precision=precision,
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        limit_val_batches=0,
        gradient_clip_val=built.config["optim"].get("grad_clip"),
        callbacks=[clock],
    )
    utilisation = Utilisation(device)
    with peak_memory(device) as memory, utilisation.sampling():
        trainer.fit(built.module, train_dataloaders=loader)
    seconds = max(clock.stopped - clock.started, 1e-9)
    flops = clock.flops if not compiled else flops or 0
    tflops = flops * steps / seconds / 1e12 if steps else 0.0
    return TrainingFigure(
        name,
        size,
        sum(p.numel() for p in built.module.parameters()),
        batch,
        precision,
        compiled,
        clock.warmed - clock.began,
        steps / seconds,
        steps * batch / seconds,
        utilisation.mean,
        memory["gib"],
        flops / 1e9,
        tflops,
        tflops / peak if peak else None,
    )


# ------------------------------------------------------------------------------------------ sampling
@dataclass
class SamplingFigure:
    model: str
    size: str
    batch: int
    frames: int
    steps: int | None  # the diffusion models' reverse steps; MMM decodes in its own iterations
    precision: str
    seconds: float
    aits: float
    aits_at_all_steps: float  # MotionDiffuse at fewer steps: the time at all its trained steps, by proportion


@dataclass
class LongFigure:
    model: str
    method: str
    compiled: bool
    actions: int
    minutes: float
    steps: int | None
    seconds: float
    seconds_at_all_steps: float
    first_call_seconds: float  # the untimed first call: with ``compiled``, compiling its shapes


def measure_sampling(
    generator: Any, size: str, batch: int, frames: int, repeats: int, md_steps: int | None
) -> SamplingFigure:
    """AITS of ``batch`` sentences of ``frames`` frames in one call (after one untimed call);
    MotionDiffuse at ``md_steps`` of its steps (None: all, the paper's)."""
    stepped = generator.model == "motiondiffuse" and md_steps is not None
    options = generator.options(SINGLE, **({"steps": md_steps} if stepped else {}))
    actions = [[PROMPTS[i % len(PROMPTS)]] for i in range(batch)]

    def call(round_: int) -> None:
        generator.generate(actions, [[frames]] * batch, options, [round_ * batch + i for i in range(batch)])

    call(0)
    seconds = statistics.median(wall_time(lambda r=r: call(r), generator.device) for r in range(1, repeats + 1))
    steps = (options.steps or trained_steps(generator)) if generator.model in STEP_SERIES else None
    scale = trained_steps(generator) / md_steps if stepped else 1.0
    return SamplingFigure(
        generator.model,
        size,
        batch,
        frames,
        steps,
        generator.precision,
        seconds,
        seconds / batch,
        seconds / batch * scale,
    )


def measure_long(generator: Any, minutes: float, md_steps: int, compiled: bool = False) -> LongFigure:
    """One sequence of ``minutes`` by the model's multi-action method, after one untimed call
    (which, ``compiled``, compiles M2D2M's denoiser at the sequence's shapes)."""
    frames = long_plan(minutes, FPS, generator.frame_step, FRAMES)
    stepped = generator.model == "motiondiffuse"
    changes = {"steps": md_steps} if stepped else {"compile": "on"} if compiled else {}
    options = generator.options(MULTI, method=LONG_METHODS[generator.model], **changes)
    actions = [[PROMPTS[i % len(PROMPTS)] for i in range(len(frames))]]
    first = wall_time(lambda: generator.generate(actions, [frames], options, [0]), generator.device)
    seconds = wall_time(lambda: generator.generate(actions, [frames], options, [1]), generator.device)
    trained = trained_steps(generator) if stepped else None
    return LongFigure(
        generator.model,
        options.method,
        compiled,
        len(frames),
        sum(frames) / FPS / 60,
        md_steps if stepped else None,
        seconds,
        seconds * trained / md_steps if stepped else seconds,
        first,
    )


# ---------------------------------------------------------------------------------- the command line
CLI_VERBS = {"vq": "train-vq", "m2d2m": "train-diffusion", "mmm": "train-mmm", "motiondiffuse": "train-motiondiffuse"}
PROGRESS = re.compile(r"^training: (\d+)/(\d+) step")  # training.callbacks.PlainProgress's lines
LINE_RATE = re.compile(r", ([\d.]+) (step/s|s/step)")  # the rate such a line gives, over the training so far


@dataclass
class CliFigure:
    model: str
    verb: str
    compiled: bool
    steps: int
    total_s: float  # the command, start to exit: imports, data, validations, previews, model file, MLflow
    steps_per_s: float  # from its first progress line (a tenth of the steps) to its last: the steady path
    finished_to_exit_s: float | None
    steady: bool = True  # False: too quick for two lines (one each 5 s at most); the last line's own rate


def measure_cli(name: str, project: Path, steps: int, compiled: bool) -> CliFigure:
    """``m2d2m <verb> --config demo`` of ``name`` for ``steps`` steps with two validations, run as a
    user runs it in ``project`` (a project with the demo's data and tokens: after `make data` and
    `make train-vq`): the real path, data loader, validations, previews, checkpoints and MLflow
    included. Its steps/s runs from its first progress line to its last, past start-up; a run too
    quick for two lines (they come 5 s apart at most) takes its last line's rate, which its first
    steps are in (``steady`` False)."""
    verb = CLI_VERBS[name]
    settings = [f"trainer.max_steps={steps}", f"trainer.val_every_steps={max(1, steps // 2)}", "trainer.gif_every=1"]
    settings += [f"trainer.compile={'on' if compiled else 'off'}"]
    command, env = from_this_checkout(verb, "--config", "demo", *(f"--set={s}" for s in settings))
    run = timed(command, project, env)
    if run.returncode != 0:
        raise RuntimeError(f"m2d2m {verb} exited {run.returncode}: {run.lines[-1][1] if run.lines else ''}")
    progress = [(at, int(match[1]), line) for at, line in run.lines if (match := PROGRESS.match(line))]
    if not progress:
        raise RuntimeError(f"m2d2m {verb} printed no progress line")
    (first_at, first, _), (last_at, last, last_line) = progress[0], progress[-1]
    if len(progress) >= 2:
        rate, steady = (last - first) / max(last_at - first_at, 1e-9), True
    elif stated := LINE_RATE.search(last_line):
        rate, steady = float(stated[1]) if stated[2] == "step/s" else 1 / float(stated[1]), False
    else:
        raise RuntimeError(f"m2d2m {verb} printed no rate: {last_line}")
    return CliFigure(name, verb, compiled, steps, run.total, rate, run.after_finished, steady)


# ------------------------------------------------------------------------------------------- serving
def measure_serving(quick: bool) -> dict[str, Any]:
    """bench/serve.py's load test on the demo's trained models, or why it was skipped."""
    if quick:
        return {"skipped": "--quick"}
    if not (PROJECT / "runs" / "synthetic" / "m2d2m" / "latest").exists():
        return {"skipped": "no trained demo model in runs/synthetic (make demo first)"}
    try:
        import fastapi  # noqa: F401
    except ImportError:
        return {"skipped": "FastAPI is not installed"}
    command = [sys.executable, str(PROJECT / "bench" / "serve.py"), "--rounds", "3"]
    answer = subprocess.run(command, capture_output=True, text=True, cwd=PROJECT, check=False)
    return {"command": " ".join(command[1:]), "returncode": answer.returncode, "markdown": answer.stdout.strip()}


# -------------------------------------------------------------------------------------------- report
def _cell(value: Any, digits: int = 3) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return str(value)


def _percent(share: float | None) -> str:
    return "–" if share is None else f"{100 * share:.1f} %"


def report(result: dict[str, Any]) -> str:
    """The Markdown of BENCHMARKS.md's GPU section."""
    info = result["machine"]
    peak = f"{info['bf16_peak_tflops']:g} TFLOP/s bf16" if info["bf16_peak_tflops"] else "peak unknown"
    lines = [
        f"Device: {info['device']} ({peak}); torch {info['torch']}, Lightning {info['lightning']}, "
        f"Python {info['python']}, {info['cores']} cores, {info['torch_threads']} torch threads"
        + (" — `--quick`: proves it runs, not speed" if result["quick"] else ""),
        "",
        "| model | size | parameters | batch | precision | compiled | warm-up (s) | steps/s | samples/s "
        "| GPU busy % | peak GiB | GFLOP/step | TFLOP/s | of peak |",
        "|---|---|---:|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for f in result["training"]:
        lines.append(
            f"| {f['model']} | {f['size']} | {f['parameters'] / 1e6:.1f} M | {f['batch']} | {f['precision']} "
            f"| {'yes' if f['compiled'] else 'no'} | {_cell(f['warmup_s'])} | {_cell(f['steps_per_s'])} | {_cell(f['samples_per_s'])} | {_cell(f['gpu_utilisation'])} "
            f"| {_cell(f['peak_memory_gib'])} | {_cell(f['gflop_per_step'])} | {_cell(f['tflops'])} "
            f"| {_percent(f['share_of_peak'])} |"
        )
    lines += [
        "",
        "| model | size | batch | frames | steps | precision | call (s) | AITS (s) | AITS at all steps (s) |",
        "|---|---|---:|---:|---:|---|---:|---:|---:|",
    ]
    for f in result["sampling"]:
        lines.append(
            f"| {f['model']} | {f['size']} | {f['batch']} | {f['frames']} | {_cell(f['steps'])} | {f['precision']} "
            f"| {_cell(f['seconds'])} | {_cell(f['aits'])} | {_cell(f['aits_at_all_steps'])} |"
        )
    lines += [
        "",
        "| long sequence | method | compiled | actions | minutes | steps | seconds | at all steps (s) | first call (s) |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for f in result["long"]:
        lines.append(
            f"| {f['model']} | {f['method']} | {'yes' if f['compiled'] else 'no'} | {f['actions']} "
            f"| {f['minutes']:.3f} | {_cell(f['steps'])} | {_cell(f['seconds'])} | {_cell(f['seconds_at_all_steps'])} "
            f"| {_cell(f['first_call_seconds'])} |"
        )
    if result["cli"]:
        synthetic = {(f["model"], f["compiled"]): f["steps_per_s"] for f in result["training"] if f["size"] == "demo"}
        lines += [
            "",
            "| command (demo config) | compiled | steps | total (s) | steps/s (* whole run) | synthetic steps/s "
            "| synthetic ÷ CLI "
            "| last line → exit (s) |",
            "|---|---|---:|---:|---:|---:|---:|---:|",
        ]
        for f in result["cli"]:
            bench = synthetic.get((f["model"], f["compiled"]))
            ratio = None if bench is None else bench / f["steps_per_s"]
            lines.append(
                f"| `m2d2m {f['verb']}` | {'yes' if f['compiled'] else 'no'} | {f['steps']} | {_cell(f['total_s'])} "
                f"| {_cell(f['steps_per_s'])}{'' if f.get('steady', True) else ' *'} | {_cell(bench)} | {_cell(ratio)} "
                f"| {_cell(f['finished_to_exit_s'])} |"
            )
    serving = result.get("serving", {"skipped": "not reached"})
    lines += ["", f"Serving: skipped ({serving['skipped']})" if "skipped" in serving else serving["markdown"]]
    lines += [f"\nFailed: {failure}" for failure in result["failures"]]
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------------- run
def training_batches(args: argparse.Namespace, size: str, config: dict[str, Any]) -> list[int]:
    """The batches a model is trained at: ``--batch``, at paper size ``--paper-batches``, else its config's."""
    if args.batch:
        return [args.batch]
    return args.paper_batches if size == "paper" and args.paper_batches else [config["data"]["batch_size"]]


class Results:
    """The figures so far, written to ``gpu.json`` and ``gpu.md`` after each one (so a run that is
    stopped keeps what it measured); a measurement that fails is recorded and the run goes on."""

    def __init__(self, out: Path, quick: bool, info: dict[str, Any]) -> None:
        self.out = out
        self.result: dict[str, Any] = {
            "quick": quick,
            "machine": info,
            "training": [],
            "sampling": [],
            "long": [],
            "cli": [],
            "failures": [],
        }

    def add(self, table: str | None, what: str, measure: Callable[[], Any]) -> Any:
        """``measure()``'s figure, appended to ``table`` (None: a step, not a figure), or None if it failed."""
        print(f"{what} …", flush=True)
        try:
            figure = measure()
        except Exception as error:  # one model's failure must not lose the others' figures
            self.result["failures"].append(f"{what}: {type(error).__name__}: {error}")
            print(f"  failed: {type(error).__name__}: {error}", flush=True)
            figure = None
        else:
            if table is not None:
                self.result[table].append(asdict(figure))
        self.write()
        return figure

    def write(self) -> str:
        markdown = report(self.result)
        (self.out / "gpu.json").write_text(json.dumps(self.result, indent=1), encoding="utf-8")
        (self.out / "gpu.md").write_text(markdown + "\n", encoding="utf-8")
        return markdown


def measure(args: argparse.Namespace) -> Results:
    device = torch.device(args.device)
    info = machine(device)
    out = Path(args.out)
    work = out / WORK
    results = Results(out, args.quick, info)
    clip = results.add(None, "writing a random CLIP text tower", lambda: random_clip(work / "clip-random"))
    compiled_last = None  # compiling takes minutes: M2D2M's compiled long sequence comes after every other figure
    for name in args.models:
        for size in args.sizes:
            torch.manual_seed(0)
            built = results.add(None, f"building {name} ({size})", lambda: build(name, size, work, clip))
            if built is None:
                continue
            for batch in training_batches(args, size, built.config):
                eager_flops = None  # a step's FLOPs, counted eagerly, for the compiled step's share of the peak
                for compiled in [mode == "on" for mode in args.train_compile]:
                    figure = results.add(
                        "training",
                        f"training {name} ({size}) at batch {batch}" + (", compiled" if compiled else ""),
                        lambda: measure_training(
                            name,
                            size,
                            built,
                            batch,
                            args.steps,
                            args.warmup,
                            device,
                            info["bf16_peak_tflops"],
                            compiled,
                            eager_flops if compiled else None,
                        ),
                    )
                    if figure is not None and not compiled:
                        eager_flops = int(figure.gflop_per_step * 1e9)
            if name == "vq":
                continue
            generator = results.add(
                None,
                f"loading {name} ({size})'s model file",
                lambda: model(name).load("generator").load(built.save(work / f"{name}-{size}.pt"), device),
            )
            if generator is None:
                continue
            for sampled in args.batches:
                results.add(
                    "sampling",
                    f"sampling {name} ({size}) at batch {sampled}",
                    lambda: measure_sampling(generator, size, sampled, args.frames, args.repeats, args.md_steps),
                )
            if size == args.sizes[-1]:  # the largest size asked
                what = f"the {args.long_minutes}-minute sequence by {name}"
                results.add("long", what, lambda: measure_long(generator, args.long_minutes, args.md_long_steps))
                if name == "m2d2m" and args.long_compiled:
                    compiled_last = (what + ", compiled", generator)
    if args.cli_project is not None:
        # the VQ-VAE last: a new one is the project's latest, and the others' tokens would be made anew
        for name in sorted(args.models, key=lambda name: name == "vq"):
            for compiled in [mode == "on" for mode in args.train_compile]:
                results.add(
                    "cli",
                    f"m2d2m {CLI_VERBS[name]} in {args.cli_project}" + (", compiled" if compiled else ""),
                    lambda: measure_cli(name, Path(args.cli_project), args.cli_steps, compiled),
                )
    if compiled_last is not None:
        what, generator = compiled_last
        results.add("long", what, lambda: measure_long(generator, args.long_minutes, args.md_long_steps, compiled=True))
    results.result["serving"] = measure_serving(args.quick)
    return results


def parse(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--quick", action="store_true", help="demo sizes, 2 steps, batches of 2, a 0.1-minute sequence: CI's run"
    )
    parser.add_argument("--models", nargs="+", choices=MODELS, default=list(MODELS))
    parser.add_argument("--sizes", nargs="+", choices=SIZES, default=list(SIZES), help="the long sequence: the last")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--steps", type=int, default=30, help="timed training steps per model and size")
    parser.add_argument("--warmup", type=int, default=5, help="untimed training steps first")
    parser.add_argument("--batch", type=int, default=None, help="training batch (default: each config's)")
    parser.add_argument(
        "--paper-batches",
        type=int,
        nargs="+",
        default=None,
        help="training batches at paper size (default: the config's)",
    )
    parser.add_argument(
        "--train-compile",
        nargs="+",
        choices=("off", "on"),
        default=None,
        help="training steps eager (off), compiled (on) or both (default: both on a GPU, eager on a CPU)",
    )
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 32], help="sampling batches for AITS")
    parser.add_argument("--frames", type=int, default=FRAMES, help="frames of each sampled action")
    parser.add_argument("--repeats", type=int, default=3, help="timed sampling calls (median)")
    parser.add_argument("--long-minutes", type=float, default=10.873, help="MMM's long sequence")
    parser.add_argument("--md-steps", type=int, default=None, help="MotionDiffuse's AITS steps (default: all)")
    parser.add_argument("--md-long-steps", type=int, default=50, help="MotionDiffuse's steps on the long sequence")
    parser.add_argument(
        "--long-compiled", action="store_true", help="also M2D2M's long sequence with its denoiser compiled"
    )
    parser.add_argument(
        "--cli-project",
        default=None,
        help="also time each model's training verb through the command line in this project (it has the demo's "
        "data and tokens: `make data && make train-vq`)",
    )
    parser.add_argument("--cli-steps", type=int, default=200, help="steps of each command-line training")
    parser.add_argument("--out", default=None, help="default runs/bench/gpu/<machine>-<time>")
    args = parser.parse_args(argv)
    if args.train_compile is None:
        args.train_compile = ["off", "on"] if args.device.startswith("cuda") else ["off"]
    args.train_compile = sorted(set(args.train_compile))  # eager first: it counts the FLOPs
    if args.quick:
        args.sizes, args.steps, args.warmup, args.batch, args.batches = ["demo"], 2, 1, 2, [1, 2]
        args.frames, args.repeats, args.long_minutes, args.md_steps, args.md_long_steps = 40, 1, 0.1, 2, 2
        args.cli_steps = 4
    counts = (
        args.steps,
        args.warmup + 1,
        *args.batches,
        *(args.paper_batches or [1]),
        args.frames,
        args.repeats,
        args.md_steps or 1,
        args.md_long_steps,
    )
    if min(counts) < 1:
        parser.error(
            "--steps, --batches, --paper-batches, --frames, --repeats and --md-*steps must be >= 1, --warmup >= 0"
        )
    if args.out is None:
        stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
        label = "cpu" if args.device == "cpu" else torch.cuda.get_device_name(0).replace(" ", "-")
        args.out = str(PROJECT / "runs" / "bench" / "gpu" / f"{label}-{stamp}")
    return args


@contextlib.contextmanager
def quiet() -> Iterator[None]:
    """Only this script's lines and the table: Lightning's per-fit notices (accelerators found, tips)
    and its warning about the frozen CLIP tower's eval mode would repeat for every model. Restored
    afterwards, for a caller in the same process (a test)."""
    lightning = logging.getLogger("lightning.pytorch")
    level = lightning.level
    lightning.setLevel(logging.WARNING)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*module\\(s\\) in eval mode.*")
            yield
    finally:
        lightning.setLevel(level)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parse(argv)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    with quiet():
        try:
            results = measure(args)
        finally:  # random model files and CLIP's tower: hundreds of MB at paper size, no result
            shutil.rmtree(Path(args.out) / WORK, ignore_errors=True)
    print(results.write())
    print(f"\nwritten to {args.out}")
    if results.result["failures"]:
        sys.exit(1)
    return results.result


if __name__ == "__main__":
    main()
