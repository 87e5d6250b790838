"""The Ray Data job behind ``m2d2m data``: a raw corpus in, ``data/<name>/`` out.

Stages: read (list the corpus) → validate → features (+ mirror) → language (verb decomposition)
→ stats → write. The per-motion stages are one function of rows, run by Ray Data tasks, so the
same code runs on a laptop (``ray.init()`` locally) and on a cluster (``--ray-address``). The
driver consumes the results in input order and writes the shards, the statistics and, last, the
manifest; the same input and config therefore give byte-identical shards. Everything is built in
a sibling directory and swapped in only once complete, so a failed, interrupted or killed build
leaves the previous dataset as it was (docs/data.md, "Rebuilding").
"""

from __future__ import annotations

import io
import json
import os
import secrets
import shutil
import subprocess
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

import m2d2m
from m2d2m.atomic import atomic_path
from m2d2m.layout import MANIFEST, NLP, QUARANTINE, SHARDS, STATS, recorded_path, relative_to_project
from m2d2m.locks import holding
from m2d2m.motion.representation.features import features_to_joints, joints_to_features, mirror_caption, mirror_joints
from m2d2m.motion.representation.normalization import Normalizer, RunningMoments, group_averaged_std
from m2d2m.motion.representation.skeleton import Skeleton
from m2d2m.plugins import import_plugins
from m2d2m.progress import ProgressLines, on_terminal
from pipelines.corpora import SPLITS, Corpus, CorpusLayout, FrameBounds, Rejected, corpus
from pipelines.dataset import encode_sample, reason_kind, stage_counts, summary_table
from pipelines.language import SMALL_MODEL, Tagger, decompose, load_tagger, parse_tagged_tokens, train_tagger
from pipelines.shards import SCHEMA_VERSION, ShardWriter, shard_records, write_json_atomically
from pipelines.synthetic.corpus import tagged_captions


@dataclass(frozen=True)
class DataConfig:
    """Everything that decides the bytes of a processed dataset (recorded in its manifest)."""

    dataset: str
    raw: str
    out: str
    samples_per_shard: int = 500
    min_frames: int | None = None
    max_frames: int | None = None
    feat_bias: float = 5.0
    workers: int = 2
    tagger_captions: int = 6000  # a tagger trains in ~30 s on 6,000 captions (2 cores)
    seed: int = 0
    ray_address: str | None = None
    # the plugins the Ray tasks import (m2d2m.plugins.plugins_for_workers), for a plugin's corpus
    plugins: dict[str, list[str]] = field(default_factory=dict)
    # what the corpus's layout takes beyond --raw (CorpusLayout.options: --bvh, --joint-map, --units)
    layout_options: dict[str, str] = field(default_factory=dict)

    @property
    def corpus(self) -> Corpus:
        return corpus(self.dataset)

    @property
    def skeleton(self) -> Skeleton:
        return self.corpus.skeleton

    @property
    def bounds(self) -> FrameBounds:
        low, high = self.corpus.frame_bounds
        return FrameBounds(self.min_frames or low, self.max_frames or high)

    def recorded(self) -> dict[str, Any]:
        """The config as the manifest stores it: what determines the output, not where it ran."""
        record = asdict(self)
        for key in ("out", "workers", "ray_address", "plugins"):
            record.pop(key)
        record["raw"] = relative_to_project(self.raw)
        record["layout_options"] = {
            name: relative_to_project(value) if Path(value).is_absolute() else value
            for name, value in self.layout_options.items()
        }
        record["min_frames"], record["max_frames"] = self.bounds.minimum, self.bounds.maximum
        return record


def code_version() -> str:
    """Package version plus the git commit when run from a checkout."""
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            timeout=5,
            cwd=Path(__file__).resolve().parent,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        commit = ""
    return f"{m2d2m.__version__}+{commit}" if commit else m2d2m.__version__


def _language(caption: dict[str, Any]) -> dict[str, Any]:
    decomposition = decompose(caption["text"], tagged=parse_tagged_tokens(" ".join(caption["tokens"])))
    return {**caption, "actions": list(decomposition.actions), "verbs": list(decomposition.verbs)}


def _mirrored_caption(caption: dict[str, Any]) -> dict[str, Any]:
    return {
        **caption,
        "text": mirror_caption(caption["text"]),
        "tokens": [mirror_caption(t) for t in caption["tokens"]],
    }


def _sample(
    key: str, source: str, features: np.ndarray, captions: list[dict], fps: float, mirrored: bool
) -> dict[str, Any]:
    meta = {
        "id": key,
        "source": source,
        "fps": fps,
        "frames": len(features),
        "mirrored": mirrored,
        "captions": [_language(c) for c in captions],
    }
    return {"key": key, "status": "ok", **encode_sample(features, meta)}


def _to_features(motion: np.ndarray, kind: str, skeleton: Skeleton, bounds: FrameBounds) -> np.ndarray:
    features = joints_to_features(motion, skeleton) if kind == "joints" else motion
    if not np.isfinite(features).all():
        raise Rejected("features", "features are not finite (degenerate joints, e.g. a zero-length bone)")
    bounds.check(len(features))
    return features


def process_motion(
    row: dict[str, Any],
    layout: CorpusLayout,
    skeleton: Skeleton,
    bounds: FrameBounds,
    make_mirror: bool,
    tagger: Tagger | None = None,
) -> list[dict[str, Any]]:
    """One corpus row → its sample (and mirror), or one quarantine record saying why not.
    ``tagger`` tags the captions a layout reads untagged."""
    try:
        motion = layout.read_motion(row, skeleton)
        features = _to_features(motion, row["kind"], skeleton, bounds)
        captions = [
            {**c, "tokens": tagger.corpus_tokens(c["text"])} if c["tokens"] is None and tagger else c
            for c in layout.read_captions(row)
        ]
        samples = [_sample(row["id"], row["id"], features, captions, skeleton.fps, False)]
        if make_mirror:
            joints = motion if row["kind"] == "joints" else features_to_joints(motion, skeleton)
            mirrored = _to_features(mirror_joints(joints, skeleton), "joints", skeleton, bounds)
            samples.append(
                _sample(
                    f"M{row['id']}", row["id"], mirrored, [_mirrored_caption(c) for c in captions], skeleton.fps, True
                )
            )
        return samples
    except Rejected as rejected:
        return [{"key": row["id"], "status": "quarantined", "stage": rejected.stage, "reason": rejected.reason}]


def init_ray(address: str | None, workers: int) -> None:
    """Join the cluster at ``address`` (or ``RAY_ADDRESS``; ``auto`` finds one started on this
    machine), saying which, or start a local Ray with ``workers`` CPUs."""
    import ray

    if ray.is_initialized():
        return
    address = address or os.environ.get("RAY_ADDRESS")
    if address:
        ray.init(address=address, logging_level="ERROR")
        print(
            f"Ray: joined the cluster at {ray.get_runtime_context().gcs_address} "
            f"({int(ray.cluster_resources().get('CPU', 0))} CPUs)",
            flush=True,
        )
    else:
        # "local" ignores a stale cluster file that a killed `ray start --head` can leave behind.
        ray.init(address="local", num_cpus=workers, include_dashboard=False, logging_level="ERROR")


@dataclass
class SplitCounts:
    inputs_seen: int = 0
    originals: int = 0
    mirrors: int = 0
    quarantined: int = 0
    frames: int = 0
    captions: int = 0
    single_verb_captions: int = 0

    @property
    def samples_written(self) -> int:
        return self.originals + self.mirrors

    def add(self, other: SplitCounts) -> None:
        for name, value in asdict(other).items():
            setattr(self, name, getattr(self, name) + value)


def plan_shards(rows: list[dict[str, Any]], samples_per_shard: int, make_mirror: bool) -> list[dict[str, Any]]:
    """Cut each split's rows, in order, into the inputs of one shard each: a shard can never
    exceed ``samples_per_shard`` (an input gives two samples when the pipeline mirrors), and the
    plan depends only on the corpus and the config, never on how many workers run it."""
    inputs_per_shard = max(1, samples_per_shard // (2 if make_mirror else 1))
    tasks = []
    for split in SPLITS:
        split_rows = [row for row in rows if row["split"] == split]
        for index, first in enumerate(range(0, len(split_rows), inputs_per_shard)):
            tasks.append({"split": split, "index": index, "rows": split_rows[first : first + inputs_per_shard]})
    return tasks


def write_shard(task: dict[str, Any], config: DataConfig, make_mirror: bool) -> dict[str, Any]:
    """Process one shard's inputs and write the shard (a Ray task): returns only what the driver
    needs — the shard's record, counts, partial train statistics, quarantine and tagged captions."""
    import_plugins(**config.plugins)  # a plugin's corpus is registered in this process too
    layout, skeleton, bounds = config.corpus.layout, config.skeleton, config.bounds
    tagger = None if layout.tagged_captions else _saved_tagger(str(Path(config.out).resolve() / NLP))
    split = task["split"]
    counts = SplitCounts()
    moments = RunningMoments(skeleton.feature_dim)
    quarantine, tagged = [], []
    writer = ShardWriter(
        Path(config.out).resolve() / SHARDS, split, config.samples_per_shard, first_index=task["index"]
    )
    with writer:
        for row in task["rows"]:
            counts.inputs_seen += 1
            for record in process_motion(row, layout, skeleton, bounds, make_mirror, tagger):
                if record["status"] == "quarantined":
                    counts.quarantined += 1
                    quarantine.append(
                        {"id": record["key"], "split": split, "stage": record["stage"], "reason": record["reason"]}
                    )
                    continue
                meta = json.loads(record["meta.json"])
                counts.mirrors += meta["mirrored"]
                counts.originals += not meta["mirrored"]
                counts.frames += meta["frames"]
                counts.captions += len(meta["captions"])
                counts.single_verb_captions += sum(len(c["verbs"]) == 1 for c in meta["captions"])
                writer.write(record["key"], {"motion.npy": record["motion.npy"], "meta.json": record["meta.json"]})
                if split == "train":
                    moments.add(np.load(io.BytesIO(record["motion.npy"])))
                    if not meta["mirrored"]:
                        tagged += [[c["text"], c["tokens"]] for c in meta["captions"]]
    return {
        "split": split,
        "index": task["index"],
        "shards": shard_records(writer.shards),
        "counts": asdict(counts),
        "moments": moments.state(),
        "quarantine": quarantine,
        "tagged": tagged,
    }


def _run_json_batch(
    batch: dict[str, np.ndarray], fn: Callable[..., dict[str, Any]], fn_kwargs: dict[str, Any]
) -> dict[str, Any]:
    """Ray Data ``map_batches`` adapter: one planned task (as JSON) in, its result (as JSON) out."""
    return {
        "position": batch["position"],
        "result": [json.dumps(fn(json.loads(task), **fn_kwargs)) for task in batch["task"]],
    }


def run_json_tasks(
    fn: Callable[..., dict[str, Any]],
    tasks: list[dict[str, Any]],
    workers: int,
    ray_address: str | None = None,
    **fn_kwargs: Any,
) -> list[dict[str, Any]]:
    """``fn(task, **fn_kwargs)`` for every JSON-able planned task, as Ray Data tasks of one CPU
    each (at most ``workers`` at a time); returns the JSON-able results in plan order, whatever
    order the tasks finished in, so the driver's output never depends on scheduling."""
    import ray

    init_ray(ray_address, workers)
    items = [{"position": position, "task": json.dumps(task)} for position, task in enumerate(tasks)]
    results = ray.data.from_items(items, override_num_blocks=max(1, len(items))).map_batches(
        _run_json_batch,
        fn_kwargs={"fn": fn, "fn_kwargs": fn_kwargs},
        batch_size=1,
        batch_format="numpy",
        compute=ray.data.TaskPoolStrategy(size=workers),
        num_cpus=1,
    )
    rows = results.iter_rows()
    if not on_terminal():  # Ray Data draws its own bars on a terminal; a log gets plain lines
        rows = ProgressLines(
            rows, total=len(items), desc=getattr(fn, "__name__", "tasks").strip("_").replace("_", " "), unit="task"
        )
    finished = sorted(rows, key=lambda row: row["position"])
    return [json.loads(row["result"]) for row in finished]


def run_shard_tasks(config: DataConfig, tasks: list[dict[str, Any]], make_mirror: bool) -> list[dict[str, Any]]:
    """Write every planned shard with Ray Data tasks; returns their results in plan order."""
    return run_json_tasks(
        write_shard, tasks, config.workers, config.ray_address, config=config, make_mirror=make_mirror
    )


def _corpus_statistics(raw: Path, skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray] | None:
    """The corpus's own Mean.npy / Std.npy when it ships them with the right shape."""
    mean_path, std_path = raw / "Mean.npy", raw / "Std.npy"
    if not (mean_path.exists() and std_path.exists()):
        return None
    mean, std = np.load(mean_path), np.load(std_path)
    if mean.shape != (skeleton.feature_dim,) or std.shape != (skeleton.feature_dim,):
        raise ValueError(f"{raw}: Mean.npy/Std.npy are not ({skeleton.feature_dim},)")
    return mean, std


def prepare_tagger(captions: list[tuple[str, list[tuple[str, str]]]], out: Path, config: DataConfig) -> str:
    """The tagger free-text prompts will use: an installed spaCy English pipeline when there is
    one, else one trained on (a seeded subsample of) the train split's own tagged captions."""
    import spacy

    if spacy.util.is_package(SMALL_MODEL):
        return f"installed {SMALL_MODEL}"
    if len(captions) > config.tagger_captions:
        chosen = np.random.default_rng(config.seed).choice(len(captions), config.tagger_captions, replace=False)
        captions = [captions[i] for i in sorted(chosen)]
    shutil.rmtree(out / NLP, ignore_errors=True)
    train_tagger(captions, out / NLP, seed=config.seed)
    return f"trained on {len(captions)} train captions"


def prepare_caption_tagger(out: Path, config: DataConfig) -> str:
    """The tagger of a corpus whose captions come untagged, made before its shards (which it tags)
    and kept for prompts: an installed spaCy English pipeline, else one trained on the tagged
    captions of the embedded corpus's plans (:func:`pipelines.synthetic.corpus.tagged_captions`)."""
    import spacy

    if spacy.util.is_package(SMALL_MODEL):
        return f"installed {SMALL_MODEL}"
    train_tagger(tagged_captions(config.tagger_captions, config.seed), out / NLP, seed=config.seed)
    return f"trained on {config.tagger_captions} captions of the embedded corpus (this corpus's come untagged)"


@lru_cache(maxsize=2)
def _saved_tagger(path: str) -> Tagger:
    """The tagger a build saved, loaded once per process (a Ray worker writes many shards)."""
    return load_tagger(path)


def reusable_dataset(config: DataConfig) -> dict[str, Any] | None:
    """The manifest of ``config.out`` when it was built from the same corpus with the same config
    (building it again would give the same dataset), else None."""
    manifest_path = Path(config.out) / MANIFEST
    if not manifest_path.exists():
        return None
    existing = json.loads(manifest_path.read_text(encoding="utf-8"))
    recorded = {**existing.get("config", {}), "raw": built_from(config.out, existing)}
    return existing if recorded == config.recorded() else None


def built_from(out: str | Path, manifest: dict[str, Any]) -> str | None:
    """The raw corpus the dataset at ``out`` was built from, named as :meth:`DataConfig.recorded`
    names it now (older manifests name it absolute, a corpus in the project too)."""
    raw = manifest.get("config", {}).get("raw")
    return relative_to_project(recorded_path(raw, Path(out) / MANIFEST)) if raw else None


# What a build writes; anything else in a dataset directory (tokens/, testsets/) is kept across a rebuild.
BUILD_OUTPUTS = frozenset({MANIFEST, QUARANTINE, STATS, SHARDS, NLP})


def _sibling(out: Path, role: str) -> Path:
    """``data/.<name>.<role>``: the lock, the build in progress, the dataset being replaced."""
    return out.parent / f".{out.name}.{role}"


def _retire(previous: Path, out: Path) -> None:
    """Move what the replaced dataset held beyond a build's outputs into the new one, then
    remove the rest of it."""
    for entry in sorted(previous.iterdir()):
        if entry.name not in BUILD_OUTPUTS and not (out / entry.name).exists():
            os.rename(entry, out / entry.name)
    shutil.rmtree(previous)


def _recover(out: Path) -> None:
    """Finish or undo whatever a killed build left beside ``out``: a swap cut between its two
    renames puts the old dataset back, one cut after them completes, and unfinished builds go."""
    previous = _sibling(out, "previous")
    if previous.exists():
        if out.exists():
            _retire(previous, out)
        else:
            os.rename(previous, out)
    building = _sibling(out, "building-").name
    for stale in out.parent.iterdir():
        if stale.name.startswith(building):
            shutil.rmtree(stale, ignore_errors=True)


@contextmanager
def _exclusive(out: Path) -> Iterator[None]:
    """Hold ``data/.<name>.lock`` while building and swapping (:mod:`m2d2m.locks`), having first
    recovered from a build that was killed."""
    out.parent.mkdir(parents=True, exist_ok=True)
    with holding(_sibling(out, "lock"), f"{out}: another `m2d2m data` is writing it; let it finish first"):
        _recover(out)
        yield


def _swap_in(building: Path, out: Path) -> None:
    """Put the complete ``building`` in the place of ``out``: the old directory is renamed aside,
    the new one into place, and the old one's derived sets move over (``_recover`` finishes
    or undoes this after a kill)."""
    previous = _sibling(out, "previous")
    if out.exists():
        os.rename(out, previous)
    os.rename(building, out)
    if previous.exists():
        _retire(previous, out)


def require_replaceable(config: DataConfig, replace_other: bool = False) -> None:
    """Refuse to replace what ``config.out`` holds unless ``replace_other`` says so, when it is a
    dataset built from another raw corpus, or a non-empty directory that is no dataset."""
    out = Path(config.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: not a directory; choose another --out")
    if replace_other or not out.exists() or not any(out.iterdir()):
        return
    raw = config.recorded()["raw"]
    if not (out / MANIFEST).exists():
        raise ValueError(
            f"{out}: not a dataset (no {MANIFEST}); pass --replace to replace it with one built "
            f"from {raw}, or choose another --out"
        )
    other = built_from(out, json.loads((out / MANIFEST).read_text(encoding="utf-8")))
    if other != raw:
        raise ValueError(f"{out}: built from {other}, not {raw}; pass --replace to replace it, or choose another --out")


def _no_statistics(raw: Path, quarantine: list[dict[str, Any]]) -> ValueError:
    """The refusal of a corpus without one usable train motion, with the quarantine's reasons
    (the quarantine file itself goes with the failed build)."""
    reasons = Counter(f"{q['stage']}: {reason_kind(q['reason'])}" for q in quarantine if q["split"] == "train")
    why = ", ".join(f"{count} {reason}" for reason, count in reasons.most_common()) or "no train inputs"
    return ValueError(f"{raw}: no valid training motion to compute statistics from ({why}); nothing was replaced")


def build_dataset(config: DataConfig, replace_other: bool = False) -> dict[str, Any]:
    """Run every stage into a sibling directory and swap it in for ``config.out`` once its
    manifest is written; returns the manifest. A failure removes only the new build. Replacing
    a dataset of another raw corpus needs ``replace_other`` (:func:`require_replaceable`)."""
    out = Path(config.out).resolve()
    with _exclusive(out):
        require_replaceable(config, replace_other)
        building = _sibling(out, f"building-{secrets.token_hex(4)}")
        building.mkdir()
        try:
            manifest = _build(replace(config, out=str(building)))
            _swap_in(building, out)
        except BaseException:
            _recover(out)
            raise
    return manifest


def _build(config: DataConfig) -> dict[str, Any]:
    """Every stage, writing ``config.out`` (a fresh directory); the manifest last."""
    skeleton, raw, out = config.skeleton, Path(config.raw).resolve(), Path(config.out).resolve()
    layout = config.corpus.layout
    rows = layout.list_rows(raw, **config.layout_options)
    make_mirror = not layout.ships_mirrors(rows)
    caption_tagger = None if layout.tagged_captions else prepare_caption_tagger(out, config)

    counts = {split: SplitCounts() for split in SPLITS}
    shards: dict[str, list[dict[str, Any]]] = {split: [] for split in SPLITS}
    moments = RunningMoments(skeleton.feature_dim)
    quarantine: list[dict[str, Any]] = []
    corpus_tagged: list[tuple[str, list[tuple[str, str]]]] = []
    for result in run_shard_tasks(config, plan_shards(rows, config.samples_per_shard, make_mirror), make_mirror):
        split = result["split"]
        counts[split].add(SplitCounts(**result["counts"]))
        shards[split] += result["shards"]
        moments.merge(RunningMoments.from_state(result["moments"]))
        quarantine += result["quarantine"]
        corpus_tagged += [(text, parse_tagged_tokens(" ".join(tokens))) for text, tokens in result["tagged"]]

    with atomic_path(out / QUARANTINE) as partial, partial.open("w", encoding="utf-8") as handle:
        for line in quarantine:
            handle.write(json.dumps(line, sort_keys=True) + "\n")

    provided = _corpus_statistics(raw, skeleton)
    if provided is None and moments.count == 0:
        raise _no_statistics(raw, quarantine)
    mean, std = provided if provided is not None else (moments.mean(), group_averaged_std(moments.std(), skeleton))
    Normalizer(mean, std, config.feat_bias).save(out / STATS)
    tagger = caption_tagger or prepare_tagger(corpus_tagged, out, config)

    manifest = {
        "schema_version": SCHEMA_VERSION,
        "dataset": config.dataset,
        "skeleton": skeleton.name,
        "fps": skeleton.fps,
        "feature_dim": skeleton.feature_dim,
        "joints": skeleton.num_joints,
        "mirrors_made_by_pipeline": make_mirror,
        "stats_source": "corpus Mean.npy/Std.npy" if provided is not None else "train split",
        "tagger": tagger,
        "splits": {
            split: {**asdict(counts[split]), "samples_written": counts[split].samples_written} for split in SPLITS
        },
        "quarantine_reasons": dict(Counter(f"{q['stage']}: {reason_kind(q['reason'])}" for q in quarantine)),
        "shards": shards,
        "corpus": dict(config.corpus.layout.about),
        "config": config.recorded(),
        "code_version": code_version(),
    }
    write_json_atomically(out / MANIFEST, manifest)
    return manifest


def print_summary(manifest: dict[str, Any], out: str | Path) -> None:
    quarantine_path = Path(out) / QUARANTINE
    quarantine = [json.loads(line) for line in quarantine_path.read_text(encoding="utf-8").splitlines()]
    print(stage_counts(manifest))
    print(summary_table(manifest, quarantine))
    for key in ("licence", "attribution"):
        if key in manifest.get("corpus", {}):
            print(f"{key}: {manifest['corpus'][key]}")
