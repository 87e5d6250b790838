"""The processed dataset's contract (docs/data.md, ``data/<name>/``): the sample schema, the
manifest, the summary people read, and the verification ``m2d2m data --check`` runs.

One WebDataset sample per motion: key = motion id (``M<id>`` for mirrors), ``motion.npy`` float32
(T, D) un-normalised features, ``meta.json`` {id, source, fps, frames, mirrored, captions:
[{text, tokens, start, end, actions, verbs}]}.
"""

from __future__ import annotations

import io
import json
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from m2d2m.layout import MANIFEST, QUARANTINE, SHARDS, STATS
from pipelines.corpora import SPLITS
from pipelines.shards import json_bytes, npy_bytes, verify_shards

META_KEYS = {"id", "source", "fps", "frames", "mirrored", "captions"}
CAPTION_KEYS = {"text", "tokens", "start", "end", "actions", "verbs"}


def encode_sample(features: np.ndarray, meta: dict[str, Any]) -> dict[str, bytes]:
    return {"motion.npy": npy_bytes(np.ascontiguousarray(features, dtype=np.float32)), "meta.json": json_bytes(meta)}


def sample_problems(key: str, members: dict[str, bytes], feature_dim: int) -> list[str]:
    """Everything wrong with one encoded sample according to the schema."""
    if set(members) != {"motion.npy", "meta.json"}:
        return [f"members {sorted(members)}, expected ['meta.json', 'motion.npy']"]
    problems = []
    try:
        motion = np.load(io.BytesIO(members["motion.npy"]), allow_pickle=False)
    except ValueError as error:
        return [f"motion.npy unreadable ({error})"]
    if motion.dtype != np.float32 or motion.ndim != 2 or motion.shape[1] != feature_dim:
        problems.append(f"motion.npy is {motion.dtype} {motion.shape}, expected float32 (T, {feature_dim})")
    try:
        meta = json.loads(members["meta.json"])
    except ValueError as error:
        return problems + [f"meta.json unreadable ({error})"]
    if not isinstance(meta, dict) or set(meta) != META_KEYS:
        return problems + [f"meta.json keys {sorted(meta) if isinstance(meta, dict) else type(meta).__name__}"]
    if meta["id"] != key:
        problems.append(f"meta.json id {meta['id']!r} differs from the key")
    if meta["frames"] != len(motion):
        problems.append(f"meta.json frames {meta['frames']} but motion has {len(motion)}")
    if not meta["captions"] or any(set(c) != CAPTION_KEYS for c in meta["captions"]):
        problems.append("captions missing or without the keys " + ", ".join(sorted(CAPTION_KEYS)))
    return problems


def check_dataset(directory: str | Path) -> list[str]:
    """Problems of a processed dataset against its manifest: counts, checksums, schema."""
    directory = Path(directory)
    manifest_path = directory / MANIFEST
    if not manifest_path.exists():
        return [f"{manifest_path}: missing (the dataset is incomplete or was never built)"]
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
        feature_dim = manifest["feature_dim"]
        shards = [s for split in SPLITS for s in manifest["shards"][split]]
    except (ValueError, KeyError) as error:
        return [f"{manifest_path}: unreadable manifest ({error})"]
    problems = verify_shards(
        directory / SHARDS, shards, lambda key, members: sample_problems(key, members, feature_dim)
    )
    for split in SPLITS:
        counts = manifest["splits"][split]
        in_shards = sum(s["samples"] for s in manifest["shards"][split])
        if in_shards != counts["samples_written"]:
            problems.append(f"{split}: shards hold {in_shards} samples, manifest counts {counts['samples_written']}")
        if counts["inputs_seen"] != counts["originals"] + counts["quarantined"]:
            problems.append(
                f"{split}: inputs seen {counts['inputs_seen']} != written {counts['originals']} + quarantined {counts['quarantined']}"
            )
    quarantined = sum(manifest["splits"][s]["quarantined"] for s in SPLITS)
    quarantine_path = directory / QUARANTINE
    lines = quarantine_path.read_text(encoding="utf-8").splitlines() if quarantine_path.exists() else []
    if len(lines) != quarantined:
        problems.append(f"{QUARANTINE}: {len(lines)} lines, manifest counts {quarantined} quarantined")
    stats_path = directory / STATS
    if not stats_path.exists():
        problems.append(f"{STATS}: missing")
    else:
        with np.load(stats_path) as stats:
            if stats["mean"].shape != (feature_dim,) or stats["std"].shape != (feature_dim,):
                problems.append(f"{STATS}: mean/std are not ({feature_dim},)")
    return problems


def reason_kind(reason: str) -> str:
    """The reason without its particulars, for counting: 'too few frames: 10 < 40' → 'too few frames'."""
    return reason.split(":")[0].split(" (")[0]


def stage_counts(manifest: dict[str, Any]) -> str:
    """One line of what each stage passed on or rejected, in stage order."""
    splits = manifest["splits"].values()
    rejected = Counter()
    for key, count in manifest["quarantine_reasons"].items():
        rejected[key.split(":")[0]] += count
    seen = sum(c["inputs_seen"] for c in splits)
    originals, mirrors = sum(c["originals"] for c in splits), sum(c["mirrors"] for c in splits)
    shards = sum(len(v) for v in manifest["shards"].values())
    return (
        f"read {seen} inputs ({rejected['read']} rejected) · validate {rejected['validate']} rejected · "
        f"features {originals} motions + {mirrors} mirrors ({rejected['features']} rejected) · "
        f"language {sum(c['captions'] for c in splits)} captions · write {shards} shards"
    )


def summary_table(manifest: dict[str, Any], quarantine: list[dict[str, Any]]) -> str:
    """Per split: motions, mirrors, frames, hours, captions, single-verb captions, quarantined
    by reason — the table ``m2d2m data`` prints at the end."""
    fps = manifest["fps"]
    header = ["split", "motions", "mirrors", "frames", "hours", "captions", "single-verb", "quarantined"]
    rows = []
    for split in SPLITS:
        c = manifest["splits"][split]
        reasons = Counter(reason_kind(q["reason"]) for q in quarantine if q["split"] == split)
        detail = ", ".join(f"{n} {r}" for r, n in sorted(reasons.items())) or "-"
        rows.append(
            [
                split,
                c["originals"],
                c["mirrors"],
                c["frames"],
                f"{c['frames'] / fps / 3600:.2f}",
                c["captions"],
                c["single_verb_captions"],
                f"{c['quarantined']} ({detail})" if c["quarantined"] else "0",
            ]
        )
    cells = [header] + [[str(v) for v in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    lines = ["  ".join(v.ljust(w) for v, w in zip(row, widths)).rstrip() for row in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)
