"""AITS (average inference time per sentence) against motion length for MMM, M2D2M and MotionDiffuse
in one run, as MMM's supplement Fig. 11 plots it, and MMM's long-sequence figure (§5.2: 10.873
minutes of motion in 1.658 s on an RTX A5000) against M2D2M's Two-Phase Sampling and MotionDiffuse's
time-varied control (Zhang et al. 2022, §3.5) on the same actions.

AITS is MLD's metric as MMM uses it (Table 7): the wall time of text → motion for one sentence,
model loading excluded. Here that is one call of a model's generator (text encoding, token
sampling, VQ-VAE decoding) with its single-action preset for one sentence (batch 1); a batch of B
sentences in one call has an AITS of the call's time / B. Every (model, batch, length) gets
``--warmup`` untimed calls, then ``--repeats`` timed ones, each with other sentences and seeds,
in rounds that time every setting once (the machine may be shared: load that comes and goes then
slows every setting alike); reported are the median and the range.

Why the times grow with length: MMM decodes L tokens in T_dyn = ⌈T·L/M⌉ iterations (§3.2; M the
corpus's longest motion in tokens, T = 10), so both the number of passes and their width grow;
M2D2M takes its steps whatever the length (two passes each for guidance, batched), only their
width grows: all T = 100 of its schedule in the paper, fewer when it jumps with exact posteriors
(``steps``; each of ``--m2d2m-steps`` is a series of its own, "m2d2m (25 steps)", at ``--batches``).
MotionDiffuse denoises the features themselves (no codec) in one pass per step, and its number of
steps does not depend on the length either, but it runs all T = 1000 steps it was trained with
(the paper's setting): ten times M2D2M's T = 100. The respaced sampler (Nichol & Dhariwal 2021,
§4: ``steps`` below T) is what makes it usable, so each of ``--md-steps`` (1000 and 100) is a
series of its own, "motiondiffuse (100 steps)"; the report gives their ratio, what respacing buys
in time (what it costs in quality is ``make compare``'s question, not this script's). A
MotionDiffuse step at batch 32 costs 12–32 times one at batch 1 on a CPU (40–196 frames), so 1000
steps at batch 32 would take minutes a call: ``--md-batches`` (default 1) says at which batch
sizes MotionDiffuse is timed.

The long sequence: ``--long-minutes`` of motion at the models' frame rate in the fewest actions of
at most ``--action-frames`` frames, whole tokens, as even as possible (10.873 min at 20 fps =
3,262 tokens = 46 actions of 196 frames and 21 of 192), generated as one sequence by MMM's
``transition``, M2D2M's ``tps`` and MotionDiffuse's ``time-varied`` (each model's multi-action
preset, M2D2M's with the steps its model file samples with unless ``--m2d2m-long-steps``): one
warm-up call each, then ``--long-repeats`` rounds. MotionDiffuse's takes
``--md-long-steps`` steps (default 50, respaced), not the paper's 1000: every step denoises all 67
intervals at once (one per action, reaching ``overlap`` frames into its neighbours as far as the
network's longest pass allows), and where they overlap the correction λ2·∇Σ‖ε_i − ε_j‖ (eq. 11)
adds a backward pass through the network, so on a CPU one step takes seconds and 1000 of them
about an hour. A step costs the same whatever their number, so the report also gives the time at
all T steps extrapolated from the measured one (× T / steps).

    python bench/aits.py [--mmm latest] [--m2d2m latest] [--motiondiffuse latest] [--dataset synthetic]
                         [--lengths 40 80 120 160 196] [--batches 1 32] [--m2d2m-steps 100 50 25 10]
                         [--m2d2m-long-steps N] [--md-steps 1000 100] [--md-batches 1]
                         [--md-long-steps 50] [--warmup 2] [--repeats 5] [--long-repeats 3] [--out DIR]

Writes ``aits.json`` (every call's time) and ``aits.png`` into ``--out`` (runs/<dataset>/bench/aits)
and prints Markdown. MMM and M2D2M took about 9 minutes on a quiet 2-core machine with the demo's
models. MotionDiffuse adds more, estimated (not yet run end to end) from single passes of the demo's
network (width 272, 2 layers) on one thread of a loaded 2-core machine: 8–16 ms a pass at batch 1
over 40–196 frames, so 8–16 s a 1000-step call and some 8 minutes for its 35 calls of the AITS
table; about 1 s for a forward pass over the long sequence's 67 intervals, with the correction's
backward pass some 3 s a step, so 2–3 minutes a 50-step call and some 10 minutes for the four.
On a loaded machine, give ``--threads 1`` (BENCHMARKS.md: 2 intra-op threads on 2 busy cores are
40× slower).
"""

from __future__ import annotations

import argparse
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
from timing import interleaved_times, publish
from tqdm import tqdm

from m2d2m.generators.options import MULTI, SINGLE
from m2d2m.generators.protocol import MotionGenerator
from m2d2m.processes.masking import dynamic_iterations
from orchestration.errors import UserError
from orchestration.generate import load_generator

PROMPTS = ("a person walks forward", "a person jumps", "a person waves their right hand", "a person sits down")
LONG_METHODS = {"mmm": "transition", "m2d2m": "tps", "motiondiffuse": "time-varied"}  # in plotting order
TRAIN = {"mmm": "make train-mmm", "m2d2m": "make train-diffusion", "motiondiffuse": "make train-motiondiffuse"}
STEPPED = "motiondiffuse"  # the model whose long sequence runs fewer steps than it samples with (--md-long-steps)
STEP_SERIES = ("m2d2m", STEPPED)  # the models timed at several numbers of sampling steps (--m2d2m-steps, --md-steps)
MMM_MINUTES, MMM_SECONDS, MMM_GPU = 10.873, 1.658, "RTX A5000"  # MMM §5.2


@dataclass
class Timing:
    """The timed calls of one series (a model, and for MotionDiffuse a number of steps) at one batch
    size and action length."""

    model: str
    series: str  # the model's name, or "motiondiffuse (100 steps)"
    batch: int  # sentences per call
    frames: int  # of each sentence's motion
    passes: int  # sampler iterations: MMM's T_dyn, M2D2M's T (guided pairs of passes), MotionDiffuse's steps
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


@dataclass(frozen=True)
class Series:
    """One curve of the figure: a model's generator with the single-action options it is timed with,
    at the batch sizes it is timed at."""

    label: str
    model: str
    generator: MotionGenerator
    options: Any
    batches: tuple[int, ...]


def trained_steps(generator: MotionGenerator) -> int:
    """The steps a diffusion model's schedule has (M2D2M's T, MotionDiffuse's T)."""
    return generator.process.num_steps if generator.model == STEPPED else generator.checkpoint.schedule.steps


def sampler_passes(generator: MotionGenerator, options: Any, frames: int) -> int:
    """Iterations of the sampler for one action of ``frames`` frames: MMM's T_dyn (§3.2), M2D2M's and
    MotionDiffuse's steps (all T when ``steps`` is None; one pass each for MotionDiffuse, as a
    single action has no neighbour to correct towards; a guided pair for M2D2M)."""
    if generator.model == "mmm":
        return dynamic_iterations(frames // generator.frame_step, generator.lengths.longest, options.iterations)
    return trained_steps(generator) if options.steps is None else options.steps


def parameter_counts(generator: MotionGenerator) -> dict[str, int]:
    """Parameters of every network a generator runs: its model file's (MotionDiffuse's noise
    estimator and its text encoder) and a token model's VQ-VAE."""
    modules = {field.name: getattr(generator.checkpoint, field.name) for field in fields(generator.checkpoint)}
    codec = getattr(generator, "codec", None)
    if codec is not None:
        modules["vq"] = codec.vq
    return {
        name: sum(p.numel() for p in module.parameters())
        for name, module in modules.items()
        if isinstance(module, torch.nn.Module)
    }


def series_of(
    generators: dict[str, MotionGenerator], batches: list[int], steps: dict[str, list[int]], md_batches: list[int]
) -> list[Series]:
    """The figure's curves: each model with its single-action preset, M2D2M and MotionDiffuse once
    per number of steps in ``steps[model]`` (MotionDiffuse at ``md_batches``), the others at ``batches``."""
    series = []
    for name, generator in generators.items():
        batch_sizes = tuple(md_batches if name == STEPPED else batches)
        if name not in steps:
            series.append(Series(name, name, generator, generator.options(SINGLE), batch_sizes))
            continue
        series += [
            Series(f"{name} ({count} steps)", name, generator, generator.options(SINGLE, steps=count), batch_sizes)
            for count in steps[name]
        ]
    return series


def request(batch: int, call: int) -> tuple[list[list[str]], list[int]]:
    """Call ``call``'s one-action sequences, cycling through :data:`PROMPTS`, and their seeds."""
    return [[PROMPTS[(call + j) % len(PROMPTS)]] for j in range(batch)], [call * batch + j for j in range(batch)]


def sentence_call(generator: MotionGenerator, batch: int, frames: int, options: Any = None) -> Callable[[], None]:
    """One call of single-action generation of ``batch`` sentences of ``frames`` frames, with
    ``options`` (the single-action preset by default); each call has the next sentences and seeds."""
    options = generator.options(SINGLE) if options is None else options
    calls = count()

    def run() -> None:
        actions, seeds = request(batch, next(calls))
        generator.generate(actions, [[frames]] * batch, options, seeds)

    return run


def measure_aits(series: list[Series], lengths: list[int], warmup: int, repeats: int) -> list[Timing]:
    """Every batch size, series and length, timed in interleaved rounds."""
    batches = dict.fromkeys(batch for s in series for batch in s.batches)
    settings = [(batch, s, frames) for batch in batches for s in series if batch in s.batches for frames in lengths]
    device = series[0].generator.device
    times = interleaved_times(
        [sentence_call(s.generator, batch, frames, s.options) for batch, s, frames in settings],
        warmup,
        repeats,
        device,
        desc="AITS",
    )
    return [
        Timing(s.model, s.label, batch, frames, sampler_passes(s.generator, s.options, frames), seconds)
        for (batch, s, frames), seconds in zip(settings, times)
    ]


def long_plan(minutes: float, fps: float, frame_step: int, action_frames: int) -> list[int]:
    """Each action's frames for ``minutes`` of motion: the fewest actions of at most
    ``action_frames`` frames, in whole steps of ``frame_step`` frames, as even as possible."""
    steps = max(1, round(minutes * 60 * fps / frame_step))
    actions = math.ceil(steps / max(1, action_frames // frame_step))
    base, longer = divmod(steps, actions)
    return [(base + 1) * frame_step] * longer + [base * frame_step] * (actions - longer)


def long_options(generator: MotionGenerator, long_steps: dict[str, int]) -> Any:
    """A model's multi-action preset with its long-sequence method, with ``long_steps[model]``
    steps where given."""
    changes = {"steps": long_steps[generator.model]} if generator.model in long_steps else {}
    return generator.options(MULTI, method=LONG_METHODS[generator.model], **changes)


def measure_long(
    generators: dict[str, MotionGenerator], frames: list[int], repeats: int, long_steps: dict[str, int]
) -> dict[str, list[float]]:
    """Seconds per call of each model's long-sequence method on one sequence of ``frames``, after
    a warm-up call that checks the length."""
    actions = [[PROMPTS[j % len(PROMPTS)] for j in range(len(frames))]]
    runs = {
        name: partial(generator.generate, actions, [frames], long_options(generator, long_steps), [0])
        for name, generator in generators.items()
    }
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
                raise UserError(
                    f"{frames} frames: {name} generates multiples of {generator.frame_step} frames "
                    f"up to {generator.longest_frames}"
                )
    if len({generator.fps for generator in generators.values()}) > 1:
        raise UserError("the models run at different frame rates; compare models of one dataset")


def check_steps(
    generators: dict[str, MotionGenerator], steps: dict[str, list[int]], long_steps: dict[str, int]
) -> None:
    """A one-line refusal of step counts a model's schedule cannot be sampled with."""
    for name in STEP_SERIES:
        trained = trained_steps(generators[name])
        for steps_asked in [*steps[name], *([long_steps[name]] if name in long_steps else [])]:
            if not 1 <= steps_asked <= trained:
                flag = "--md" if name == STEPPED else f"--{name}"
                raise UserError(
                    f"{steps_asked} steps: {name} was trained with T = {trained} steps; give {flag}-steps and "
                    f"{flag}-long-steps from 1 to {trained}"
                )


def machine(device: torch.device) -> dict[str, Any]:
    """What the times were measured on, and how loaded it was (the machine may be shared)."""
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else platform.processor() or platform.machine()
    return {
        "device": name,
        "cores": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "load": list(os.getloadavg()),
    }


def measure(args: argparse.Namespace) -> dict[str, Any]:
    """Every measurement, as the JSON written next to the figure."""
    generators = load({name: getattr(args, name) for name in LONG_METHODS}, args.dataset)
    check_lengths(generators, args.lengths, args.action_frames)
    steps = {"m2d2m": args.m2d2m_steps, STEPPED: args.md_steps}
    long_steps = {STEPPED: args.md_long_steps, **({"m2d2m": args.m2d2m_long_steps} if args.m2d2m_long_steps else {})}
    check_steps(generators, steps, long_steps)
    first = next(iter(generators.values()))
    frame_step = math.lcm(*(generator.frame_step for generator in generators.values()))
    frames = long_plan(args.long_minutes, first.fps, frame_step, args.action_frames)
    started = machine(first.device)
    series = series_of(generators, args.batches, steps, args.md_batches)
    timings = measure_aits(series, args.lengths, args.warmup, args.repeats)
    long = measure_long(generators, frames, args.long_repeats, long_steps)
    medians = {name: statistics.median(times) for name, times in long.items()}
    trained = trained_steps(generators[STEPPED])
    return {
        "date": datetime.now().isoformat(timespec="minutes"),
        "fps": first.fps,
        "machine": {**started, "load_after": list(os.getloadavg())},
        "models": {
            name: {
                "checkpoint": str(generator.source),
                "parameters": parameter_counts(generator),
                "single": "; ".join(s.generator.describe(s.options) for s in series if s.model == name),
                "long": generator.describe(long_options(generator, long_steps)),
            }
            for name, generator in generators.items()
        },
        "settings": {
            "warmup": args.warmup,
            "repeats": args.repeats,
            "long_repeats": args.long_repeats,
            "m2d2m_steps": args.m2d2m_steps,
            "m2d2m_long_steps": args.m2d2m_long_steps,
            "md_steps": args.md_steps,
            "md_batches": args.md_batches,
            "md_long_steps": args.md_long_steps,
        },
        "aits": [timing.record() for timing in timings],
        "long": {
            "minutes": sum(frames) / first.fps / 60,
            "actions": len(frames),
            "frames": frames,
            "methods": LONG_METHODS,
            "times": long,
            "median": medians,
            "ratio": medians["m2d2m"] / medians["mmm"],
            "ratios": {name: median / medians["mmm"] for name, median in medians.items()},
            STEPPED: {
                "steps": args.md_long_steps,
                "trained_steps": trained,
                "extrapolated": medians[STEPPED] * trained / args.md_long_steps,
            },
            "mmm_paper": {"minutes": MMM_MINUTES, "seconds": MMM_SECONDS, "gpu": MMM_GPU},
        },
    }


def report(result: dict[str, Any]) -> str:
    """The measurements as Markdown: one AITS table per batch size (every series against the first,
    and what respacing buys MotionDiffuse), then the long sequence."""
    timings = [Timing(**{f.name: row[f.name] for f in fields(Timing)}) for row in result["aits"]]
    info = result["machine"]
    lines = [
        f"{result['date']}; {info['device']}, {info['cores']} cores, {info['torch_threads']} torch threads, "
        f"torch {info['torch']}; load average {info['load'][0]:.2f} before, {info['load_after'][0]:.2f} after; "
        f"median [min–max] of {result['settings']['repeats']} calls after {result['settings']['warmup']} "
        "warm-ups"
    ]
    lines += [
        f"- {name}: {model['checkpoint']}, parameters {model['parameters']}; single: {model['single']}"
        for name, model in result["models"].items()
    ]
    for batch in dict.fromkeys(t.batch for t in timings):
        rows = {(t.series, t.frames): t for t in timings if t.batch == batch}
        series = list(dict.fromkeys(t.series for t in timings if t.batch == batch))
        by_model: dict[str, list[str]] = {}
        for name in series:
            by_model.setdefault(rows[(name, timings[0].frames)].model, []).append(name)
        ratios = [(name, series[0]) for name in series[1:]]
        header = " | ".join(f"{name} passes | {name} AITS (ms) | {name} per pass (ms)" for name in series)
        lines += [
            "",
            f"AITS, {batch} sentence(s) per call",
            "",
            f"| frames | {header} | {' | '.join(f'{a} / {b}' for a, b in ratios)} |",
            "| --- " * (1 + 3 * len(series) + len(ratios)) + "|",
        ]
        for frames in dict.fromkeys(t.frames for t in timings):
            cells = []
            for name in series:
                t = rows[(name, frames)]
                low, high = t.spread
                cells.append(
                    f"{t.passes} | {1e3 * t.aits:.1f} [{1e3 * low:.1f}–{1e3 * high:.1f}] | "
                    f"{1e3 * t.aits / t.passes:.2f}"
                )
            cells += [f"{rows[(a, frames)].aits / rows[(b, frames)].aits:.1f}" for a, b in ratios]
            lines.append(f"| {frames} | {' | '.join(cells)} |")
        for model, stepped in by_model.items():
            if len(stepped) < 2:
                continue
            most, fewest = rows[(stepped[0], timings[0].frames)].passes, rows[(stepped[-1], timings[0].frames)].passes
            lines += [
                "",
                f"Fewer steps: {most} → {fewest} ({most / fewest:.1f}× fewer) makes {model}'s call "
                + ", ".join(
                    f"{rows[(stepped[0], f)].aits / rows[(stepped[-1], f)].aits:.1f}×"
                    for f in dict.fromkeys(t.frames for t in timings)
                )
                + " faster over the lengths above.",
            ]
    long = result["long"]
    md = long[STEPPED]
    lines += [
        "",
        f"Long sequence: {long['minutes']:.3f} min in {long['actions']} actions "
        f"({', '.join(f'{n} × {f}' for f, n in sorted(Counter(long['frames']).items(), reverse=True))} frames), "
        f"{len(next(iter(long['times'].values())))} calls after a warm-up",
        "",
        "| model | method | median (s) | range (s) | / mmm |",
        "| --- | --- | --- | --- | --- |",
    ]
    for name, times in long["times"].items():
        method = long["methods"][name]
        if name == STEPPED:
            method += f", {md['steps']} of T = {md['trained_steps']} steps"
        lines.append(
            f"| {name} | {method} | {long['median'][name]:.2f} | {min(times):.2f}–{max(times):.2f} | "
            f"{long['ratios'][name]:.1f} |"
        )
    paper = long["mmm_paper"]
    lines += [
        "",
        f"m2d2m / mmm: {long['ratio']:.1f}×; MMM's paper: {paper['minutes']} min in {paper['seconds']} s "
        f"on an {paper['gpu']}",
        f"{STEPPED} ran {md['steps']} of its T = {md['trained_steps']} steps (--md-long-steps): all "
        f"{md['trained_steps']} would take about {md['extrapolated']:.1f} s (× T / steps, not measured: a step "
        "costs the same whatever their number). Its time-varied correction adds a backward pass per step "
        "where intervals overlap.",
        "",
    ]
    return "\n".join(lines)


def plot(path: Path, result: dict[str, Any]) -> None:
    """AITS against frames, one curve per series and batch size (Fig. 11's axes), log time."""
    from matplotlib.figure import Figure

    figure = Figure(figsize=(7.2, 4.6), dpi=110, layout="constrained")
    axes = figure.subplots()
    colours = {name: f"C{i}" for i, name in enumerate(dict.fromkeys(row["series"] for row in result["aits"]))}
    for series, batch in dict.fromkeys((row["series"], row["batch"]) for row in result["aits"]):
        rows = [row for row in result["aits"] if row["series"] == series and row["batch"] == batch]
        x = [row["frames"] for row in rows]
        y = [row["aits"] for row in rows]
        error = [[row["aits"] - row["spread"][0] for row in rows], [row["spread"][1] - row["aits"] for row in rows]]
        axes.errorbar(
            x,
            y,
            yerr=error,
            marker="o" if batch == 1 else "s",
            capsize=3,
            color=colours[series],
            linestyle="-" if batch == 1 else "--",
            label=f"{series}, batch {batch}",
        )
        if batch == 1:
            for row in rows:
                axes.annotate(
                    str(row["passes"]),
                    (row["frames"], row["aits"]),
                    textcoords="offset points",
                    xytext=(5, 3),
                    ha="left",
                    fontsize="x-small",
                    color=colours[series],
                )
    long = result["long"]
    info = result["machine"]
    steps = {STEPPED: f" ({long[STEPPED]['steps']} steps)"}
    axes.set(
        xlabel=f"frames ({result['fps']:g} fps)\nover the points: sampler iterations "
        "(MMM's T_dyn, M2D2M's T, MotionDiffuse's steps)",
        ylabel="AITS (s): median, range",
        yscale="log",
    )
    axes.set_title(
        f"AITS by motion length, {info['device']}, {info['cores']} cores, "
        f"{info['torch_threads']} torch thread(s)\n"
        f"{long['minutes']:.3f} min in {long['actions']} actions: "
        + ", ".join(
            f"{name} {long['methods'][name]}{steps.get(name, '')} {seconds:.2f} s"
            for name, seconds in long["median"].items()
        ),
        fontsize="small",
    )
    axes.grid(alpha=0.3, which="both")
    axes.legend(fontsize="x-small")
    figure.savefig(path)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    for name, hint in TRAIN.items():
        parser.add_argument(
            f"--{name}", default="latest", help=f"{name}'s model: latest, a run or its model.pt ({hint})"
        )
    parser.add_argument("--dataset", default="synthetic")
    parser.add_argument("--lengths", type=int, nargs="+", default=[40, 80, 120, 160, 196], help="frames per sentence")
    parser.add_argument("--batches", type=int, nargs="+", default=[1, 32], help="sentences per call")
    parser.add_argument(
        "--m2d2m-steps",
        type=int,
        nargs="+",
        default=[100, 50, 25, 10],
        help="M2D2M's sampling steps, one series each (below T: jumps with exact posteriors)",
    )
    parser.add_argument(
        "--m2d2m-long-steps",
        type=int,
        default=None,
        help="M2D2M's steps on the long sequence (default: those its model file samples with)",
    )
    parser.add_argument(
        "--md-steps",
        type=int,
        nargs="+",
        default=[1000, 100],
        help="MotionDiffuse's sampling steps, one series each (below T: respaced)",
    )
    parser.add_argument(
        "--md-batches",
        type=int,
        nargs="+",
        default=[1],
        help="sentences per call at which MotionDiffuse is timed (1000 steps at 32: minutes a call)",
    )
    parser.add_argument(
        "--md-long-steps",
        type=int,
        default=50,
        help="MotionDiffuse's steps on the long sequence (the paper's 1000 would take about an hour)",
    )
    parser.add_argument("--warmup", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--long-minutes", type=float, default=MMM_MINUTES)
    parser.add_argument("--action-frames", type=int, default=196, help="the long sequence's longest action")
    parser.add_argument("--long-repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=os.cpu_count(), help="torch threads")
    parser.add_argument("--out", default=None, help="where aits.json and aits.png go (runs/<dataset>/bench/aits)")
    args = parser.parse_args(argv)
    if (
        min(
            args.batches
            + args.md_batches
            + args.md_steps
            + args.m2d2m_steps
            + [args.md_long_steps, args.m2d2m_long_steps or 1, args.repeats, args.long_repeats, args.threads]
        )
        < 1
        or args.warmup < 0
        or not args.long_minutes > 0
    ):
        parser.error(
            "batches, steps, repeats and threads must be at least 1, --warmup at least 0, --long-minutes positive"
        )
    # the paper's many steps first, each respacing after
    args.md_steps, args.m2d2m_steps = (sorted(set(steps), reverse=True) for steps in (args.md_steps, args.m2d2m_steps))

    torch.set_num_threads(args.threads)
    try:
        result = measure(args)
    except UserError as error:
        raise SystemExit(f"bench/aits.py: {error}") from None
    publish(Path(args.out or f"runs/{args.dataset}/bench/aits"), "aits", result, plot, report)


if __name__ == "__main__":
    main()
