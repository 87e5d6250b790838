"""`m2d2m testset` and `m2d2m evaluate`: the paper's multi-motion table (§5.2, Tables 1–2), its
single-motion table (§5.3, Table 3) and its Fig. 5, for one checkpoint on one N-action test set.

Per method and repeat r, every test instance is generated (lengths: the ground-truth items' in
tokens) and measured with the text–motion evaluator:

- individual motion: each action's frames of the generated sequence against the item's caption
  (R-Top3, MM-Dist), against the ground-truth segments (FID), and among themselves (Diversity);
- transition: the ``WINDOW`` frames around each boundary against "ground truth (single)"
  windows, the middle ``WINDOW`` frames of every ground-truth item (FID), among themselves
  (Diversity), and the paper's Jerk (eq. 10) of the joints there, time measured in frames.

Reference rows: "ground truth (single)" measures the ground-truth segments and their middle
windows the same way; "ground truth (concat)" is the Jerk at the boundaries of each instance's
ground-truth segments joined by :func:`m2d2m.transitions.slerp_join` with no window (aligned, not blended). Every number is a mean ± 95 %
CI over the repeats. docs/evaluation.md explains each choice.

Each finished (method, repeat) is a JSON file under the run's ``results/``, so ``--resume``
recomputes nothing that is done; the table, the figure and the MLflow run are rebuilt from those
files at the end.
"""

from __future__ import annotations

import json
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.nn.utils.rnn import pad_sequence
from tqdm import tqdm

from m2d2m.evaluator import TextMotionEvaluator, load_evaluator, load_guo_checkpoint
from m2d2m.layout import MANIFEST
from m2d2m.metrics import (DEFAULT_MIN_STEP, diversity, fid, jerk, mean_confidence_interval, mm_dist,
                           multimodality, r_precision, transition_windows)
from m2d2m.motion import Motion
from m2d2m.representation import features_to_joints
from m2d2m.sampling import METHODS, SamplingOptions, switch_step
from m2d2m.skeleton import Skeleton
from m2d2m.transitions import slerp_join
from orchestration.errors import UserError
from orchestration.generate import Generator, resolve_checkpoint
from orchestration.runs import find_run, mark_latest, new_run_dir, read_run_info, run_file, write_run_info
from orchestration.tracking import client as tracking_client
from orchestration.tracking import ensure_experiment, experiment_name, log_batch
from orchestration.train import EVALUATOR_FILE, EVALUATOR_STAGE
from pipelines.shards import write_json_atomically
from pipelines.testset import (INSTANCES, MOTIONS, TestSet, split_metas, build_testset, check_testset, describe,
                               load_testset, testset_dir)

EVAL_STAGE = "eval"
TESTSET_STAGE = "testset"
DEFAULT_N, DEFAULT_SEED = 4, 0  # the paper's N = 4; the test set `evaluate` builds when none is given
WINDOW = 40  # transition frames around a boundary (paper §5.1, after PriorMDM)
JERK_FPS = 1.0  # time in frames: the scale of the paper's Jerk column (ground truth ≈ 1.19)
R_PRECISION_BATCH = 32  # Guo's: each caption against 31 other motions
DIVERSITY_PAIRS = 300
MM_PROMPTS, MM_GENERATIONS = 100, 10  # MModality: prompts, generations per prompt
SINGLE_GUIDANCE, SINGLE_ETA = 4.0, 0.5  # the paper's single-motion sampling settings
EMBED_CHUNK = 256  # clips per evaluator call
RESULTS = "results"
TABLE_MD, TABLE_JSON, FIGURE = "table.md", "table.json", "fig5.png"
GT_SINGLE, GT_CONCAT, GENERATED = "gt_single", "gt_concat", "generated"

# (metric, column title) of each table, in the paper's order
MULTI_COLUMNS = (("r_top3", "R-Top3 ↑"), ("fid", "FID ↓"), ("mm_dist", "MMdist ↓"), ("diversity", "Div →"),
                 ("transition_fid", "Transition FID ↓"), ("transition_diversity", "Transition Div →"),
                 ("jerk", "Jerk →"))
SINGLE_COLUMNS = (("r_top1", "R-Top1 ↑"), ("r_top2", "R-Top2 ↑"), ("r_top3", "R-Top3 ↑"), ("fid", "FID ↓"),
                  ("mm_dist", "MM-Dist ↓"), ("diversity", "Diversity →"), ("mmodality", "MModality ↑"))
ROW_TITLES = {GT_SINGLE: "Ground truth (single)", GT_CONCAT: "Ground truth (concat)",
              GENERATED: "Generated (single action)"}


# ------------------------------------------------------------------------------------ MLflow


# ---------------------------------------------------------------------------------- test sets


def make_testset(data_dir: str | Path, dataset: str, n: int = DEFAULT_N, seed: int = DEFAULT_SEED,
                 mirrors: str = "same", force: bool = False, limit: int | None = None) -> dict[str, Any]:
    """Build (or reuse) the N-action test set of a processed dataset and record it in MLflow
    (experiment ``<dataset>/testset``: its parameters, pool and instance counts, and its files,
    so an evaluation can name exactly what it ran on). Returns the summary with ``mlflow_run_id``."""
    try:
        summary = build_testset(data_dir, n=n, seed=seed, mirrors=mirrors, force=force, limit=limit)
    except (FileNotFoundError, FileExistsError, ValueError) as error:
        raise UserError(str(error)) from error
    path = Path(summary["path"])
    client = tracking_client()
    run = client.create_run(ensure_experiment(experiment_name(dataset, TESTSET_STAGE)), run_name=path.name,
                            tags={"dataset": dataset, "stage": TESTSET_STAGE, "reused": str(summary["reused"])})
    run_id = run.info.run_id
    pool = summary["pool"]
    log_batch(client, run_id,
         params={"n": n, "seed": seed, "mirrors": mirrors, "limit": limit, "split": summary["split"],
                 "min_frames": summary["min_frames"], "data": summary["source"]["dir"], "path": path},
         metrics={"pool_captions": pool["entries"], "pool_motions": pool["motions"],
                  "instances": summary["instances"]})
    for name in (MANIFEST, INSTANCES, MOTIONS):
        client.log_artifact(run_id, str(path / name), artifact_path="testset")
    client.set_terminated(run_id)
    return {**summary, "mlflow_run_id": run_id}


def _open_testset(path: str | Path) -> TestSet:
    """A test set that checks clean against its manifest, or a one-line error."""
    path = Path(path)
    if not (path / MANIFEST).exists():
        raise UserError(f"{path}: no test set there; build one with `m2d2m testset` (make testset)")
    problems = check_testset(path)
    if problems:
        raise UserError(f"{path}: {problems[0]} (rebuild it with `m2d2m testset --force`)")
    return load_testset(path)


def _caption_tokens(testset: TestSet) -> list[list[str]]:
    """Each item's caption as ``word/POS`` tokens, in item order, read from the test set's source
    dataset: the corpus's own tags are what the evaluator was trained on. (The test set's own
    shard reader is reused: importing training's would load Lightning, seconds for nothing.)"""
    try:
        metas = split_metas(Path(testset.manifest["source"]["dir"]), testset.manifest["split"])
    except FileNotFoundError as error:
        raise UserError(f"{error}; the captions' word/POS tokens come from the test set's source dataset") from error
    wanted = {(item.key, item.caption_index) for instance in testset for item in instance.items}
    tokens = {(meta["id"], index): caption["tokens"] for meta in metas
              for index, caption in enumerate(meta["captions"]) if (meta["id"], index) in wanted}
    return [tokens[item.key, item.caption_index] for instance in testset for item in instance.items]


# ----------------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class EvalSettings:
    """Every knob that changes the numbers. Recorded in run.json, table.json and the MLflow
    params, and fixed for a run: ``--resume`` continues with exactly these."""

    checkpoint: str
    testset: str | None  # None: the default test set of the checkpoint's dataset, resolved by evaluate
    evaluator: str
    glove: str | None  # Guo's published evaluator: its GloVe and meta directories
    meta: str | None
    methods: tuple[str, ...]
    ts: int | None
    eta: float
    guidance: float
    repeats: int
    single: bool

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "EvalSettings":
        return cls(**{**values, "methods": tuple(values["methods"])})


KNOBS = tuple(f.name for f in fields(EvalSettings)) + ("guo_evaluator",)


def _methods(values: Sequence[str]) -> tuple[str, ...]:
    """Methods given as repeated options and/or comma lists, in order, without repeats."""
    methods = [m.strip() for value in values for m in value.split(",") if m.strip()]
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        problem = f"unknown method {unknown[0]!r}" if unknown else "no method given"
        raise UserError(f"{problem}; choose from {', '.join(METHODS)}")
    return tuple(dict.fromkeys(methods))


def new_settings(dataset: str, checkpoint: str = "latest", testset: str | None = None, evaluator: str | None = None,
                 guo_evaluator: str | None = None, glove: str | None = None, meta: str | None = None,
                 methods: Sequence[str] = ("tps",), ts: int | None = None, eta: float = 0.25, guidance: float = 2.0,
                 repeats: int = 10, single: bool = False) -> EvalSettings:
    """The settings of a new evaluation, with references resolved to files (so that a later
    ``latest`` cannot change what a resumed run measures). Defaults: the paper's multi-motion
    sampling (T_s = 0.9·T, η = 0.25, s = 2) and its 10 repeats."""
    if repeats < 1:
        raise UserError(f"--repeats must be at least 1, got {repeats}")
    if eta < 0:
        raise UserError(f"--eta must be >= 0, got {eta}")
    if guo_evaluator is not None:
        if evaluator is not None:
            raise UserError("give --evaluator or --guo-evaluator, not both")
        if glove is None:
            raise UserError("--guo-evaluator needs --glove DIR (text-to-motion's glove/ directory)")
        evaluator_path = Path(guo_evaluator).resolve()
        meta = str(Path(meta or evaluator_path / "meta").resolve())
        glove = str(Path(glove).resolve())
    else:
        if glove is not None or meta is not None:
            raise UserError("--glove and --meta go with --guo-evaluator")
        evaluator_path = run_file(evaluator or "latest", dataset, EVALUATOR_STAGE, EVALUATOR_FILE,
                                  "make train-evaluator").resolve()
    return EvalSettings(
        checkpoint=str(resolve_checkpoint(checkpoint, dataset).resolve()),
        testset=None if testset is None else str(Path(testset).resolve()),
        evaluator=str(evaluator_path), glove=glove, meta=meta, methods=_methods(methods), ts=ts,
        eta=float(eta), guidance=float(guidance), repeats=int(repeats), single=bool(single))


def reopen(reference: str, dataset: str) -> tuple[Path, EvalSettings]:
    """An earlier evaluation run (directory, name or MLflow id) and its settings, to resume."""
    run_dir = find_run(reference, dataset, EVAL_STAGE)
    return run_dir, EvalSettings.from_dict(read_run_info(run_dir)["settings"])


def _load_evaluator(settings: EvalSettings, device: torch.device) -> TextMotionEvaluator:
    try:
        if settings.glove is not None:
            return load_guo_checkpoint(settings.evaluator, settings.glove, settings.meta, map_location=device)
        return load_evaluator(settings.evaluator, map_location=device)
    except (FileNotFoundError, ValueError, KeyError) as error:
        raise UserError(str(error)) from error


# ------------------------------------------------------------------------------- measurements


def _rng(repeat: int, purpose: str) -> np.random.Generator:
    """One stream per repeat and purpose: the seeds of repeat r are the same for every method,
    and do not depend on which other repeats or tables run."""
    return np.random.default_rng([repeat, zlib.crc32(purpose.encode())])


def _seeds(repeat: int, purpose: str, count: int) -> list[int]:
    return [int(s) for s in _rng(repeat, purpose).integers(0, 2**31 - 1, count)]


def _pairs(count: int) -> int:
    """Diversity pairs: Guo's 300, or fewer for a small set (a pair must not need more samples)."""
    return min(DIVERSITY_PAIRS, count - 1)


def _nanmean(values: Sequence[float]) -> float:
    """Mean over the defined values (a window where nothing moves has no Jerk); NaN if none is."""
    kept = np.asarray(values, dtype=np.float64)
    kept = kept[~np.isnan(kept)]
    return float(kept.mean()) if len(kept) else float("nan")


def _embed_clips(evaluator: TextMotionEvaluator, clips: Sequence[np.ndarray]) -> np.ndarray:
    """Motion embeddings (len(clips), E) of un-normalised feature clips of any lengths."""
    parts = []
    with torch.no_grad():
        for start in range(0, len(clips), EMBED_CHUNK):
            chunk = [torch.as_tensor(np.asarray(c), dtype=torch.float32) for c in clips[start:start + EMBED_CHUNK]]
            lengths = torch.tensor([len(c) for c in chunk])
            padded = pad_sequence(chunk, batch_first=True).to(evaluator.device)
            parts.append(evaluator.embed_motion(padded, lengths).cpu().numpy())
    return np.concatenate(parts)


def _embed_captions(evaluator: TextMotionEvaluator, captions: Sequence[Sequence[str]]) -> np.ndarray:
    with torch.no_grad():
        return np.concatenate([evaluator.embed_text(captions[start:start + EMBED_CHUNK]).cpu().numpy()
                               for start in range(0, len(captions), EMBED_CHUNK)])


def transition_profiles(joints: np.ndarray, boundaries: Sequence[int]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Fig. 5's curves for each full ``WINDOW``-frame window around a boundary: the mean joint
    speed per frame step (metres per frame, ``WINDOW − 1`` values) and the mean jerk magnitude
    normalised by each joint's peak speed in the window (per frame², ``WINDOW − 3`` values).
    Clipped windows, at a sequence's ends, are left out so that every curve has the same frames."""
    profiles = []
    for frames in transition_windows(joints, boundaries, WINDOW):
        if len(frames) < WINDOW:
            continue
        steps = np.linalg.norm(np.diff(frames, axis=0), axis=-1)  # (WINDOW − 1, J) metres per frame
        third = np.linalg.norm(np.diff(frames, n=3, axis=0), axis=-1)  # (WINDOW − 3, J)
        peak = np.maximum(steps.max(0), DEFAULT_MIN_STEP)  # a still joint must not blow up the ratio
        profiles.append((steps.mean(1), (third / peak).mean(1)))
    return profiles


def _mean_profile(profiles: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, Any]:
    if not profiles:
        return {"velocity": None, "jerk": None, "windows": 0}
    return {"velocity": np.mean([p[0] for p in profiles], 0).tolist(),
            "jerk": np.mean([p[1] for p in profiles], 0).tolist(), "windows": len(profiles)}


def _matching(text: np.ndarray, motion: np.ndarray, order: np.ndarray, batch: int) -> dict[str, float]:
    """R-Top1..3 over consecutive groups of ``batch`` in the repeat's shuffled order (Guo
    shuffles; the incomplete group is dropped), and MM-Dist over the same rows."""
    used = order[: len(order) // batch * batch]
    precision = r_precision(text[used], motion[used], top_k=3, batch=batch)
    return {**{f"r_top{k + 1}": float(p) for k, p in enumerate(precision)},
            "mm_dist": mm_dist(text[used], motion[used])}


@dataclass
class Reference:
    """What the test set contributes whatever the method: its requests, the caption embeddings,
    the ground-truth segment and middle-window embeddings, and the ground-truth Jerk values."""

    actions: list[list[str]]  # per instance
    tokens: list[list[int]]  # per instance, lengths in tokens
    text: np.ndarray  # (items, E)
    segments: np.ndarray  # (items, E)
    windows: np.ndarray  # (items, E): the middle WINDOW frames of each item
    jerk_single: float
    jerk_concat: float
    concat_profile: dict[str, Any]

    @property
    def items(self) -> int:
        return len(self.text)

    @property
    def rp_batch(self) -> int:
        """R-precision's group size: Guo's 32, or every item of a smaller test set."""
        return min(R_PRECISION_BATCH, self.items)

    @classmethod
    def build(cls, testset: TestSet, evaluator: TextMotionEvaluator, skeleton: Skeleton,
              frames_per_token: int) -> "Reference":
        tokens = [[max(1, n // frames_per_token) for n in instance.lengths] for instance in testset]
        # each segment cut to the frames generated for it (whole tokens: a multiple of 4, as Guo's loader crops)
        features = [[testset.features(instance.index, p)[:n * frames_per_token] for p, n in enumerate(lengths)]
                    for instance, lengths in zip(testset, tokens)]
        flat = [clip for clips in features for clip in clips]
        middles = [transition_windows(clip, [len(clip) // 2], WINDOW)[0] for clip in flat]
        joints = [[features_to_joints(clip, skeleton) for clip in clips] for clips in features]
        single = [jerk(j, JERK_FPS, [len(j) // 2], WINDOW) for clips in joints for j in clips]
        # joined with no transition window: each clip turned and moved to where the previous ended
        concat = [(joined, [first for first, _ in ranges[1:]])
                  for joined, ranges in (slerp_join(clips, 0, skeleton) for clips in joints)]
        return cls(
            actions=[instance.actions for instance in testset],
            tokens=tokens,
            text=_embed_captions(evaluator, _caption_tokens(testset)),
            segments=_embed_clips(evaluator, flat), windows=_embed_clips(evaluator, middles),
            jerk_single=_nanmean(single), jerk_concat=_nanmean([jerk(j, JERK_FPS, b, WINDOW) for j, b in concat]),
            concat_profile=_mean_profile([p for j, b in concat for p in transition_profiles(j, b)]))

    def measure(self, repeat: int) -> dict[str, float]:
        """The "ground truth (single)" row for one repeat (its shuffle and diversity draws)."""
        order = _rng(repeat, "order").permutation(self.items)
        return {**_matching(self.text, self.segments, order, self.rp_batch),
                "diversity": diversity(self.segments, _pairs(self.items), seed=repeat),
                "transition_diversity": diversity(self.windows, _pairs(self.items), seed=repeat),
                "jerk": self.jerk_single}


class Evaluation:
    """The measurements of one run: a loaded checkpoint and evaluator, the test set's
    :class:`Reference`, and a progress bar over (method, repeat, batch)."""

    def __init__(self, generator: Generator, evaluator: TextMotionEvaluator, reference: Reference,
                 settings: EvalSettings, batch_size: int, bar: tqdm) -> None:
        self.generator = generator
        self.evaluator = evaluator
        self.reference = reference
        self.settings = settings
        self.batch_size = batch_size
        self.bar = bar

    def _generate(self, actions: list[list[str]], tokens: list[list[int]], options: SamplingOptions, eta: float,
                  seeds: list[int]) -> Iterator[list[Motion]]:
        """The motions of the requests, one batch at a time (a whole repeat would not fit in
        memory on a real test set)."""
        for start in range(0, len(actions), self.batch_size):
            window = slice(start, start + self.batch_size)
            yield self.generator.generate_tokens(actions[window], tokens[window], options, eta, seeds[window])
            self.bar.update()

    def multi(self, method: str, repeat: int) -> dict[str, Any]:
        """One repeat of one method on the multi-motion test set: the metrics and Fig. 5's curves."""
        reference, settings = self.reference, self.settings
        self.bar.set_description(f"{method} r{repeat}")
        options = SamplingOptions(method=method, ts=settings.ts, guidance=settings.guidance)
        seeds = _seeds(repeat, "multi", len(reference.actions))
        segments, windows, jerks, profiles = [], [], [], []
        for motions in self._generate(reference.actions, reference.tokens, options, settings.eta, seeds):
            segments.append(_embed_clips(self.evaluator, [m.features[a:b] for m in motions for a, b in m.ranges]))
            windows.append(_embed_clips(self.evaluator, [
                w for m in motions for w in transition_windows(m.features, m.boundaries, WINDOW)]))
            jerks += [jerk(m.joints, JERK_FPS, m.boundaries, WINDOW) for m in motions]
            profiles += [p for m in motions for p in transition_profiles(m.joints, m.boundaries)]
        segment_emb, window_emb = np.concatenate(segments), np.concatenate(windows)
        order = _rng(repeat, "order").permutation(reference.items)
        metrics = {**_matching(reference.text, segment_emb, order, reference.rp_batch),
                   "fid": fid(segment_emb, reference.segments),
                   "diversity": diversity(segment_emb, _pairs(len(segment_emb)), seed=repeat),
                   "transition_fid": fid(window_emb, reference.windows),
                   "transition_diversity": diversity(window_emb, _pairs(len(window_emb)), seed=repeat),
                   "jerk": _nanmean(jerks)}
        return {"method": method, "repeat": repeat, "metrics": metrics, "profile": _mean_profile(profiles)}

    def single(self, repeat: int) -> dict[str, Any]:
        """One repeat of the single-motion table: every test item generated alone with the
        paper's single-motion settings, and MModality from ``MM_GENERATIONS`` generations of
        each of the first ``MM_PROMPTS`` items in the repeat's order."""
        reference = self.reference
        self.bar.set_description(f"single r{repeat}")
        options = SamplingOptions(method="tps", guidance=SINGLE_GUIDANCE)
        actions = [[action] for instance in reference.actions for action in instance]
        tokens = [[n] for instance in reference.tokens for n in instance]
        order = _rng(repeat, "order").permutation(reference.items)
        embedded = self._embed_generated(actions, tokens, options, _seeds(repeat, "single", len(actions)))
        prompts = order[:min(MM_PROMPTS, reference.items)]
        repeated = [p for p in prompts for _ in range(MM_GENERATIONS)]
        again = self._embed_generated([actions[p] for p in repeated], [tokens[p] for p in repeated], options,
                                      _seeds(repeat, "mmodality", len(repeated)))
        metrics = {**_matching(reference.text, embedded, order, reference.rp_batch),
                   "fid": fid(embedded, reference.segments),
                   "diversity": diversity(embedded, _pairs(len(embedded)), seed=repeat),
                   "mmodality": multimodality(again.reshape(len(prompts), MM_GENERATIONS, -1),
                                              pairs=MM_GENERATIONS, seed=repeat)}
        return {"repeat": repeat, "metrics": metrics}

    def _embed_generated(self, actions: list[list[str]], tokens: list[list[int]], options: SamplingOptions,
                         seeds: list[int]) -> np.ndarray:
        return np.concatenate([_embed_clips(self.evaluator, [m.features for m in motions])
                               for motions in self._generate(actions, tokens, options, SINGLE_ETA, seeds)])


# ------------------------------------------------------------------------------------- tables


def _summary(values: Sequence[float]) -> dict[str, float | None]:
    """Mean and 95 % CI half-width over the repeats; None where a repeat had no defined value."""
    values = np.asarray(values, dtype=np.float64)
    if not np.isfinite(values).all():
        return {"mean": None, "ci": None}
    mean, ci = mean_confidence_interval(values)
    return {"mean": mean, "ci": ci}


def _rows(per_repeat: dict[str, list[dict[str, float]]]) -> dict[str, dict[str, dict[str, float | None]]]:
    """Row → metric → mean and CI, from each row's per-repeat metric dicts."""
    return {row: {metric: _summary([r[metric] for r in repeats]) for metric in repeats[0]}
            for row, repeats in per_repeat.items()}


def _cell(summary: dict[str, float | None] | None) -> str:
    if summary is None or summary["mean"] is None:
        return "–"
    return f"{summary['mean']:.3f} ± {summary['ci']:.3f}"


def _markdown(title: str, columns: tuple[tuple[str, str], ...], rows: dict[str, dict[str, Any]]) -> list[str]:
    lines = [f"## {title}", "", "| Method | " + " | ".join(name for _, name in columns) + " |",
             "| --- |" + " --- |" * len(columns)]
    for row, values in rows.items():
        lines.append(f"| {ROW_TITLES.get(row, row)} | " + " | ".join(_cell(values.get(m)) for m, _ in columns) + " |")
    return lines + [""]


def render_table(table: dict[str, Any]) -> str:
    """table.md: the paper's tables, then the conventions a reader needs to compare them."""
    settings, testset = table["settings"], table["testset"]
    lines = [f"# Evaluation of {settings['checkpoint']}", "",
             f"Test set {testset['path']}: {testset['instances']} instances of N = {testset['n']} actions. "
             f"Mean ± 95 % CI over {settings['repeats']} repeats.", ""]
    lines += _markdown("Multi-motion (paper Tables 1–2)", MULTI_COLUMNS, table["multi"])
    if "single" in table:
        lines += _markdown("Single-motion (paper Table 3)", SINGLE_COLUMNS, table["single"])
    lines += [f"- {note}" for note in table["notes"]]
    return "\n".join(lines) + "\n"


def _notes(settings: EvalSettings, reference: Reference, steps: int) -> list[str]:
    notes = [f"sampling: T_s = {switch_step(settings.ts, steps)} of T = {steps}, η = {settings.eta:g}, "
             f"s = {settings.guidance:g}" + (f"; single-motion: s = {SINGLE_GUIDANCE:g}, η = {SINGLE_ETA:g}"
                                            if settings.single else ""),
             f"transition: the {WINDOW} frames around each boundary; ground truth (single) = the middle "
             f"{WINDOW} frames of every ground-truth item",
             "Jerk: paper eq. 10 averaged over joints and boundaries, time measured in frames (fps = 1)"]
    if reference.rp_batch < R_PRECISION_BATCH:
        notes.append(f"R-precision over groups of {reference.rp_batch}, not {R_PRECISION_BATCH}: the test set has only "
                     f"{reference.items} items (not comparable with published R-Top numbers)")
    return notes


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
    for axes, title, unit in ((speed_axes, "(a) Velocity", "mean joint speed (m/frame)"),
                              (jerk_axes, "(b) Jerk", "‖jerk‖ / peak speed (frame⁻²)")):
        axes.axvline(0, color="grey", linewidth=0.8)
        axes.set(title=title, xlabel="frames from the boundary", ylabel=unit)
        axes.legend(fontsize="small")
    figure.savefig(path, dpi=120)
    return path


def table_metrics(table: dict[str, Any]) -> dict[str, float]:
    """``multi/<method>/<metric>``, ``gt/<metric>_single``, ``gt/jerk_concat``, ``single/<metric>``,
    each with a ``_ci`` twin; undefined values are left out."""
    names = {}
    sections = [("multi", row, values) for row, values in table["multi"].items()]
    sections += [("single", row, values) for row, values in table.get("single", {}).items() if row == GENERATED]
    for section, row, values in sections:
        for metric, summary in values.items():
            if summary["mean"] is None:
                continue
            if row in (GT_SINGLE, GT_CONCAT):
                name = f"gt/{metric}_{row.removeprefix('gt_')}"
            else:
                name = f"multi/{row}/{metric}" if section == "multi" else f"single/{metric}"
            names[name], names[f"{name}_ci"] = summary["mean"], summary["ci"]
    return names


# ------------------------------------------------------------------------------------ the run


def _result_file(run_dir: Path, method: str | None, repeat: int) -> Path:
    return run_dir / RESULTS / (f"multi-{method}-r{repeat}.json" if method else f"single-r{repeat}.json")


def _read(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text(encoding="utf-8"))


@dataclass(frozen=True)
class ParentRun:
    """An MLflow run to nest an evaluation under (a sweep): its experiment, its id, the child's name."""

    experiment_id: str
    run_id: str
    child_name: str


def _start(settings: EvalSettings, dataset: str, generator: Generator, testset: TestSet, rp_batch: int,
           parent: ParentRun | None = None) -> Path:
    """A new run directory and its MLflow run (experiment ``<dataset>/eval``, or a child run of
    ``parent`` in the parent's experiment) with every knob."""
    run_dir = new_run_dir(dataset, EVAL_STAGE)
    client = tracking_client()
    tags = {"dataset": dataset, "stage": EVAL_STAGE, "methods": ",".join(settings.methods),
            "run_dir": str(run_dir.resolve())}
    if parent is None:
        run = client.create_run(ensure_experiment(experiment_name(dataset, EVAL_STAGE)), run_name=run_dir.name,
                                tags=tags)
    else:
        run = client.create_run(parent.experiment_id, run_name=parent.child_name,
                                tags={**tags, "mlflow.parentRunId": parent.run_id})
    steps = generator.checkpoint.schedule.config.steps
    log_batch(client, run.info.run_id, params={
        **asdict(settings), "methods": ",".join(settings.methods), "ts": switch_step(settings.ts, steps),
        "steps": steps, "n": testset.n, "instances": len(testset), "window": WINDOW, "jerk_fps": JERK_FPS,
        "r_precision_batch": rp_batch, "single_guidance": SINGLE_GUIDANCE, "single_eta": SINGLE_ETA})
    write_run_info(run_dir, stage=EVAL_STAGE, dataset=dataset, status="running", settings=asdict(settings),
                   mlflow_run_id=run.info.run_id)
    return run_dir


def _default_testset(generator: Generator, dataset: str) -> Path:
    """n4-seed0 of the dataset the checkpoint was trained on (data/<dataset> when it does not
    say), built and logged when missing."""
    data_dir = Path(generator.checkpoint.extra.get("data_dir") or Path("data") / dataset)
    path = testset_dir(data_dir, DEFAULT_N, DEFAULT_SEED)
    if not (path / MANIFEST).exists():
        print(describe(make_testset(data_dir, dataset)))
    return path


def _check(settings: EvalSettings, generator: Generator, testset: TestSet, evaluator: TextMotionEvaluator) -> None:
    """Refuse, before anything runs, what cannot give a table."""
    dims = {"the checkpoint": generator.checkpoint.normalizer.mean.shape[-1],
            "the evaluator": evaluator.config.feature_dim}
    for owner, dim in dims.items():
        if testset.manifest.get("feature_dim") != dim:
            raise UserError(f"{testset.path} holds {testset.manifest.get('feature_dim')}-d features but {owner} "
                            f"works on {dim}-d ones: use a test set of the same dataset")
    if testset.n < 2 or len(testset) < 2:
        raise UserError(f"{testset.path}: multi-motion evaluation needs N >= 2 actions and at least 2 instances "
                        f"(it has N = {testset.n}, {len(testset)} instances)")
    steps = generator.checkpoint.schedule.config.steps
    try:
        for method in settings.methods:
            SamplingOptions(method=method, ts=settings.ts, guidance=settings.guidance).check(steps)
    except ValueError as error:
        raise UserError(str(error)) from error


def evaluate(settings: EvalSettings, dataset: str = "synthetic", run_dir: Path | None = None,
             batch_size: int = 64, parent: ParentRun | None = None,
             progress: bool = True) -> tuple[Path, dict[str, Any]]:
    """Run (or, given ``run_dir``, finish) an evaluation; returns the run directory and the table.
    ``parent`` nests its MLflow run under a sweep's.

    Only the (method, repeat) pairs without a result file are computed, so a killed run resumes
    where it stopped and a finished one only rewrites its table, figure and MLflow record.
    """
    generator = Generator.from_checkpoint(settings.checkpoint, dataset)
    if settings.testset is None:
        settings = replace(settings, testset=str(_default_testset(generator, dataset).resolve()))
    testset = _open_testset(settings.testset)
    evaluator = _load_evaluator(settings, generator.sampler.device)
    _check(settings, generator, testset, evaluator)
    checkpoint = generator.checkpoint
    reference = Reference.build(testset, evaluator, checkpoint.skeleton, checkpoint.frames_per_token)
    if run_dir is None:
        run_dir = _start(settings, dataset, generator, testset, reference.rp_batch, parent)
    (run_dir / RESULTS).mkdir(exist_ok=True)
    jobs: list[tuple[str | None, int]] = [(m, r) for m in settings.methods for r in range(settings.repeats)]
    jobs += [(None, r) for r in range(settings.repeats)] if settings.single else []
    pending = [job for job in jobs if not _result_file(run_dir, *job).exists()]
    run_id = read_run_info(run_dir)["mlflow_run_id"]
    client = tracking_client()
    batches = {"multi": -(-len(reference.actions) // batch_size),
               "single": -(-reference.items // batch_size)
               + -(-min(MM_PROMPTS, reference.items) * MM_GENERATIONS // batch_size)}
    try:
        with tqdm(total=sum(batches["multi" if m else "single"] for m, _ in pending), unit="batch",
                  disable=not progress) as bar:
            evaluation = Evaluation(generator, evaluator, reference, settings, batch_size, bar)
            for method, repeat in pending:
                result = evaluation.multi(method, repeat) if method else evaluation.single(repeat)
                write_json_atomically(_result_file(run_dir, method, repeat), result)
        table = _finish(run_dir, settings, testset, reference, checkpoint.schedule.config.steps)
    except BaseException:
        write_run_info(run_dir, status="failed")
        client.set_terminated(run_id, "FAILED")
        raise
    log_batch(client, run_id, metrics=table_metrics(table))
    for name in (TABLE_MD, TABLE_JSON, FIGURE):
        client.log_artifact(run_id, str(run_dir / name))
    client.log_artifacts(run_id, str(run_dir / RESULTS), artifact_path=RESULTS)
    client.set_terminated(run_id)
    write_run_info(run_dir, status="finished")
    mark_latest(run_dir)
    return run_dir, table


def _finish(run_dir: Path, settings: EvalSettings, testset: TestSet, reference: Reference,
            steps: int) -> dict[str, Any]:
    """table.json, table.md and fig5.png from the run's result files."""
    multi = {m: [_read(_result_file(run_dir, m, r)) for r in range(settings.repeats)] for m in settings.methods}
    gt_single = [reference.measure(r) for r in range(settings.repeats)]
    per_row = {GT_SINGLE: gt_single, GT_CONCAT: [{"jerk": reference.jerk_concat}] * settings.repeats,
               **{m: [result["metrics"] for result in results] for m, results in multi.items()}}
    table: dict[str, Any] = {
        "settings": asdict(settings),
        "testset": {"path": str(testset.path), "n": testset.n, "instances": len(testset), "items": reference.items},
        "r_precision_batch": reference.rp_batch, "window": WINDOW, "jerk_fps": JERK_FPS,
        "notes": _notes(settings, reference, steps), "multi": _rows(per_row)}
    if settings.single:
        single = [_read(_result_file(run_dir, None, r))["metrics"] for r in range(settings.repeats)]
        columns = {metric for metric, _ in SINGLE_COLUMNS}
        table["single"] = _rows({GT_SINGLE: [{k: v for k, v in m.items() if k in columns} for m in gt_single],
                                 GENERATED: single})
    write_json_atomically(run_dir / TABLE_JSON, table)
    (run_dir / TABLE_MD).write_text(render_table(table), encoding="utf-8")
    curves = {m: _mean_profile([(np.asarray(r["profile"]["velocity"]), np.asarray(r["profile"]["jerk"]))
                                for r in results if r["profile"]["windows"]]) for m, results in multi.items()}
    plot_fig5(run_dir / FIGURE, {ROW_TITLES[GT_CONCAT]: reference.concat_profile, **curves})
    return table
