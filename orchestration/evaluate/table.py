"""An evaluation's table, assembled from its result files: table.json, table.md and Fig. 5."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from m2d2m.evaluation.measurements import (
    FEET_VARIANTS,
    JERK_FPS,
    R_PRECISION_BATCH,
    WINDOW,
    Reference,
    mean_profile,
)
from m2d2m.generators.edits import EDIT_MARGIN_SECONDS
from orchestration.evaluate.jobs import jobs, read_result, result_file
from orchestration.evaluate.records import Sampling
from orchestration.evaluate.settings import EvalSettings
from orchestration.registry import model
from orchestration.reports import (
    EDIT_TITLES,
    FEET_TITLES,
    FIGURE,
    GT_CONCAT,
    GT_SINGLE,
    RECONSTRUCTION,
    ROW_TITLES,
    SINGLE_COLUMNS,
    TABLE_JSON,
    TABLE_MD,
    notes,
    plot_fig5,
    render_table,
    summarize_rows,
)
from pipelines.shards import write_json_atomically
from pipelines.testset import TestSet


def _titles(settings: EvalSettings, codec_rows: dict[str, str]) -> dict[str, str]:
    """Row titles beyond :data:`ROW_TITLES`: editing rows, and with several models each row's model."""
    several = len(settings.candidates) > 1
    owner = {c.model: f"{c.model} " if several else "" for c in settings.candidates}
    titles = {
        row: f"{owner[c.model]}{EDIT_TITLES[task]} ({'w/' if text else 'w/o'} text)"
        for c in settings.candidates
        for task, text, row in settings.edit_rows(c)
    }
    if settings.regenerate is not None:
        for c in settings.candidates:
            stem = settings.regenerate_row(c)
            titles[f"{stem}/edit"] = f"{owner[c.model]}action {settings.regenerate} by an edit, the rest kept"
            titles[f"{stem}/whole"] = f"{owner[c.model]}the whole sequence again"
    if several:
        titles |= {settings.row(c, m): f"{c.model} {m}" for c, m in settings.rows()}
        titles |= {settings.single_row(c): f"{c.model} (single action)" for c in settings.candidates}
        titles |= {
            row: f"{ROW_TITLES[RECONSTRUCTION]} ({', '.join(m for m, r in codec_rows.items() if r == row)})"
            for row in set(codec_rows.values())
        }
    return titles


def _edit_methods(settings: EvalSettings) -> str:
    """How the judged models that edit with another method than their own say so: " (mmm with its
    independent method)", or nothing."""
    methods = {name: model(name).load("generator").edit_method for name in settings.models}
    own = [f"{name} with its {method} method" for name, method in methods.items() if method is not None]
    return f" ({', '.join(own)})" if own else ""


def _feet_rows(results: dict[tuple[str, str], list[dict[str, Any]]]) -> dict[str, list[dict[str, float]]]:
    """Each multi-motion row's motions with the feet planted as row ``<row>.planted`` (MLflow takes
    periods in metric names, not "+")."""
    return {
        f"{row}.{variant}": [result[f"metrics_{variant}"] for result in found]
        for (kind, row), found in results.items()
        if kind == "multi"
        for variant in FEET_VARIANTS
    }


def build_table(
    run_dir: Path,
    settings: EvalSettings,
    testset: TestSet,
    reference: Reference,
    codec_of: dict[str, str],
    samplings: dict[str, Sampling],
) -> dict[str, Any]:
    """table.json, table.md and fig5.png from the run's result files."""
    several = len(settings.candidates) > 1
    results: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for job in jobs(settings):
        results.setdefault((job.table, job.row), []).append(read_result(result_file(run_dir, job)))
    metrics = {key: [result["metrics"] for result in found] for key, found in results.items()}
    feet_rows = _feet_rows(results)
    codecs = {
        label: [reference.reconstruction_rows(label, r) for r in range(settings.repeats)]
        for label in reference.reconstructions
    }
    codec_row = {label: f"{RECONSTRUCTION}/{label}" if len(codecs) > 1 else RECONSTRUCTION for label in codecs}
    owners = {name: codec_row[label] for name, label in codec_of.items()}
    titles = _titles(settings, owners)
    titles |= {
        row: f"{titles.get(base, base)}{FEET_TITLES[variant]}"
        for row in feet_rows
        for base, variant in [row.rsplit(".", 1)]
    }
    gt_single = [reference.measure(r) for r in range(settings.repeats)]
    columns = {metric for metric, _ in SINGLE_COLUMNS}
    gt_items = [{k: v for k, v in m.items() if k in columns} for m in gt_single]
    items_through_codecs = {codec_row[label]: [rows[1] for rows in repeats] for label, repeats in codecs.items()}
    sampling_note = "; ".join(f"{name}: {s.multi}" if several else s.multi for name, s in samplings.items())
    single_note = "; ".join(f"{name}: {s.single}" if several else str(s.single) for name, s in samplings.items())
    table: dict[str, Any] = {
        "settings": asdict(settings),
        "testset": {"path": str(testset.path), "n": testset.n, "instances": len(testset), "items": reference.items},
        "r_precision_batch": reference.rp_batch,
        "window": WINDOW,
        "jerk_fps": JERK_FPS,
        "notes": notes(sampling_note, single_note if settings.single else None, reference),
        "titles": titles,
        "codecs": owners,
        "multi": summarize_rows(
            {
                GT_SINGLE: gt_single,
                GT_CONCAT: [reference.concat_row()] * settings.repeats,
                **{codec_row[label]: [rows[0] for rows in repeats] for label, repeats in codecs.items()},
                **{row: found for (kind, row), found in metrics.items() if kind == "multi"},
                **feet_rows,
            }
        ),
    }
    for kind in ("single", "editing"):
        rows = {row: found for (owner, row), found in metrics.items() if owner == kind}
        if rows:
            table[kind] = summarize_rows({GT_SINGLE: gt_items, **items_through_codecs, **rows})
    regenerated = {
        f"{row}/{version}": [result[key] for result in found]
        for (kind, row), found in results.items()
        if kind == "regenerate"
        for version, key in (("edit", "metrics"), ("whole", "metrics_whole"))
    }
    if regenerated:
        table["regenerate"] = summarize_rows(regenerated)
        table["notes"].append(
            f"editing on the timeline: action {settings.regenerate} of each instance (sampled as its multi-motion "
            f"row samples it) sampled again, every other frame kept outside {EDIT_MARGIN_SECONDS:g}-s margins"
            f"{_edit_methods(settings)}; against the whole sequence sampled again, with the same new "
            f"seeds. R-Top3 over groups of {min(R_PRECISION_BATCH, len(reference.actions))} regenerated actions; "
            "transition FID and Jerk at the action's joins"
        )
    write_json_atomically(run_dir / TABLE_JSON, table)
    (run_dir / TABLE_MD).write_text(render_table(table), encoding="utf-8")
    curves = {
        titles.get(row, row): mean_profile(
            [
                (np.asarray(r["profile"]["velocity"]), np.asarray(r["profile"]["jerk"]))
                for r in found
                if r["profile"]["windows"]
            ]
        )
        for (kind, row), found in results.items()
        if kind == "multi"
    }
    reconstructed = {
        titles.get(codec_row[label], ROW_TITLES[RECONSTRUCTION]): mean_profile(codec.measures.profiles)
        for label, codec in reference.reconstructions.items()
    }
    plot_fig5(run_dir / FIGURE, {ROW_TITLES[GT_CONCAT]: reference.concat_profile, **reconstructed, **curves})
    return table
