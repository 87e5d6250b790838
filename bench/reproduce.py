"""Reproduce the M2D2M paper's ablations on the embedded default: `make reproduce`.

Trains longer than the demo, on the demo's corpus and data: the VQ-VAE, then two denoisers that
differ only in their transition (uniform β_t against dynamic β(t, d), paper §4.2 and Table 5).
It then evaluates both on one N = 4 test set with mirrors counted as motions of their own:

* Table 5: each transition × T_s = 100 (independent sampling) and T_s = 90 (TPS);
* Table 6: handshake, SLERP and TPS on the β(t, d) model (paper §5.3);
* Jerk and FID against T_s for both models, with their 95 % intervals.

Every stage goes through the `m2d2m` command line, so MLflow holds every training run and every
evaluation. The tables and the curve are written to ``runs/synthetic/reproduction/``
(``report.md``, ``ts-curve.png``); docs/reproduction.md holds the measured copy and discusses it.

    python bench/reproduce.py [--vq-steps 4000] [--diffusion-steps 4000] [--repeats 5] [--ts 0 50 90 100]

About 100 minutes on 2 CPU cores at the defaults (twice the demo's training); ``--quick`` runs every stage at toy sizes (minutes)
to check the pipeline, not to measure anything.

A stopped reproduction continues where it stopped: ``state.json`` beside the report records
each stage's start and what it produced, an interrupted training run is continued with
``--resume``, an interrupted evaluation with ``evaluate --resume``, and finished ones are not
run again. ``--restart`` starts over; another scale than the recorded one is refused.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from stages import DATASET, RUNS, Progress, run

from orchestration.reports import cell, plot_against_knob

TESTSET = Path("data") / DATASET / "testsets" / "n4-seed0-distinct"
OUT = RUNS / "reproduction"
TRANSITIONS = {"uniform": "β_t (uniform)", "dynamic": "β(t, d) (dynamic)"}
COLUMNS = (
    ("fid", "FID ↓"),
    ("transition_fid", "Transition FID ↓"),
    ("jerk", "Jerk →"),
    ("peak_jerk", "PJ →"),
    ("auj", "AUJ ↓"),
    ("r_top3", "R-Top3 ↑"),
)


@dataclass(frozen=True)
class Scale:
    vq_steps: int
    diffusion_steps: int
    repeats: int
    ts: tuple[int, ...]


def _plain(scale: Scale) -> dict[str, Any]:
    return {**asdict(scale), "ts": list(scale.ts)}


def schedule_overrides(steps: int) -> list[str]:
    """The demo's schedule stretched to ``steps``: warm-up as before, the decay at 80 %."""
    return [
        "--set",
        f"trainer.max_steps={steps}",
        "--set",
        f"optim.milestones=[{int(0.8 * steps)}]",
        "--set",
        f"trainer.val_every_steps={max(steps // 6, 1)}",
    ]


def train(scale: Scale, progress: Progress) -> dict[str, Path]:
    """The VQ-VAE, its tokens, the evaluator and one denoiser per transition kind."""

    def model_file(name: str) -> Callable[[Path], str]:
        return lambda run_dir: str(run_dir / name)

    vq = progress.stage(
        "vq",
        "vq",
        model_file("vq.pt"),
        "train-vq",
        "--config",
        "demo",
        *schedule_overrides(scale.vq_steps),
        resume=("train-vq", "--config", "demo", "--resume", "{run}"),
    )
    run("tokenize", "--vq", vq)
    progress.stage(
        "evaluator",
        "evaluator",
        model_file("evaluator.pt"),
        "train-evaluator",
        "--config",
        "demo",
        resume=("train-evaluator", "--config", "demo", "--resume", "{run}"),
    )
    models = {}
    for kind in TRANSITIONS:
        models[kind] = Path(
            progress.stage(
                f"denoiser/{kind}",
                "m2d2m",
                model_file("model.pt"),
                "train-diffusion",
                "--config",
                "paper-demo",
                "--set",
                f"vq={vq}",
                "--set",
                f"diffusion.kind={kind}",
                *schedule_overrides(scale.diffusion_steps),
                resume=("train-diffusion", "--config", "paper-demo", "--resume", "{run}"),
            )
        )
    return models


def evaluate(
    progress: Progress, key: str, model: Path, methods: Sequence[str], ts: int, repeats: int
) -> dict[str, Any]:
    """One `m2d2m evaluate` run (multi-motion table only), or the rest of an interrupted one;
    its table.json's multi-motion rows."""

    def table(run_dir: Path) -> dict[str, Any]:
        return json.loads((run_dir / "table.json").read_text(encoding="utf-8"))["multi"]

    return progress.stage(
        key,
        "eval",
        table,
        "evaluate",
        "--dataset",
        DATASET,
        "--checkpoint",
        str(model),
        "--testset",
        str(TESTSET),
        "--method",
        ",".join(methods),
        "--ts",
        str(ts),
        "--repeats",
        str(repeats),
        "--no-single",
        resume=("evaluate", "--dataset", DATASET, "--resume", "{run}"),
    )


def table(rows: list[tuple[str, dict[str, Any]]]) -> list[str]:
    lines = ["| | " + " | ".join(title for _, title in COLUMNS) + " |", "| --- " * (len(COLUMNS) + 1) + "|"]
    lines += [f"| {label} | " + " | ".join(cell(m.get(name)) for name, _ in COLUMNS) + " |" for label, m in rows]
    return lines


def report(results: dict[str, dict[int, dict[str, Any]]], baselines: dict[str, Any], scale: Scale) -> str:
    """The Markdown report: Tables 5 and 6, the T_s table behind the curve, the ground truth.
    Cells not measured yet read "–", so a report written midway is already readable."""

    def tps(kind: str, ts: int) -> dict[str, Any]:
        return results.get(kind, {}).get(ts, {}).get("tps", {})

    lines = [
        "# Reproduction on the embedded default",
        "",
        f"VQ-VAE {scale.vq_steps} steps, denoisers {scale.diffusion_steps} steps each; test set "
        f"{TESTSET} (N = 4); mean ± 95 % CI over {scale.repeats} repeats.",
        "",
        "## Table 5: transition × T_s",
        "",
    ]
    lines += table([(f"{TRANSITIONS[k]}, T_s = {ts}", tps(k, ts)) for k in TRANSITIONS for ts in (100, 90)])
    lines += ["", "## Table 6: multi-motion methods on the β(t, d) model", ""]
    lines += table(
        [
            ("handshake", baselines.get("handshake", {})),
            ("slerp", baselines.get("slerp", {})),
            ("TPS, T_s = 90", tps("dynamic", 90)),
        ]
    )
    # every evaluation measures the same reference rows; take them from any finished one
    measured = [baselines] + [r for runs in results.values() for r in runs.values()]
    reference = next((m for m in measured if "gt_single" in m), {})
    lines += ["", "## Ground truth and the codec's ceiling", ""]
    lines += table(
        [
            ("ground truth (single)", reference.get("gt_single", {})),
            ("ground truth (concat)", reference.get("gt_concat", {})),
            ("VQ-VAE reconstruction", reference.get("reconstruction", {})),
        ]
    )
    lines += ["", "## Jerk and FID against T_s (TPS; T_s = 100 is independent sampling)", ""]
    lines += table([(f"{TRANSITIONS[k]}, T_s = {ts}", tps(k, ts)) for k in TRANSITIONS for ts in scale.ts])
    lines += ["", "![Jerk and FID against T_s](ts-curve.png)", ""]
    return "\n".join(lines)


def plot(path: Path, results: dict[str, dict[int, dict[str, Any]]]) -> None:
    """Jerk and FID against T_s, one line per transition, with the 95 % intervals as bars."""
    series = {
        metric: {
            label: [(ts, r["tps"][metric]["mean"], r["tps"][metric]["ci"]) for ts, r in results.get(kind, {}).items()]
            for kind, label in TRANSITIONS.items()
        }
        for metric in ("jerk", "fid")
    }
    plot_against_knob(path, series, "T_s (joint phase for t > T_s)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--vq-steps", type=int, default=4000)
    parser.add_argument("--diffusion-steps", type=int, default=4000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--ts", type=int, nargs="+", default=[0, 50, 90, 100])
    parser.add_argument("--quick", action="store_true", help="toy sizes: checks the pipeline in minutes")
    parser.add_argument("--restart", action="store_true", help="start over instead of continuing a stopped run")
    args = parser.parse_args()
    scale = (
        Scale(60, 60, 2, (90, 100))
        if args.quick
        else Scale(args.vq_steps, args.diffusion_steps, args.repeats, tuple(sorted({*args.ts, 90, 100})))
    )

    progress = Progress(OUT / "state.json", _plain(scale), args.restart)
    run("synthesize", "--out", f"data/raw/{DATASET}", "--clips", "2000", "--seed", "0")
    run("data", "--dataset", DATASET, "--raw", f"data/raw/{DATASET}")
    models = train(scale, progress)
    run("testset", "--dataset", DATASET, "--n", "4", "--seed", "0", "--mirrors", "distinct")

    results: dict[str, dict[int, dict[str, Any]]] = {kind: {} for kind in models}
    baselines: dict[str, Any] = {}
    # Tables 5 and 6 first, then the rest of the curve; the report is rewritten after each.
    order = [(kind, ts) for ts in (100, 90) for kind in models] + [("baselines", 90)]
    order += [(kind, ts) for ts in scale.ts if ts not in (90, 100) for kind in models]
    for kind, ts in order:
        if kind == "baselines":
            baselines = evaluate(
                progress, "eval/baselines", models["dynamic"], ["handshake", "slerp"], ts, scale.repeats
            )
        else:
            results[kind][ts] = evaluate(progress, f"eval/{kind}/{ts}", models[kind], ["tps"], ts, scale.repeats)
        plot(OUT / "ts-curve.png", results)
        (OUT / "report.md").write_text(report(results, baselines, scale), encoding="utf-8")
    print(f"report: {OUT / 'report.md'}; every run is in MLflow (make ui)")


if __name__ == "__main__":
    main()
