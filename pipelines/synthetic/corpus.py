"""The corpus on disk: clips written in parallel (byte-identical whatever the workers), the
splits, annotations and ``corpus.json``."""

from __future__ import annotations

import json
import multiprocessing
import re
from collections import Counter
from collections.abc import Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict
from functools import partial
from pathlib import Path

import numpy as np

from pipelines.synthetic.body import FPS
from pipelines.synthetic.captions import is_multi_verb, make_captions
from pipelines.synthetic.clips import TEXTURE, check_families, make_clip, sample_plan
from pipelines.synthetic.families import FAMILIES
from pipelines.synthetic.words import caption_line, caption_text

GENERATOR_VERSION = "1.1"


SPLITS = {"train": 0.80, "val": 0.05, "test": 0.15}


_ID = re.compile(r"^\d{6}$")


def tagged_captions(count: int, seed: int) -> list[tuple[str, list[tuple[str, str]]]]:
    """``count`` captions of plans drawn as the corpus draws them, with the tags its text files
    carry (HumanML3D's ``word/UPOS``): what a tagger learns from where a corpus's captions come
    untagged. No motion is made, so thousands take a second."""
    rng = np.random.default_rng(seed)
    captions = []
    for _ in range(count):
        tokens = make_captions(sample_plan(rng, FAMILIES), rng, count=1)[0]
        captions.append((caption_text(tokens), [(t.lemma, t.tag) for t in tokens if t.lemma.isalpha()]))
    return captions


def assign_splits(ids: Sequence[str], seed: int) -> dict[str, list[str]]:
    """Deterministic ~80/5/15 split of ``ids`` (each list sorted)."""
    order = np.random.default_rng([seed, 1_000_003]).permutation(len(ids))
    n_val = int(round(SPLITS["val"] * len(ids)))
    n_test = int(round(SPLITS["test"] * len(ids)))
    shuffled = [ids[i] for i in order]
    return {
        "train": sorted(shuffled[n_val + n_test :]),
        "val": sorted(shuffled[:n_val]),
        "test": sorted(shuffled[n_val : n_val + n_test]),
    }


def _write_clip(out: Path, seed: int, families: tuple[str, ...], max_actions: int, index: int) -> tuple[dict, int]:
    """Generate and write one clip; returns its annotation and how many captions are multi-verb."""
    clip = make_clip(index, seed, families, max_actions)
    np.save(out / "joints" / f"{clip.id}.npy", clip.joints)
    lines = "".join(caption_line(c) + "\n" for c in clip.captions)
    (out / "texts" / f"{clip.id}.txt").write_text(lines, encoding="utf-8")
    return clip.annotation(), sum(is_multi_verb(c) for c in clip.captions)


def _remove_stale(out: Path) -> None:
    """Delete clips of an earlier run in the same directory, so the layout matches the splits."""
    for folder, suffix in (("joints", ".npy"), ("texts", ".txt")):
        for path in (out / folder).glob(f"*{suffix}"):
            if _ID.match(path.stem):
                path.unlink()


def existing_corpus(out_dir: str | Path, clips: int, seed: int, families: Sequence[str] | None = None) -> bool:
    """Whether ``out_dir`` already holds exactly this corpus (so generating it again is nothing to
    do); ValueError when it holds a different one, which only an explicit rebuild may replace."""
    marker = Path(out_dir) / "corpus.json"
    if not marker.exists():
        return False
    existing = json.loads(marker.read_text(encoding="utf-8"))
    wanted = {"clips": clips, "seed": seed, "families": list(families or FAMILIES), "version": GENERATOR_VERSION}
    different = [key for key, value in wanted.items() if existing.get(key) != value]
    if not different:
        return True
    raise ValueError(
        f"{out_dir} holds a different corpus ({marker}: other {', '.join(different)}); use another --out or --force"
    )


def generate_corpus(
    out_dir: str | Path,
    clips: int = 2000,
    seed: int = 0,
    families: Sequence[str] | None = None,
    workers: int = 1,
    progress: bool = False,
    max_actions: int = 3,
) -> dict:
    """Write the synthetic corpus (layout in the module docstring) and return its summary:
    clip counts per split, captions, multi-verb caption share, frames, hours, actions per family.

    ``families`` restricts the action families (``FAMILIES`` lists them); ``max_actions=1``
    makes a corpus of single actions. The files depend only on (clips, seed, families,
    max_actions), never on ``workers``.
    """
    families = check_families(families)
    if clips < 1:
        raise ValueError(f"clips must be at least 1, got {clips}")
    if max_actions < 1:
        raise ValueError(f"max_actions must be at least 1, got {max_actions}")
    out = Path(out_dir)
    for folder in ("joints", "texts"):
        (out / folder).mkdir(parents=True, exist_ok=True)
    _remove_stale(out)

    job = partial(_write_clip, out, seed, families, max_actions)
    if workers > 1:
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            results = _progress(pool.map(job, range(clips), chunksize=16), clips, progress)
            results = list(results)
    else:
        results = list(_progress(map(job, range(clips)), clips, progress))

    records = [record for record, _ in results]
    with open(out / "annotations.jsonl", "w", encoding="utf-8") as f:
        for record in records:
            f.write(json.dumps(record, sort_keys=True) + "\n")
    splits = assign_splits([r["id"] for r in records], seed)
    for name, ids in splits.items():
        (out / f"{name}.txt").write_text("".join(i + "\n" for i in ids), encoding="utf-8")

    frames = sum(r["frames"] for r in records)
    captions = sum(len(r["captions"]) for r in records)
    per_family = Counter(a["family"] for r in records for a in r["actions"])
    summary = {
        "clips": clips,
        "splits": {name: len(ids) for name, ids in splits.items()},
        "captions": captions,
        "multi_verb_share": round(sum(n for _, n in results) / captions, 4),
        "frames": frames,
        "hours": round(frames / FPS / 3600.0, 4),
        "families": {f: per_family.get(f, 0) for f in families},
    }
    corpus = {
        "generator": "pipelines.synthetic",
        "version": GENERATOR_VERSION,
        "seed": seed,
        "clips": clips,
        "fps": FPS,
        "families": list(families),
        "max_actions": max_actions,
        "texture": asdict(TEXTURE),
        "summary": summary,
    }
    (out / "corpus.json").write_text(json.dumps(corpus, indent=2) + "\n", encoding="utf-8")
    return summary


def _progress(results: Iterable, total: int, enabled: bool) -> Iterable:
    if not enabled:
        return results
    from m2d2m.progress import progress

    return progress(results, total=total, desc="synthetic corpus", unit="clip")
