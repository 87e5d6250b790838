"""Learning curves at equal compute, and the ablation that splits M2D2M's gap to MMM into causes.

**Curves.** Each model of ``--curves`` is trained once on the embedded default, from its demo
config (the paper-size configs' semantics at the demo's sizes), for the largest of ``--steps``,
with the weights kept after each of them (``trainer.snapshots``) and the learning rate cut at
75 % as the demo does. Every snapshot is judged on the single-motion protocol (paper Table 3:
FID, R-Top3, MM-Dist, MModality) of the same test set by the same evaluator. The token models read
the same VQ run's tokens. The figure plots FID and R-Top3 against training steps and against the
training's wall-clock seconds (``snapshots/seconds.json``, validation and previews included).

**Ablation** (``--ablation``). The paper's setting (``configs/m2d2m/paper-demo.yaml``) and one
change at a time, each trained for ``--ablation-steps`` with the demo's schedule and judged as
above; sampling-only changes reuse the paper model's run. MMM on the same tokens is the target
and the last row the shipped demo config (every change that measured better, docs/training.md), so
that each cause's share of the gap is a number.

    python bench/learning_curves.py [--curves m2d2m m2d2m-paper mmm motiondiffuse motiondiffuse-x0]
                                    [--steps 500 1000 2000 4000 8000]
                                    [--ablation] [--ablation-steps 2000] [--repeats 2] [--quick] [--restart]

Every training run and every evaluation goes through the `m2d2m` command line, so MLflow holds them
all (experiments ``synthetic/<model>`` and ``synthetic/eval``); the runs do not become ``latest``.
Writes ``report.md`` and ``curves.png`` into ``runs/synthetic/learning-curves/`` after each
evaluation, so a partial run is readable, and continues where it stopped when run again
(``state.json``; ``--restart`` starts over); calls with other ``--curves`` or with and without
``--ablation`` add to the same report as long as the steps and repeats stay. Needs the demo's data,
VQ-VAE, tokens and evaluator (`make demo`); `make learning-curves` runs it. docs/reproduction.md,
"M2D2M against MMM on the same tokens", holds a measured copy.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from stages import DATASET, RUNS, Progress, keeping_latest, run

from orchestration.registry import model
from orchestration.reports import GENERATED, GT_SINGLE, RECONSTRUCTION, cell
from orchestration.train import SNAPSHOTS

OUT = RUNS / "learning-curves"
TESTSET = Path("data") / DATASET / "testsets" / "n4-seed0"
COLUMNS = (("fid", "FID ↓"), ("r_top3", "R-Top3 ↑"), ("mm_dist", "MM-Dist ↓"), ("mmodality", "MModality ↑"))


@dataclass(frozen=True)
class Variant:
    """A model trained from one of its configs with overrides, sampled with options: a curve or a
    row of the ablation. ``trained_as`` names the variant whose run a sampling-only row samples;
    ``repeats`` caps the run's repeats for a model whose single-motion table costs ten times the others'."""

    key: str
    label: str
    model: str
    config: str = "demo"
    overrides: tuple[str, ...] = ()
    options: tuple[str, ...] = ()
    trained_as: str | None = None
    repeats: int | None = None


CURVES = {
    variant.key: variant
    for variant in (
        Variant("m2d2m", "M2D2M (demo.yaml, ours; its 25 sampling steps)", "m2d2m"),
        Variant("m2d2m-paper", "M2D2M (paper-demo.yaml)", "m2d2m", "paper-demo"),
        Variant("mmm", "MMM", "mmm"),
        Variant(
            "motiondiffuse",
            "MotionDiffuse (paper-demo.yaml, ε; 100 respaced steps, 1 repeat)",
            "motiondiffuse",
            "paper-demo",
            options=("steps=100",),
            repeats=1,
        ),
        Variant(
            "motiondiffuse-x0",
            "MotionDiffuse (demo.yaml, x0-prediction, ours; 100 respaced steps, 1 repeat)",
            "motiondiffuse",
            options=("steps=100",),
            repeats=1,
        ),
    )
}

PAPER = "paper"
ABLATION = (
    Variant(PAPER, "the paper's setting (paper-demo.yaml)", "m2d2m", "paper-demo"),
    Variant("mmm", "MMM (demo.yaml) on the same tokens: the target", "mmm"),
    Variant("truncation", "+ truncation r = 0.86 at sampling", "m2d2m", options=("truncation=0.86",), trained_as=PAPER),
    Variant(
        "guidance-3",
        "guidance s = 3 at sampling (VQ-Diffusion's scale 4)",
        "m2d2m",
        options=("guidance=3",),
        trained_as=PAPER,
    ),
    Variant(
        "action-offsets",
        "+ offsets within the action (positions: action)",
        "m2d2m",
        "paper-demo",
        ("denoiser.positions=action",),
    ),
    Variant("aux-1", "+ auxiliary weight λ = 1 (paper 5e-4)", "m2d2m", "paper-demo", ("diffusion.aux_weight=1.0",)),
    Variant(
        "importance", "+ importance sampling of t", "m2d2m", "paper-demo", ("diffusion.timestep_sampling=importance",)
    ),
    Variant("adaptive-aux", "+ adaptive auxiliary weight", "m2d2m", "paper-demo", ("diffusion.adaptive_aux=true",)),
    Variant(
        "absorbing",
        "+ absorbing schedule (VQ-Diffusion's endpoints)",
        "m2d2m",
        "paper-demo",
        ("diffusion.schedule=absorbing",),
    ),
    Variant("ema", "+ EMA of the weights (decay 0.995 a step)", "m2d2m", "paper-demo", ("trainer.ema=0.995",)),
    Variant(
        "codebook",
        "+ codes embedded by their frozen codebook vectors (embedding: codebook)",
        "m2d2m",
        "paper-demo",
        ("denoiser.embedding=codebook",),
    ),
    # every row samples with all 100 steps, the paper's sampler; demo.yaml's own default is fewer
    Variant("ours", "demo.yaml (ours: every change that measured better)", "m2d2m", options=("steps=100",)),
    # the same settings from another training seed: how far a row moves by chance alone
    Variant(
        "paper-seed", "the paper's setting, training seed 124 (chance alone)", "m2d2m", "paper-demo", ("seed=124",)
    ),
    Variant(
        "ours-seed",
        "demo.yaml, training seed 124 (chance alone)",
        "m2d2m",
        overrides=("seed=124",),
        options=("steps=100",),
    ),
)


def schedule_overrides(steps: int, snapshots: list[int] | None = None) -> list[str]:
    """The demo's schedule stretched to ``steps`` (decay at 75 %), with snapshots when given."""
    settings = [
        f"trainer.max_steps={steps}",
        f"optim.milestones=[{int(0.75 * steps)}]",
        f"trainer.val_every_steps={min(500, steps)}",
    ]
    if snapshots:
        settings.append(f"trainer.snapshots=[{','.join(map(str, snapshots))}]")
    return [arg for setting in settings for arg in ("--set", setting)]


def train(progress: Progress, key: str, variant: Variant, steps: int, snapshots: list[int] | None = None) -> Path:
    """The variant's training run (trained, continued or found finished) as a directory."""
    entry = model(variant.model)
    sets = [arg for override in variant.overrides for arg in ("--set", override)]
    with keeping_latest(entry.stage):
        return Path(
            progress.stage(
                key,
                entry.stage,
                str,
                entry.train_verb,
                "--config",
                variant.config,
                *sets,
                *schedule_overrides(steps, snapshots),
                resume=(entry.train_verb, "--config", variant.config, "--resume", "{run}"),
            )
        )


def judge(progress: Progress, key: str, variant: Variant, model_file: Path, repeats: int) -> dict[str, Any]:
    """The single-motion table of one model file: the generated row, the ground truth and (token
    models) the codec's ceiling, as ``{row: {metric: {mean, ci}}}``."""

    def rows(run_dir: Path) -> dict[str, Any]:
        single = json.loads((run_dir / "table.json").read_text(encoding="utf-8"))["single"]
        return {row: values for row, values in single.items() if row in (GENERATED, GT_SINGLE, RECONSTRUCTION)}

    options = [arg for option in variant.options for arg in ("--option", option)]
    repeats = min(repeats, variant.repeats or repeats)
    with keeping_latest("eval"):
        return progress.stage(
            key,
            "eval",
            rows,
            "evaluate",
            "--dataset",
            DATASET,
            "--model",
            variant.model,
            "--checkpoint",
            str(model_file),
            "--testset",
            str(TESTSET),
            "--no-multi",
            "--single",
            "--repeats",
            str(repeats),
            *options,
            resume=("evaluate", "--dataset", DATASET, "--resume", "{run}"),
        )


def curve(
    progress: Progress,
    variant: Variant,
    steps: list[int],
    repeats: int,
    on_point: Callable[[str, dict[str, Any]], None],
) -> None:
    """Train the variant to the last of ``steps`` with snapshots, then judge each snapshot."""
    from training.callbacks import StepSnapshots  # Lightning: imported when a curve is measured, not at start-up

    run_dir = train(progress, f"curve/{variant.key}/train", variant, max(steps), steps)
    seconds = StepSnapshots.recorded(run_dir / SNAPSHOTS)
    for step in steps:
        table = judge(
            progress, f"curve/{variant.key}/{step}", variant, run_dir / SNAPSHOTS / f"model-step{step}.pt", repeats
        )
        on_point(variant.key, {"step": step, "seconds": seconds[str(step)], "table": table})


def ablation(progress: Progress, steps: int, repeats: int, on_row: Callable[[str, dict[str, Any]], None]) -> None:
    """Every row of :data:`ABLATION` at ``steps`` training steps."""
    runs: dict[str, Path] = {}
    for variant in ABLATION:
        source = variant.trained_as or variant.key
        if source not in runs:
            trained = next(v for v in ABLATION if v.key == source)
            runs[source] = train(progress, f"ablation/{source}/train", trained, steps)
        table = judge(
            progress, f"ablation/{variant.key}", variant, runs[source] / model(variant.model).model_file, repeats
        )
        on_row(variant.key, table)


# ------------------------------------------------------------------------------------- report
def _metric(table: dict[str, Any], metric: str, row: str = GENERATED) -> float | None:
    return (table.get(row, {}).get(metric) or {}).get("mean")


def report(results: dict[str, Any], settings: dict[str, Any]) -> str:
    """The Markdown report: each curve's points, then the ablation with each row's change of FID
    and R-Top3 against the paper's setting. Cells not measured yet read "–"."""
    lines = [
        "# Learning curves and ablation on the embedded default",
        "",
        f"Single-motion protocol on {TESTSET} ({settings['repeats']} repeats; mean ± 95 % CI).",
        "",
    ]
    for key, points in results.get("curves", {}).items():
        lines += [
            f"## {CURVES[key].label}",
            "",
            "| steps | seconds | " + " | ".join(t for _, t in COLUMNS) + " |",
            "| --- " * (len(COLUMNS) + 2) + "|",
        ]
        for point in sorted(points, key=lambda p: p["step"]):
            generated = point["table"].get(GENERATED, {})
            lines.append(
                f"| {point['step']} | {point['seconds']:.0f} | "
                + " | ".join(cell(generated.get(name)) for name, _ in COLUMNS)
                + " |"
            )
        lines.append("")
    rows = results.get("ablation", {})
    if rows:
        paper = rows.get(PAPER, {})
        lines += [
            f"## Ablation at {settings['ablation_steps']} steps",
            "",
            "| change | " + " | ".join(t for _, t in COLUMNS) + " | Δ FID | Δ R-Top3 |",
            "| --- " * (len(COLUMNS) + 3) + "|",
        ]
        for variant in ABLATION:
            table = rows.get(variant.key)
            if table is None:
                continue
            generated = table.get(GENERATED, {})
            deltas = [
                None
                if _metric(table, m) is None or _metric(paper, m) is None
                else _metric(table, m) - _metric(paper, m)
                for m in ("fid", "r_top3")
            ]
            lines.append(
                f"| {variant.label} | "
                + " | ".join(cell(generated.get(name)) for name, _ in COLUMNS)
                + " | "
                + " | ".join("–" if d is None else f"{d:+.3f}" for d in deltas)
                + " |"
            )
        reference = next(iter(rows.values()))
        for row, title in (
            (RECONSTRUCTION, "VQ-VAE reconstruction (the token models' ceiling)"),
            (GT_SINGLE, "ground truth"),
        ):
            if row in reference:
                lines.append(
                    f"| {title} | " + " | ".join(cell(reference[row].get(name)) for name, _ in COLUMNS) + " | | |"
                )
        lines += [
            "",
            "± is over the sampling repeats of one trained model; how far a row moves by chance in "
            "training is what the seed-124 rows show against their seed-123 twins.",
            "",
        ]
    lines += ["![FID and R-Top3 against training steps and seconds](curves.png)", ""]
    return "\n".join(lines)


def plot(path: Path, results: dict[str, Any]) -> None:
    """FID (log scale) and R-Top3 against steps and against seconds, one line per curve, with the
    codec's ceiling and the ground truth's R-Top3 dashed."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import NullFormatter

    figure = Figure(figsize=(10, 8), dpi=110, layout="constrained")
    axes = figure.subplots(2, 2)
    references: dict[tuple[str, str], float] = {}
    for key, points in results.get("curves", {}).items():
        points = sorted(points, key=lambda p: p["step"])
        for column, x_name in enumerate(("step", "seconds")):
            for row, metric in enumerate(("fid", "r_top3")):
                values = [(p[x_name], _metric(p["table"], metric)) for p in points]
                values = [(x, y) for x, y in values if y is not None]
                if values:
                    axes[row, column].plot(*zip(*values), marker="o", label=CURVES[key].label)
        for point in points:
            for row_name in (RECONSTRUCTION, GT_SINGLE):
                for metric in ("fid", "r_top3"):
                    value = _metric(point["table"], metric, row_name)
                    if value is not None and not (row_name == GT_SINGLE and metric == "fid"):
                        references[row_name, metric] = value
    labels = {RECONSTRUCTION: "VQ-VAE reconstruction", GT_SINGLE: "ground truth"}
    steps = sorted({p["step"] for points in results.get("curves", {}).values() for p in points})
    for row, (metric, title) in enumerate((("fid", "FID ↓ (log)"), ("r_top3", "R-Top3 ↑"))):
        for column, x_label in enumerate(("training steps", "training wall-clock seconds")):
            ax = axes[row, column]
            for (row_name, which), value in references.items():
                if which == metric:
                    ax.axhline(
                        value,
                        linestyle="--",
                        linewidth=1,
                        color="grey" if row_name == GT_SINGLE else "black",
                        label=labels[row_name],
                    )
            ax.set(xlabel=x_label, title=title, xscale="log")
            if column == 0 and steps:  # the measured steps as plain numbers, no log-scale minor labels
                ax.set_xticks(steps, [str(step) for step in steps])
                ax.xaxis.set_minor_formatter(NullFormatter())
            if metric == "fid":
                ax.set_yscale("log")
            ax.grid(alpha=0.3, which="both")
    handles, names = axes[1, 0].get_legend_handles_labels()
    if handles:  # one legend below the panels, where it covers no curve
        figure.legend(handles, names, loc="outside lower center", ncols=2, fontsize="small")
    figure.savefig(path)


def track(results: dict[str, Any], settings: dict[str, Any]) -> str:
    """One MLflow run (experiment ``<dataset>/bench``) holding the curves as metrics indexed by
    training step (``curve/<model>/<metric>``, which the MLflow UI plots as curves), the ablation's
    rows (``ablation/<row>/<metric>``), the report and the figure; returns its id."""
    from mlflow.entities import Metric

    from orchestration.tracking import experiment_name, log_batch, tracked_run

    metrics = [
        Metric(f"curve/{key}/{name}", value, 0, point["step"])
        for key, points in results.get("curves", {}).items()
        for point in points
        for name, _ in COLUMNS
        if (value := _metric(point["table"], name)) is not None
    ]
    metrics += [
        Metric(f"curve/{key}/seconds", point["seconds"], 0, point["step"])
        for key, points in results.get("curves", {}).items()
        for point in points
    ]
    rows = {
        f"ablation/{key}/{name}": value
        for key, table in results.get("ablation", {}).items()
        for name, _ in COLUMNS
        if (value := _metric(table, name)) is not None
    }
    tags = {"dataset": DATASET, "stage": "bench"}
    with tracked_run(experiment_name(DATASET, "bench"), "learning-curves", tags, settings) as (client, run_id):
        client.log_batch(run_id, metrics=metrics)
        log_batch(client, run_id, metrics=rows)
        for name in ("report.md", "curves.png"):
            client.log_artifact(run_id, str(OUT / name))
    return run_id


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--curves",
        nargs="*",
        default=["m2d2m", "m2d2m-paper", "mmm", "motiondiffuse", "motiondiffuse-x0"],
        choices=list(CURVES),
        help="the models whose learning curves to measure",
    )
    parser.add_argument("--steps", type=int, nargs="+", default=[500, 1000, 2000, 4000, 8000])
    parser.add_argument("--ablation", action="store_true", help="also the ablation table (about 10 minutes a row)")
    parser.add_argument("--ablation-steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--quick", action="store_true", help="toy sizes: checks the pipeline in minutes")
    parser.add_argument("--restart", action="store_true", help="start over instead of continuing a stopped run")
    args = parser.parse_args()
    steps = [20, 40] if args.quick else sorted(set(args.steps))
    # what the recorded results depend on; which curves and whether the ablation run is each call's choice
    settings = {
        "steps": steps,
        "ablation_steps": 40 if args.quick else args.ablation_steps,
        "repeats": 1 if args.quick else args.repeats,
    }
    progress = Progress(OUT / "state.json", settings, args.restart)
    results: dict[str, Any] = progress.state.setdefault("results", {"curves": {}, "ablation": {}})

    def publish() -> None:
        progress.record("results", results)
        plot(OUT / "curves.png", results)
        (OUT / "report.md").write_text(report(results, settings), encoding="utf-8")

    def on_point(key: str, point: dict[str, Any]) -> None:
        points = [p for p in results["curves"].setdefault(key, []) if p["step"] != point["step"]]
        results["curves"][key] = [*points, point]
        publish()

    def on_row(key: str, table: dict[str, Any]) -> None:
        results["ablation"][key] = table
        publish()

    run("testset", "--dataset", DATASET, "--n", "4", "--seed", "0")
    if args.ablation:
        ablation(progress, settings["ablation_steps"], settings["repeats"], on_row)
    for key in args.curves:
        curve(progress, CURVES[key], steps, settings["repeats"], on_point)
    publish()
    run_id = track(results, settings)
    print(f"report: {OUT / 'report.md'}; every run is in MLflow (make ui), the curves in run {run_id}")


if __name__ == "__main__":
    main()
