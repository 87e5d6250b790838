"""The evaluation's reports: table.md and table.json (the paper's multi-motion Tables 1–2 and
single-motion Table 3, mean ± 95 % CI over repeats), Fig. 5 as a PNG, and the tables' numbers
under MLflow metric names."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from m2d2m.evaluation.measurements import R_PRECISION_BATCH, WINDOW, Reference
from m2d2m.evaluation.metrics import mean_confidence_interval
from m2d2m.evaluation.sequence_metrics import sequence_metrics

TABLE_MD, TABLE_JSON, FIGURE = "table.md", "table.json", "fig5.png"
GT_SINGLE, GT_CONCAT, RECONSTRUCTION, GENERATED = "gt_single", "gt_concat", "reconstruction", "generated"

# (metric, column title) of each table, in the paper's order
MULTI_COLUMNS = (
    ("r_top3", "R-Top3 ↑"),
    ("fid", "FID ↓"),
    ("mm_dist", "MMdist ↓"),
    ("diversity", "Div →"),
    ("transition_fid", "Transition FID ↓"),
    ("transition_diversity", "Transition Div →"),
    ("jerk", "Jerk →"),
    ("peak_jerk", "PJ →"),
    ("auj", "AUJ ↓"),
    ("bone_std", "Bone σ (mm) ↓"),
)
SINGLE_COLUMNS = (
    ("r_top1", "R-Top1 ↑"),
    ("r_top2", "R-Top2 ↑"),
    ("r_top3", "R-Top3 ↑"),
    ("fid", "FID ↓"),
    ("mm_dist", "MM-Dist ↓"),
    ("diversity", "Diversity →"),
    ("mmodality", "MModality ↑"),
)
EDIT_COLUMNS = (
    ("r_top1", "R-Top1 ↑"),
    ("r_top3", "R-Top3 ↑"),
    ("fid", "FID ↓"),
    ("mm_dist", "MM-Dist ↓"),
    ("diversity", "Diversity →"),
)  # MMM Table 3's, and R-Top3 as every table here has
REGENERATE_COLUMNS = (
    ("r_top3", "R-Top3 ↑"),
    ("fid", "FID ↓"),
    ("transition_fid", "Transition FID ↓"),
    ("jerk", "Jerk →"),
)  # the timeline-editing table's: the regenerated action, and the transitions at its joins
EDIT_TITLES = {"inbetween": "In-betweening", "upper": "Upper-body editing"}
# the suffix of a multi-motion row's feet rows (m2d2m.evaluation.measurements.FEET_VARIANTS)
FEET_TITLES = {"planted": ", feet planted"}
ROW_TITLES = {
    GT_SINGLE: "Ground truth (single)",
    GT_CONCAT: "Ground truth (concat)",
    RECONSTRUCTION: "VQ-VAE reconstruction",
    GENERATED: "Generated (single action)",
}


def multi_columns(table: dict[str, Any]) -> tuple[tuple[str, str], ...]:
    """The multi-motion table's columns: the paper's, then each registered sequence metric the
    table holds (:mod:`m2d2m.evaluation.sequence_metrics`)."""
    held = {metric for values in table["multi"].values() for metric in values}
    return MULTI_COLUMNS + tuple((m.name, m.title) for m in sequence_metrics() if m.name in held)


def _summary(values: Sequence[float]) -> dict[str, float | None]:
    """Mean and 95 % CI half-width over the repeats; None where a repeat had no defined value.
    One repeat has a mean but no interval (its spread says nothing): its ``ci`` is None."""
    values = np.asarray(values, dtype=np.float64)
    if not np.isfinite(values).all():
        return {"mean": None, "ci": None}
    mean, ci = mean_confidence_interval(values)
    return {"mean": mean, "ci": ci if len(values) > 1 else None}


def summarize_rows(per_repeat: dict[str, list[dict[str, float]]]) -> dict[str, dict[str, dict[str, float | None]]]:
    """Row → metric → mean and CI, from each row's per-repeat metric dicts (a repeat written
    before a metric existed, continued by ``--resume``, leaves that metric undefined)."""
    return {
        row: {metric: _summary([r.get(metric, np.nan) for r in repeats]) for metric in repeats[0]}
        for row, repeats in per_repeat.items()
    }


def cell(summary: dict[str, float | None] | None) -> str:
    """``mean ± ci`` to three decimals, ``mean (n = 1)`` from one repeat, or "–" for a value not
    measured (yet)."""
    if summary is None or summary["mean"] is None:
        return "–"
    if summary["ci"] is None:
        return f"{summary['mean']:.3f} (n = 1)"
    return f"{summary['mean']:.3f} ± {summary['ci']:.3f}"


def _markdown(
    title: str, columns: tuple[tuple[str, str], ...], rows: dict[str, dict[str, Any]], titles: dict[str, str]
) -> list[str]:
    lines = [
        f"## {title}",
        "",
        "| Method | " + " | ".join(name for _, name in columns) + " |",
        "| --- |" + " --- |" * len(columns),
    ]
    for row, values in rows.items():
        name = titles.get(row, ROW_TITLES.get(row, row))
        lines.append(f"| {name} | " + " | ".join(cell(values.get(m)) for m, _ in columns) + " |")
    return lines + [""]


def render_table(table: dict[str, Any]) -> str:
    """table.md: the paper's tables, then the conventions a reader needs to compare them."""
    settings, testset, titles = table["settings"], table["testset"], table.get("titles", {})
    judged = ", ".join(c["checkpoint"] for c in settings["candidates"])
    lines = [
        f"# Evaluation of {judged}",
        "",
        f"Test set {testset['path']}: {testset['instances']} instances of N = {testset['n']} actions. "
        + (
            f"Mean ± 95 % CI over {settings['repeats']} repeats."
            if settings["repeats"] > 1
            else "One repeat: means without an interval (`--repeats 2` or more gives 95 % CIs)."
        ),
        "",
    ]
    lines += _markdown("Multi-motion (paper Tables 1–2)", multi_columns(table), table["multi"], titles)
    if "single" in table:
        lines += _markdown("Single-motion (paper Table 3)", SINGLE_COLUMNS, table["single"], titles)
    if "editing" in table:
        lines += _markdown("Editing (MMM Table 3)", EDIT_COLUMNS, table["editing"], titles)
    if "regenerate" in table:
        title = f"Editing on the timeline: action {settings['regenerate']} of {testset['n']} sampled again"
        lines += _markdown(title, REGENERATE_COLUMNS, table["regenerate"], titles)
    lines += [f"- {note}" for note in table["notes"]]
    return "\n".join(lines) + "\n"


def notes(sampling: str, single_sampling: str | None, reference: Reference) -> list[str]:
    """The conventions a reader needs: the sampling settings as the generator describes them
    (``single_sampling`` when the single-motion table was made), the windows, the Jerk's units."""
    lines = [
        f"sampling: {sampling}" + (f"; single-motion: {single_sampling}" if single_sampling else ""),
        f"transition: the {WINDOW} frames around each boundary; ground truth (single) = the middle "
        f"{WINDOW} frames of every ground-truth item",
        "Jerk: paper eq. 10 averaged over joints and boundaries, time measured in frames (fps = 1)",
        "PJ, AUJ: FlowMDM's (Barquero et al., CVPR 2024; not the paper's Jerk): per frame, the L1 norm of "
        "each joint's third difference, max over joints, averaged over the full transition windows; PJ its "
        f"peak, AUJ Σ |curve − c| with c = {reference.frame_jerk_mean:.6f} m/frame³, this test set's ground-truth mean (FlowMDM's "
        "for HumanML3D: 0.033031363)",
        "Bone σ: each bone's standard deviation of length over a sequence's decoded joints, mean over "
        "bones and sequences, in mm (0 = one rigid skeleton; `m2d2m generate` puts its files on one)",
    ]
    if reference.rp_batch < R_PRECISION_BATCH:
        lines.append(
            f"R-precision over groups of {reference.rp_batch}, not {R_PRECISION_BATCH}: the test set has only "
            f"{reference.items} items (not comparable with published R-Top numbers)"
        )
    return lines


def plot_fig5(path: Path, curves: dict[str, dict[str, Any]]) -> Path:
    """The paper's Fig. 5: mean joint speed and peak-normalised jerk per frame around the
    transitions, one curve per label."""
    from matplotlib.figure import Figure

    figure = Figure(figsize=(10, 4), layout="constrained")
    speed_axes, jerk_axes = figure.subplots(1, 2)
    for label, profile in curves.items():
        if profile["velocity"] is None:
            continue
        style = {"color": "black", "linestyle": "--"} if label == ROW_TITLES[GT_CONCAT] else {}
        velocity, jerk_curve = np.asarray(profile["velocity"]), np.asarray(profile["jerk"])
        speed_axes.plot(np.arange(len(velocity)) - WINDOW // 2 + 0.5, velocity, label=label, **style)
        jerk_axes.plot(np.arange(len(jerk_curve)) - WINDOW // 2 + 1.5, jerk_curve, label=label, **style)
    for axes, title, unit in (
        (speed_axes, "(a) Velocity", "mean joint speed (m/frame)"),
        (jerk_axes, "(b) Jerk", "‖jerk‖ / peak speed (frame⁻²)"),
    ):
        axes.axvline(0, color="grey", linewidth=0.8)
        axes.set(title=title, xlabel="frames from the boundary", ylabel=unit)
        axes.legend(fontsize="small")
    figure.savefig(path, dpi=120)
    return path


Point = tuple[float, float, float | None]  # a knob's value, a metric's mean, its 95 % half-width (or None)
KNOB_METRICS = (
    ("jerk", "Jerk (transitions)"),
    ("fid", "FID (individual motions)"),
    ("r_top3", "R-Top3 (individual motions)"),
)


def plot_against_knob(path: Path, series: dict[str, dict[str, list[Point]]], knob: str) -> Path:
    """Jerk, FID and R-Top3 against a sampling knob (T_s, η, steps, ...), one line per label of
    ``series[metric]``, with error bars where a point has a half-width."""
    from matplotlib.figure import Figure

    figure = Figure(figsize=(12, 3.6), dpi=110, layout="constrained")
    for axes, (metric, title) in zip(figure.subplots(1, len(KNOB_METRICS)), KNOB_METRICS):
        for label, points in series.get(metric, {}).items():
            points = sorted(p for p in points if p[1] is not None)
            if not points:
                continue
            xs, means, widths = zip(*points)
            errors = None if any(w is None for w in widths) else widths
            axes.errorbar(xs, means, yerr=errors, marker="o", capsize=3, label=label)
        axes.set(xlabel=knob, title=title)
        axes.grid(alpha=0.3)
        axes.legend(fontsize="small")
    figure.savefig(path)
    return path


def table_metrics(table: dict[str, Any]) -> dict[str, float]:
    """``multi/<row>/<metric>`` (``multi/tps/jerk``; ``multi/mmm/transition/jerk`` when several
    models are judged; ``multi/reconstruction/jerk``), ``gt/<metric>_single``, ``gt/jerk_concat``,
    ``single/<metric>`` (``single/<model>/<metric>`` for several models),
    ``single/reconstruction/<metric>``, ``edit/<task>/<text|no_text>/<metric>`` (the editing table's
    rows, ``edit/<model>/...`` for several models), ``regenerate/regenerate<K>/<edit|whole>/<metric>``
    (the timeline-editing table's), each with a ``_ci`` twin; undefined values are left out."""
    names = {}
    sections = [("multi", row, values) for row, values in table["multi"].items()]
    sections += [("single", row, values) for row, values in table.get("single", {}).items() if row != GT_SINGLE]
    sections += [
        ("edit", row, values)
        for row, values in table.get("editing", {}).items()
        if row != GT_SINGLE and not row.startswith(RECONSTRUCTION)
    ]
    sections += [("regenerate", row, values) for row, values in table.get("regenerate", {}).items()]
    for section, row, values in sections:
        for metric, summary in values.items():
            if summary["mean"] is None:
                continue
            if row in (GT_SINGLE, GT_CONCAT):
                name = f"gt/{metric}_{row.removeprefix('gt_')}"
            elif section == "single" and row.split("/")[0] == GENERATED:
                name = "/".join(["single", *row.split("/")[1:], metric])
            else:
                name = f"{section}/{row}/{metric}"
            names[name] = summary["mean"]
            if summary["ci"] is not None:
                names[f"{name}_ci"] = summary["ci"]
    return names
