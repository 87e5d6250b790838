"""Where Two-Phase Sampling differs from independent sampling, and what that does to each
boundary (issue: an honest reproduction report, §5).

The sampler draws one uniform per token position from each request's own seeded stream, whatever
the rows of the batch look like, so TPS with T_s = T *is* independent sampling draw for draw.
At equal seeds, TPS at a smaller T_s therefore differs from independent sampling only through
its joint phase (t = T … T_s + 1): every difference below is that phase's effect, and every
comparison is paired (the same instance, the same seed, the same uniforms).

For the test set's instances, ``--seeds`` seeds each, and every T_s given, this measures:

* how many tokens differ from independent sampling, by distance (in tokens) from the nearest
  boundary: a joint phase that acts on transitions changes the tokens next to a boundary more
  than those in the middle of an action. The reference is two independent samplings with
  different seeds: how far apart two draws of the model are at all;
* how much of the sequence the joint phase decides: the share of positions not masked at
  t = T_s, 1 − γ̄_{T_s} (what survives into the independent phase; ᾱ_{T_s} of it is data);
* the paper's Jerk (eq. 10, fps 1, 40 frames) of each boundary, TPS minus independent, paired,
  with its 95 % interval (Student's t over the pairs, as `m2d2m evaluate`'s), and the same for the middle of each action as a control: an effect
  that is there too is not a transition effect;
* the power of `m2d2m evaluate`: its Jerk is a mean over the test set's sequences, which stay
  the same from repeat to repeat, so only the seed-to-seed spread of a sequence's Jerk (σ, from
  the seeds here) moves it, and R repeats of n instances give a 95 % half-width of about
  1.96·σ/√(R·n): the normal quantile, to size R (the sequences are many; the interval the
  evaluation prints is Student's t over its R repeats, wider when R is small).

    python bench/tps_boundaries.py [--checkpoint latest] [--testset data/synthetic/testsets/n4-seed0-distinct]
                                   [--ts 0 50 90] [--seeds 2] [--out runs/synthetic/reproduction/boundaries]

It writes ``boundaries.md`` and ``boundaries.png`` in ``--out`` and prints the table.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m2d2m.evaluation.measurements import JERK_FPS, WINDOW
from m2d2m.evaluation.metrics import CI95_Z, jerk, mean_confidence_interval
from m2d2m.generators.options import MULTI
from m2d2m.motion.clip import Motion
from orchestration.generate import load_generator
from pipelines.testset import load_testset

NEAREST = 12  # token distances from a boundary reported one by one; farther ones are pooled
POWER_TARGET = 0.03  # the Jerk half-width the evaluation is sized for (docs/evaluation.md, Power)


@dataclass
class Paired:
    """Per-sequence results of one sampling, seed-major: every instance under the first seed, then
    every instance under the next."""

    tokens: list[np.ndarray]  # each sequence's tokens
    token_boundaries: list[list[int]]  # each sequence's first token of actions 2..N
    boundary_jerk: np.ndarray  # (sequences, N − 1): Jerk of each boundary's window
    middle_jerk: np.ndarray  # (sequences, N): Jerk of a window in the middle of each action


def measure(motions: list[Motion], frames_per_token: int) -> Paired:
    boundary, middle, tokens, cuts = [], [], [], []
    for motion in motions:
        boundary.append([jerk(motion.joints, JERK_FPS, [b], WINDOW) for b in motion.boundaries])
        middle.append([jerk(motion.joints, JERK_FPS, [(first + end) // 2], WINDOW) for first, end in motion.ranges])
        tokens.append(np.asarray(motion.tokens))
        cuts.append([first // frames_per_token for first, _ in motion.ranges[1:]])
    return Paired(tokens, cuts, np.asarray(boundary), np.asarray(middle))


def distance_to_boundary(length: int, boundaries: list[int]) -> np.ndarray:
    """Each token's distance to the nearest boundary: 0 for the tokens on either side of one."""
    position = np.arange(length)[:, None]
    cuts = np.asarray(boundaries)[None, :]
    return np.minimum(np.abs(position - cuts), np.abs(position - (cuts - 1))).min(axis=1)


def changed_by_distance(tps: Paired, independent: Paired) -> np.ndarray:
    """Share of tokens that differ from independent sampling at distance 0 … NEAREST − 1 from
    the nearest boundary, and (last entry) farther."""
    changed, counted = np.zeros(NEAREST + 1), np.zeros(NEAREST + 1)
    for a, b, cuts in zip(tps.tokens, independent.tokens, tps.token_boundaries):
        bins = np.minimum(distance_to_boundary(len(a), cuts), NEAREST)
        np.add.at(changed, bins, a != b)
        np.add.at(counted, bins, 1)
    return changed / np.maximum(counted, 1)


def paired_difference(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Mean of a − b and its 95 % half-width (Student's t) over the defined pairs; NaN with one."""
    difference = (a - b).ravel()
    mean, half_width = mean_confidence_interval(difference[np.isfinite(difference)])
    return float(mean), float(half_width)


def seed_spread(paired: Paired, seeds: int) -> float:
    """σ of a sequence's Jerk (as `m2d2m evaluate` averages it: over its boundaries) from one
    seed to another, pooled over the instances (sequences are in seed-major order)."""
    per_sequence = np.nanmean(paired.boundary_jerk, axis=1).reshape(seeds, -1)
    return float(np.sqrt(np.nanmean(per_sequence.var(axis=0, ddof=1))))


def repeats_for(sigma: float, instances: int, half_width: float = POWER_TARGET) -> int:
    """Repeats of ``instances`` sequences that bring 1.96·σ/√(R·n) to ``half_width``: sizing by
    the normal quantile, which R·n sequences (many) allow."""
    return max(1, math.ceil((CI95_Z * sigma / half_width) ** 2 / instances))


def another_seed(independent: Paired, instances: int) -> np.ndarray:
    """:func:`changed_by_distance` between each seed's sequences and the next seed's of the same
    instances (seed-major order): the share of tokens two draws of the model differ in anyway."""

    def part(chosen: slice) -> Paired:
        return Paired(
            independent.tokens[chosen],
            independent.token_boundaries[chosen],
            independent.boundary_jerk[chosen],
            independent.middle_jerk[chosen],
        )

    return changed_by_distance(part(slice(instances, None)), part(slice(None, -instances)))


def sample(generator, actions, frames, ts: int, seeds: list[int]) -> Paired:
    options = generator.options(MULTI, method="tps", ts=ts)
    motions: list[Motion] = []
    for start in range(0, len(actions), 64):
        chunk = slice(start, start + 64)
        motions += generator.generate(actions[chunk], frames[chunk], options, seeds[chunk])
    return measure(motions, generator.frame_step)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoint", default="latest")
    parser.add_argument("--dataset", default="synthetic")
    parser.add_argument("--testset", default="data/synthetic/testsets/n4-seed0-distinct")
    parser.add_argument("--ts", type=int, nargs="+", default=[0, 50, 90])
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--out", default="runs/synthetic/reproduction/boundaries")
    args = parser.parse_args(argv)

    generator = load_generator("m2d2m", args.checkpoint, args.dataset)
    schedule = generator.checkpoint.schedule
    testset = load_testset(args.testset)
    instances = list(testset) * args.seeds
    actions = [list(instance.actions) for instance in instances]
    frames = [[generator.round_frames(item.length) for item in instance.items] for instance in instances]
    seeds = [1000 * (i // len(testset)) + instance.index for i, instance in enumerate(instances)]

    independent = sample(generator, actions, frames, schedule.steps, seeds)
    spreads = {f"independent (T_s = {schedule.steps})": seed_spread(independent, args.seeds)}
    curves = {"independent, another seed": another_seed(independent, len(testset))} if args.seeds > 1 else {}
    rows = []
    for ts in sorted(args.ts):
        tps = sample(generator, actions, frames, ts, seeds)
        spreads[f"TPS, T_s = {ts}"] = seed_spread(tps, args.seeds)
        changed = curves[f"T_s = {ts}"] = changed_by_distance(tps, independent)
        boundary = paired_difference(tps.boundary_jerk, independent.boundary_jerk)
        middle = paired_difference(tps.middle_jerk, independent.middle_jerk)
        per_boundary = [
            paired_difference(tps.boundary_jerk[:, k], independent.boundary_jerk[:, k])
            for k in range(tps.boundary_jerk.shape[1])
        ]
        rows.append(
            (
                ts,
                1 - float(schedule.gamma_bar[ts]),
                float(schedule.alpha_bar[ts]),
                changed,
                boundary,
                middle,
                per_boundary,
            )
        )

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    text = report(
        rows,
        spreads,
        curves.get("independent, another seed"),
        len(testset),
        args.seeds,
        float(np.nanmean(independent.boundary_jerk)),
        float(np.nanmean(independent.middle_jerk)),
        schedule.steps,
        args,
    )
    (out / "boundaries.md").write_text(text, encoding="utf-8")
    plot(out / "boundaries.png", curves)
    print(text)


def report(
    rows,
    spreads: dict[str, float],
    reference: np.ndarray | None,
    instances: int,
    seeds: int,
    independent_boundary: float,
    independent_middle: float,
    steps: int,
    args: argparse.Namespace,
) -> str:
    pm = "{:+.3f} ± {:.3f}".format
    lines = [
        f"# TPS against independent sampling, paired ({args.checkpoint}, {args.testset})",
        "",
        f"{instances} instances × {seeds} seeds; T = {steps}. Independent sampling (T_s = T): Jerk "
        f"{independent_boundary:.3f} at the boundaries, {independent_middle:.3f} in the middles of the actions.",
        "",
        "| T_s | decided at T_s (1 − γ̄) | data at T_s (ᾱ) | tokens changed: next to a boundary | "
        f"3 tokens away | ≥ {NEAREST} away | Δ Jerk, boundaries | Δ Jerk, middles (control) | "
        "Δ Jerk per boundary (1st, 2nd, …) |",
        "| --- " * 9 + "|",
    ]
    for ts, decided, data, changed, boundary, middle, per_boundary in rows:
        lines.append(
            f"| {ts} | {decided:.3f} | {data:.3f} | {changed[0]:.3f} | {changed[3]:.3f} | "
            f"{changed[NEAREST]:.3f} | {pm(*boundary)} | {pm(*middle)} | "
            + ", ".join(pm(*b) for b in per_boundary)
            + " |"
        )
    if reference is not None:
        lines.append(
            f"| independent, another seed | | | {reference[0]:.3f} | {reference[3]:.3f} | "
            f"{reference[NEAREST]:.3f} | | | |"
        )
    lines += [
        "",
        "Δ = TPS minus independent sampling on the same instance and seed; ± is the 95 % half-width "
        "(Student's t) over the pairs. Tokens changed: the share that differs from independent sampling at the same "
        "seed (last row: between two seeds of independent sampling).",
        "",
        "![tokens changed by distance from the boundary](boundaries.png)",
        "",
        f"Power: σ is a sequence's Jerk's seed-to-seed standard deviation; R is the number of repeats "
        f"of these {instances} instances that gives `m2d2m evaluate` a Jerk half-width of {POWER_TARGET}.",
        "",
        "| sampling | σ | R |",
        "| --- | --- | --- |",
    ]
    lines += [f"| {name} | {sigma:.3f} | {repeats_for(sigma, instances)} |" for name, sigma in spreads.items()]
    lines += [""]
    return "\n".join(lines)


def plot(path: Path, curves: dict[str, np.ndarray]) -> None:
    from matplotlib.figure import Figure

    figure = Figure(figsize=(6, 3.6), dpi=110, layout="constrained")
    axes = figure.subplots()
    for label, changed in curves.items():
        style = {"color": "black", "linestyle": "--"} if label.startswith("independent") else {}
        axes.plot(np.arange(NEAREST + 1), changed, marker="o", label=label, **style)
    axes.set(
        xlabel=f"tokens from the nearest boundary (last point: {NEAREST} or more)",
        ylabel="share of tokens ≠ independent",
        title="Where the joint phase changes tokens",
        ylim=(0, 1),
    )
    axes.grid(alpha=0.3)
    axes.legend(fontsize="small")
    figure.savefig(path)


if __name__ == "__main__":
    main()
