"""AITS (average inference time per sentence) against motion length for MMM and M2D2M in one run,
as MMM's supplement Fig. 11 plots it, and MMM's long-sequence figure (§5.2: 10.873 minutes of
motion in 1.658 s on an RTX A5000) against M2D2M's Two-Phase Sampling on the same actions.

AITS is MLD's metric as MMM uses it (Table 7): the wall time of text → motion for one sentence,
model loading excluded. Here that is one call of a model's generator (text encoding, token
sampling, VQ-VAE decoding) with its single-action preset for one sentence (batch 1); a batch of B
sentences in one call has an AITS of the call's time / B. Every (model, batch, length) gets
``--warmup`` untimed calls, then ``--repeats`` timed ones, each with other sentences and seeds,
in rounds that time every setting once (the machine may be shared: load that comes and goes then
slows every setting alike); reported are the median and the range.

Why the times grow with length: MMM decodes L tokens in T_dyn = ⌈T·L/M⌉ iterations (§3.2; M the
corpus's longest motion in tokens, T = 10), so both the number of passes and their width grow;
M2D2M always takes T steps (two passes each for guidance, batched), only their width grows.

The long sequence: ``--long-minutes`` of motion at the models' frame rate in the fewest actions of
at most ``--action-frames`` frames, whole tokens, as even as possible (10.873 min at 20 fps =
3,262 tokens = 46 actions of 196 frames and 21 of 192), generated as one sequence by MMM's
``transition`` and M2D2M's ``tps`` (each model's multi-action preset): one warm-up call each,
then ``--long-repeats`` rounds.

    python bench/aits.py [--mmm latest] [--m2d2m latest] [--dataset synthetic] [--lengths 40 80 120 160 196]
                         [--batches 1 32] [--warmup 2] [--repeats 5] [--long-repeats 3] [--out DIR]

Writes ``aits.json`` (every call's time) and ``aits.png`` into ``--out`` (runs/<dataset>/bench/aits)
and prints Markdown. About 9 minutes on a quiet 2-core machine with the demo's models; on a loaded
one, give ``--threads 1`` (BENCHMARKS.md: 2 intra-op threads on 2 busy cores are 40× slower).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
from collections import Counter
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from datetime import datetime
from functools import partial
from itertools import count
from pathlib import Path
from typing import Any

import torch
from tqdm import tqdm

from m2d2m.generators.protocol import MULTI, SINGLE, MotionGenerator
from m2d2m.processes.masking import dynamic_iterations
from orchestration.errors import UserError
from orchestration.generate import load_generator
from timing import interleaved_times

PROMPTS = ("a person walks forward", "a person jumps", "a person waves their right hand", "a person sits down")
LONG_METHODS = {"mmm": "transition", "m2d2m": "tps"}  # each model's long-sequence method, in plotting order
MMM_MINUTES, MMM_SECONDS, MMM_GPU = 10.873, 1.658, "RTX A5000"  # MMM §5.2


@dataclass
class Timing:
    """The timed calls of one model at one batch size and action length."""

    model: str
    batch: int  # sentences per call
    frames: int  # of each sentence's motion
    passes: int  # sampler iterations: MMM's T_dyn, M2D2M's T (each a guided pair of passes)
    times: list[float]  # seconds per call

    @property
    def aits(self) -> float:
        """The median call's seconds per sentence."""
        return statistics.median(self.times) / self.batch

    @property
    def spread(self) -> tuple[float, float]:
        """The fastest and slowest call's seconds per sentence."""
        return min(self.times) / self.batch, max(self.times) / self.batch

    def record(self) -> dict[str, Any]:
        return {**asdict(self), "aits": self.aits, "spread": list(self.spread)}


def sampler_passes(generator: MotionGenerator, options: Any, frames: int) -> int:
    """Iterations of the sampler for one action of ``frames`` frames: MMM's T_dyn (§3.2), M2D2M's T."""
    if generator.model == "mmm":
        return dynamic_iterations(frames // generator.frame_step, generator.lengths.longest, options.iterations)
    return generator.checkpoint.schedule.steps


def parameter_counts(generator: MotionGenerator) -> dict[str, int]:
    """Parameters of every network a token model's generator runs: its model file's and the VQ-VAE."""
    modules = {field.name: getattr(generator.checkpoint, field.name) for field in fields(generator.checkpoint)}
    modules["vq"] = generator.codec.vq
    return {name: sum(p.numel() for p in module.parameters())
            for name, module in modules.items() if isinstance(module, torch.nn.Module)}


def request(batch: int, call: int) -> tuple[list[list[str]], list[int]]:
    """Call ``call``'s one-action sequences, cycling through :data:`PROMPTS`, and their seeds."""
    return [[PROMPTS[(call + j) % len(PROMPTS)]] for j in range(batch)], [call * batch + j for j in range(batch)]


def sentence_call(generator: MotionGenerator, batch: int, frames: int) -> Callable[[], None]:
    """One call of single-action generation of ``batch`` sentences of ``frames`` frames; each
    call has the next sentences and seeds."""
    options = generator.options(SINGLE)
    calls = count()

    def run() -> None:
        actions, seeds = request(batch, next(calls))
        generator.generate(actions, [[frames]] * batch, options, seeds)

    return run


def measure_aits(generators: dict[str, MotionGenerator], lengths: list[int], batches: list[int], warmup: int,
                 repeats: int) -> list[Timing]:
    """Every batch size, model and length, timed in interleaved rounds."""
    settings = [(batch, name, frames) for batch in batches for name in generators for frames in lengths]
    device = next(iter(generators.values())).device
    times = interleaved_times([sentence_call(generators[name], batch, frames) for batch, name, frames in settings],
                              warmup, repeats, device, desc="AITS")
    return [Timing(name, batch, frames, sampler_passes(generators[name], generators[name].options(SINGLE), frames),
                   seconds) for (batch, name, frames), seconds in zip(settings, times)]


def long_plan(minutes: float, fps: float, frame_step: int, action_frames: int) -> list[int]:
    """Each action's frames for ``minutes`` of motion: the fewest actions of at most
    ``action_frames`` frames, in whole steps of ``frame_step`` frames, as even as possible."""
    steps = max(1, round(minutes * 60 * fps / frame_step))
    actions = math.ceil(steps / max(1, action_frames // frame_step))
    base, longer = divmod(steps, actions)
    return [(base + 1) * frame_step] * longer + [base * frame_step] * (actions - longer)


def measure_long(generators: dict[str, MotionGenerator], frames: list[int], repeats: int) -> dict[str, list[float]]:
    """Seconds per call of each model's long-sequence method on one sequence of ``frames``, after
    a warm-up call that checks the length."""
    actions = [[PROMPTS[j % len(PROMPTS)] for j in range(len(frames))]]
    runs = {name: partial(generator.generate, actions, [frames], generator.options(MULTI, method=LONG_METHODS[name]),
                          [0]) for name, generator in generators.items()}
    for name, run in tqdm(runs.items(), desc="long sequence, warm-up", unit="model"):
        made = len(run()[0].features)
        if made != sum(frames):
            raise RuntimeError(f"{name} made {made} frames of the {sum(frames)} asked for")
    device = next(iter(generators.values())).device
    return dict(zip(runs, interleaved_times(list(runs.values()), 0, repeats, device, desc="long sequence")))


def load(checkpoints: dict[str, str], dataset: str) -> dict[str, MotionGenerator]:
    """Every model's generator, or one UserError naming each that is missing and how to train it."""
    generators, errors = {}, []
    for name, checkpoint in checkpoints.items():
        try:
            generators[name] = load_generator(name, checkpoint, dataset)
        except UserError as error:
            errors.append(str(error))
    if errors:
        raise UserError("; ".join(errors))
    return generators


def check_lengths(generators: dict[str, MotionGenerator], lengths: list[int], action_frames: int) -> None:
    """A one-line refusal of lengths a model cannot generate, before anything is timed."""
    for name, generator in generators.items():
        for frames in [*lengths, action_frames]:
            if not generator.frame_step <= frames <= generator.longest_frames or frames % generator.frame_step:
                raise UserError(f"{frames} frames: {name} generates multiples of {generator.frame_step} frames "
                                f"up to {generator.longest_frames}")
    if len({generator.fps for generator in generators.values()}) > 1:
        raise UserError("the models run at different frame rates; compare models of one dataset")


def machine(device: torch.device) -> dict[str, Any]:
    """What the times were measured on, and how loaded it was (the machine may be shared)."""
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else platform.processor() or platform.machine()
    return {"device": name, "cores": os.cpu_count(), "torch_threads": torch.get_num_threads(),
            "torch": torch.__version__, "load": list(os.getloadavg())}


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """Every measurement, as the JSON written next to the figure."""
    generators = load({name: getattr(args, name) for name in LONG_METHODS}, args.dataset)
    check_lengths(generators, args.lengths, args.action_frames)
    first = next(iter(generators.values()))
    frame_step = math.lcm(*(generator.frame_step for generator in generators.values()))
    frames = long_plan(args.long_minutes, first.fps, frame_step, args.action_frames)
    started = machine(first.device)
    timings = measure_aits(generators, args.lengths, args.batches, args.warmup, args.repeats)
    long = measure_long(generators, frames, args.long_repeats)
    medians = {name: statistics.median(times) for name, times in long.items()}
    return {
        "date": datetime.now().isoformat(timespec="minutes"),
        "fps": first.fps,
        "machine": {**started, "load_after": list(os.getloadavg())},
        "models": {name: {"checkpoint": str(generator.source), "parameters": parameter_counts(generator),
                          "single": generator.describe(generator.options(SINGLE)),
                          "long": generator.describe(generator.options(MULTI, method=LONG_METHODS[name]))}
                   for name, generator in generators.items()},
        "settings": {"warmup": args.warmup, "repeats": args.repeats, "long_repeats": args.long_repeats},
        "aits": [timing.record() for timing in timings],
        "long": {"minutes": sum(frames) / first.fps / 60, "actions": len(frames), "frames": frames,
                 "methods": LONG_METHODS, "times": long, "median": medians,
                 "ratio": medians["m2d2m"] / medians["mmm"],
                 "mmm_paper": {"minutes": MMM_MINUTES, "seconds": MMM_SECONDS, "gpu": MMM_GPU}},
    }


def report(result: dict[str, Any]) -> str:
    """The measurements as Markdown: one AITS table per batch size, then the long sequence."""
    timings = [Timing(**{f.name: row[f.name] for f in fields(Timing)}) for row in result["aits"]]
    models = list(dict.fromkeys(t.model for t in timings))
    info = result["machine"]
    lines = [f"{result['date']}; {info['device']}, {info['cores']} cores, {info['torch_threads']} torch threads, "
             f"torch {info['torch']}; load average {info['load'][0]:.2f} before, {info['load_after'][0]:.2f} after; "
             f"median [min–max] of {result['settings']['repeats']} calls after {result['settings']['warmup']} "
             "warm-ups"]
    lines += [f"- {name}: {model['checkpoint']}, parameters {model['parameters']}; single: {model['single']}"
              for name, model in result["models"].items()]
    for batch in dict.fromkeys(t.batch for t in timings):
        rows = {(t.model, t.frames): t for t in timings if t.batch == batch}
        header = " | ".join(f"{m} passes | {m} AITS (ms) | {m} per pass (ms)" for m in models)
        lines += ["", f"AITS, {batch} sentence(s) per call", "", f"| frames | {header} | {models[-1]} / {models[0]} |",
                  "| --- " * (2 + 3 * len(models)) + "|"]
        for frames in dict.fromkeys(t.frames for t in timings):
            cells = []
            for model in models:
                t = rows[(model, frames)]
                low, high = t.spread
                cells.append(f"{t.passes} | {1e3 * t.aits:.1f} [{1e3 * low:.1f}–{1e3 * high:.1f}] | "
                             f"{1e3 * t.aits / t.passes:.2f}")
            ratio = rows[(models[-1], frames)].aits / rows[(models[0], frames)].aits
            lines.append(f"| {frames} | {' | '.join(cells)} | {ratio:.1f} |")
    long = result["long"]
    lines += ["", f"Long sequence: {long['minutes']:.3f} min in {long['actions']} actions "
              f"({', '.join(f'{n} × {f}' for f, n in sorted(Counter(long['frames']).items(), reverse=True))} frames), "
              f"{len(next(iter(long['times'].values())))} calls after a warm-up", "",
              "| model | method | median (s) | range (s) |", "| --- | --- | --- | --- |"]
    lines += [f"| {name} | {long['methods'][name]} | {long['median'][name]:.2f} | {min(times):.2f}–{max(times):.2f} |"
              for name, times in long["times"].items()]
    paper = long["mmm_paper"]
    lines += ["", f"m2d2m / mmm: {long['ratio']:.1f}×; MMM's paper: {paper['minutes']} min in {paper['seconds']} s "
              f"on an {paper['gpu']}", ""]
    return "\n".join(lines)


def plot(path: Path, result: dict[str, Any]) -> None:
    """AITS against frames, one curve per model and batch size (Fig. 11's axes), log time."""
    from matplotlib.figure import Figure

    figure = Figure(figsize=(6.4, 4.0), dpi=110, layout="constrained")
    axes = figure.subplots()
    colours = {name: f"C{i}" for i, name in enumerate(LONG_METHODS)}
    for model, batch in dict.fromkeys((row["model"], row["batch"]) for row in result["aits"]):
        rows = [row for row in result["aits"] if row["model"] == model and row["batch"] == batch]
        x = [row["frames"] for row in rows]
        y = [row["aits"] for row in rows]
        error = [[row["aits"] - row["spread"][0] for row in rows], [row["spread"][1] - row["aits"] for row in rows]]
        axes.errorbar(x, y, yerr=error, marker="o" if batch == 1 else "s", capsize=3, color=colours[model],
                      linestyle="-" if batch == 1 else "--", label=f"{model}, batch {batch}")
        if batch == 1:
            for row in rows:
                axes.annotate(str(row["passes"]), (row["frames"], row["aits"]), textcoords="offset points",
                              xytext=(5, 3), ha="left", fontsize="x-small", color=colours[model])
    long = result["long"]
    info = result["machine"]
    axes.set(xlabel=f"frames ({result['fps']:g} fps); over the points: sampler iterations (MMM's T_dyn, M2D2M's T)",
             ylabel="AITS (s): median, range", yscale="log")
    axes.set_title(f"AITS by motion length, {info['device']}, {info['cores']} cores, "
                   f"{info['torch_threads']} torch thread(s)\n"
                   f"{long['minutes']:.3f} min in {long['actions']} actions: "
                   + ", ".join(f"{name} {long['methods'][name]} {seconds:.2f} s"
                               for name, seconds in long["median"].items()),
                   fontsize="medium")
    axes.grid(alpha=0.3, which="both")
    axes.legend(fontsize="small")
    figure.savefig(path)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    for name, hint in (("mmm", "make train-mmm"), ("m2d2m", "make train-diffusion")):
        parser.add_argument(f"--{name}", default="latest",
                            help=f"{name}'s model: latest, a run or its model.pt ({hint})")
    parser.add_argument("--dataset", default="synthetic")
    parser.add_argument("--lengths", type=int, nargs="+", default=[40, 80, 120, 160, 196], help="frames per sentence")
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 32], help="sentences per call")
    parser.add_argument("--warmup", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--long-minutes", type=float, default=MMM_MINUTES)
    parser.add_argument("--action-frames", type=int, default=196, help="the long sequence's longest action")
    parser.add_argument("--long-repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=os.cpu_count(), help="torch threads")
    parser.add_argument("--out", default=None, help="where aits.json and aits.png go (runs/<dataset>/bench/aits)")
    args = parser.parse_args(argv)
    if min(args.batches + [args.repeats, args.long_repeats, args.threads]) < 1 or args.warmup < 0 \
            or not args.long_minutes > 0:
        parser.error("batches, repeats and threads must be at least 1, --warmup at least 0, --long-minutes positive")

    torch.set_num_threads(args.threads)
    try:
        result = measure(args)
    except UserError as error:
        raise SystemExit(f"bench/aits.py: {error}") from None
    out = Path(args.out or f"runs/{args.dataset}/bench/aits")
    out.mkdir(parents=True, exist_ok=True)
    (out / "aits.json").write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
    plot(out / "aits.png", result)
    print(report(result))
    print(f"wrote {out / 'aits.json'} and {out / 'aits.png'}")


if __name__ == "__main__":
    main()
