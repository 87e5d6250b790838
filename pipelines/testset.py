"""The N-action test set of M2D2M's multi-motion evaluation (paper §5.2 and Appendix B).

What the paper says: the test set is built from the test split's captions that contain exactly
one action verb ("each sentence includes only one action verb"); "N action descriptions" are
drawn at random from this pool, "ensuring no overlap"; for N = 4 HumanML3D gives "1,448 test
instances" (§5.2) or "1448 motions, each associated with a single-verb annotation" (App. B), and
KIT-ML 532. No code was released. The reading implemented here, and why:

* **Single-verb caption** = exactly one token tagged ``VERB`` in the caption's own tagged tokens
  (``word/UPOS``, the corpus's spaCy tags — what the authors had), *and* the caption's
  verb decomposition agrees: exactly one entry in ``verbs``, the same lemma, and one action
  sentence. The tag count is the literal reading of "one action verb" and is independent of this
  project's decomposition heuristics; the agreement check keeps out the cases where the two
  disagree ("starts to walk": two tags, one action; "turns left" with ``left/VERB``; a verb used
  as a noun), which are ambiguous about how many actions the motion shows. Disagreements are
  dropped and counted in the manifest (``pool.disagreements``). The item's condition is that
  caption's single action sentence (``actions[0]``), its verb ``verbs[0]``.
* **Pool** = one entry per single-verb caption of a clip of the split whose frame span is usable:
  ``start``/``end`` seconds cut frames ``[int(start·fps), int(end·fps))`` (HumanML3D's and
  T2M-GPT's rule, clipped to the clip; both 0 = the whole clip); a span that is empty or shorter
  than ``min_frames`` (HumanML3D's loader minimum, 40 frames by default: the dataset's own lower
  frame bound) is dropped and counted (``pool.too_short``).
* **No overlap** = no motion is used twice in a test set: every instance is made of captions of N
  distinct motions, and a motion appears in at most one instance. A mirror is the same motion
  mirrored, so by default (``mirrors="same"``) it counts as its original: a pipeline-made mirror
  says so in its meta (``mirrored: true``, ``source`` = the original id); a corpus-shipped one
  (HumanML3D's ``M<id>`` listed beside ``<id>``) is recognised by its key, the rule of
  :func:`pipelines.corpora.corpus_ships_mirrors`. Mirror captions stay in the pool (a mirrored
  motion with its left/right-swapped caption is a valid item), they only share their original's
  motion slot. ``mirrors="distinct"`` treats every id as its own motion (HumanML3D's split files
  list mirrors as ids of their own), ``mirrors="exclude"`` keeps originals only.
* **Drawing** (``numpy.random.default_rng(seed)``): shuffle the distinct motions, pick one of each
  motion's single-verb captions at random, and cut the sequence of picks into instances of N in
  order (an instance's order is its action order), dropping the remainder. So
  ``instances = floor(distinct usable motions / N)``.

Why this reading of 1,448 / 532: both are multiples of 4 (362 × 4, 133 × 4), as the number of
*motions* used by an N = 4 test set without re-use must be, and App. B calls them motions. They
cannot both be instance counts of disjoint groups of 4 captions (KIT-ML's test split has about
1,560 captions, fewer than 532 × 4, by the split files of EricGuo5513/HumanML3D's KIT-ML release). The paper's counts exceed
what a mirror-as-same-motion rule allows on KIT-ML (its test split has fewer than 400 original
clips), so they were most likely taken over ids with mirrors counted apart
(``mirrors="distinct"``); the default here is the stricter rule (a motion and its mirror are
never both in a test set), which the paper's "no overlap" also allows.

On disk: ``data/<name>/testsets/n<N>-seed<S>/`` (written to a temporary directory, then renamed):
``instances.jsonl`` (one instance per line: index and the N items with key, motion, caption,
action, verb, first / end frame, length), ``motions.npz`` (each item's ground-truth feature
segment, float32 (length, D), un-normalised like the shards, named ``i<index>_p<position>``, so
evaluation needs no shard access), and ``manifest.json`` (parameters, pool and instance counts,
the source dataset's manifest checksum, the files' sha256), written last.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import tarfile
import tempfile
import zipfile
from collections import Counter, defaultdict
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import m2d2m
from m2d2m.layout import MANIFEST, read_manifest, recorded_path, relative_to_project, shard_urls
from m2d2m.locks import holding
from pipelines.shards import json_bytes, npy_bytes, sha256_of, write_json_atomically

TESTSETS = "testsets"
INSTANCES = "instances.jsonl"
MOTIONS = "motions.npz"
KIND = "testset"
SCHEMA_VERSION = 1
MIRROR_RULES = ("same", "distinct", "exclude")
DEFAULT_MIN_FRAMES = 40  # HumanML3D's loader keeps 40 <= T < 200
_ZIP_TIME = (1980, 1, 1, 0, 0, 0)  # fixed member timestamps: the same arrays give the same bytes


@dataclass(frozen=True)
class PoolEntry:
    """One single-verb caption of a clip, with the frames [first, end) it describes."""

    key: str  # the shard sample key (``M<id>`` for a mirror)
    motion: str  # the motion it counts as for the no-overlap rule
    caption_index: int  # its position among the clip's captions
    caption: str
    action: str
    verb: str
    first: int
    end: int  # exclusive

    @property
    def length(self) -> int:
        return self.end - self.first


@dataclass
class PoolCounts:
    """What the pool scan saw (kept in the manifest)."""

    clips: int = 0
    captions: int = 0
    one_verb_tag: int = 0
    disagreements: int = 0  # one VERB tag but the decomposition says otherwise, or vice versa
    too_short: int = 0  # single-verb captions whose span is empty or shorter than min_frames
    mirrors_excluded: int = 0


# -------------------------------------------------------------------------------------- the pool


def verb_tags(tokens: list[str]) -> list[str]:
    """The words tagged ``VERB`` in a caption's ``word/UPOS`` tokens."""
    words = []
    for token in tokens:
        word, _, pos = token.rpartition("/")
        if pos == "VERB":
            words.append(word)
    return words


def frame_span(caption: dict[str, Any], frames: int, fps: float) -> tuple[int, int] | None:
    """The frames [first, end) a caption describes: ``int(second · fps)`` of its start/end (both 0
    = the whole clip), clipped to the clip; None when nothing is left."""
    start, end = float(caption["start"]), float(caption["end"])
    if start == 0 and end == 0:
        return 0, frames
    if end <= start:
        return None
    first, last = int(start * fps), min(int(end * fps), frames)
    return (first, last) if first < last else None


def _iter_members(url: str, suffix: str) -> Iterator[tuple[str, bytes]]:
    """(key, bytes) of one member kind of a shard, without reading the others."""
    with tarfile.open(url, "r") as tar:
        for info in tar:
            if info.isfile():
                key, _, member = Path(info.name).name.partition(".")
                if member == suffix:
                    yield key, tar.extractfile(info).read()


def split_metas(data_dir: Path, split: str) -> list[dict[str, Any]]:
    return [json.loads(raw) for url in shard_urls(data_dir, split) for _, raw in _iter_members(url, "meta.json")]


def _motion_of(meta: dict[str, Any], keys: set[str], mirrors: str) -> str | None:
    """The motion a clip counts as (None: excluded), see the module docstring."""
    key = meta["id"]
    if meta.get("mirrored"):
        original = meta.get("source") or key[1:]
    elif key.startswith("M") and key[1:] in keys:
        original = key[1:]
    else:
        return key
    if mirrors == "exclude":
        return None
    return key if mirrors == "distinct" else original


def _resolve_min_frames(data_dir: Path, min_frames: int | None) -> int:
    if min_frames is not None:
        return int(min_frames)
    return int(read_manifest(data_dir).get("config", {}).get("min_frames", DEFAULT_MIN_FRAMES))


def _scan_pool(data_dir: Path, split: str, min_frames: int, mirrors: str) -> tuple[list[PoolEntry], PoolCounts]:
    if mirrors not in MIRROR_RULES:
        raise ValueError(f"mirrors must be one of {', '.join(MIRROR_RULES)}, got {mirrors!r}")
    metas = split_metas(data_dir, split)
    keys = {meta["id"] for meta in metas}
    counts = PoolCounts(clips=len(metas))
    pool = []
    for meta in metas:
        motion = _motion_of(meta, keys, mirrors)
        for index, caption in enumerate(meta["captions"]):
            counts.captions += 1
            tagged = verb_tags(caption["tokens"])
            agrees = list(caption["verbs"]) == tagged and len(caption["actions"]) == 1
            counts.one_verb_tag += len(tagged) == 1
            if len(tagged) != 1 and len(caption["verbs"]) != 1:
                continue
            if len(tagged) != 1 or not agrees:
                counts.disagreements += 1
                continue
            span = frame_span(caption, meta["frames"], meta["fps"])
            if span is None or span[1] - span[0] < min_frames:
                counts.too_short += 1
                continue
            if motion is None:
                counts.mirrors_excluded += 1
                continue
            pool.append(
                PoolEntry(meta["id"], motion, index, caption["text"], caption["actions"][0], caption["verbs"][0], *span)
            )
    pool.sort(key=lambda e: (e.motion, e.key, e.caption_index))
    return pool, counts


def single_verb_pool(
    data_dir: str | Path, split: str = "test", min_frames: int | None = None, mirrors: str = "same"
) -> list[PoolEntry]:
    """Every single-verb caption of the split's clips with a usable span, sorted by motion, key
    and caption index (the order never depends on shard layout). ``min_frames`` None = the
    dataset's own lower frame bound (its manifest's config), else 40."""
    data_dir = Path(data_dir)
    return _scan_pool(data_dir, split, _resolve_min_frames(data_dir, min_frames), mirrors)[0]


# ---------------------------------------------------------------------------------- the drawing


def draw_instances(pool: list[PoolEntry], n: int, seed: int) -> list[list[PoolEntry]]:
    """Shuffle the distinct motions, pick one caption of each at random, cut into groups of ``n``
    (the remainder is dropped): no motion appears twice."""
    if n < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    by_motion: dict[str, list[PoolEntry]] = defaultdict(list)
    for entry in pool:
        by_motion[entry.motion].append(entry)
    motions = sorted(by_motion)
    rng = np.random.default_rng(seed)
    picks = []
    for position in rng.permutation(len(motions)):
        choices = by_motion[motions[position]]
        picks.append(choices[int(rng.integers(len(choices)))])
    return [picks[i : i + n] for i in range(0, len(picks) - n + 1, n)]


def item_name(instance: int, position: int) -> str:
    """The name of an item's ground-truth segment in ``motions.npz``."""
    return f"i{instance:05d}_p{position}"


def _item_record(entry: PoolEntry) -> dict[str, Any]:
    return {
        "key": entry.key,
        "motion": entry.motion,
        "caption_index": entry.caption_index,
        "caption": entry.caption,
        "action": entry.action,
        "verb": entry.verb,
        "first": entry.first,
        "end": entry.end,
        "length": entry.length,
    }


def _write_npz(path: Path, arrays: list[tuple[str, np.ndarray]]) -> None:
    """An ``.npz`` (readable by ``np.load``) with fixed member timestamps: ``np.savez`` stamps
    the current time, so the same arrays would not give the same bytes."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED) as archive:
        for name, array in arrays:
            archive.writestr(zipfile.ZipInfo(f"{name}.npy", date_time=_ZIP_TIME), npy_bytes(array))


def _file_record(path: Path) -> dict[str, Any]:
    return {"bytes": path.stat().st_size, "sha256": sha256_of(path)}


def _parameters(
    data_dir: Path, n: int, seed: int, split: str, min_frames: int, mirrors: str, limit: int | None
) -> dict[str, Any]:
    source = data_dir / MANIFEST
    return {
        "n": n,
        "seed": seed,
        "split": split,
        "min_frames": min_frames,
        "mirrors": mirrors,
        "limit": limit,
        "source": {"dir": relative_to_project(data_dir), "manifest_sha256": sha256_of(source)},
    }


def _same_parameters(manifest: dict[str, Any], parameters: dict[str, Any]) -> bool:
    """Drawn alike from the same dataset build: the source is known by its manifest's checksum,
    wherever the project, and so the dataset, is now."""
    checksum = parameters["source"]["manifest_sha256"]
    return manifest.get("source", {}).get("manifest_sha256") == checksum and all(
        manifest.get(name) == value for name, value in parameters.items() if name != "source"
    )


def source_dir(path: str | Path, manifest: dict[str, Any]) -> Path | None:
    """Where the source dataset of the test set at ``path`` is, as its manifest names it (None when it does not)."""
    recorded = manifest.get("source", {}).get("dir")
    return recorded_path(recorded, path) if recorded else None


def testset_dir(
    data_dir: str | Path,
    n: int,
    seed: int,
    out: str | Path | None = None,
    limit: int | None = None,
    mirrors: str = "same",
    split: str = "test",
) -> Path:
    """Where ``build_testset`` writes: ``<out or data_dir/testsets>/n<N>-seed<S>[-<mirrors>][-first<L>][-<split>]``,
    the mirror rule and the split named unless they are the defaults, so test sets drawn by other
    rules or from another split never collide."""
    name = (
        f"n{n}-seed{seed}"
        + (f"-{mirrors}" if mirrors != "same" else "")
        + (f"-first{limit}" if limit is not None else "")
        + (f"-{split}" if split != "test" else "")
    )
    return Path(out if out is not None else Path(data_dir) / TESTSETS) / name


def build_testset(
    data_dir: str | Path,
    n: int = 4,
    seed: int = 0,
    out: str | Path | None = None,
    min_frames: int | None = None,
    split: str = "test",
    mirrors: str = "same",
    force: bool = False,
    limit: int | None = None,
) -> dict[str, Any]:
    """Build (or reuse) the N-action test set of a processed dataset; returns its manifest plus
    ``path`` and ``reused``. An existing test set with the same parameters (and source dataset
    checksum) is reused when it checks clean; one with other parameters, or damaged, is an error
    unless ``force`` replaces it. ``limit`` keeps only the first instances of the seed's draw: a
    quick-look subset for sweeps, never the paper's table. ``split="val"`` draws the same kind of
    set from the validation clips, where sampling settings are chosen without seeing the test set."""
    data_dir = Path(data_dir).resolve()
    min_frames = _resolve_min_frames(data_dir, min_frames)
    if mirrors not in MIRROR_RULES:
        raise ValueError(f"mirrors must be one of {', '.join(MIRROR_RULES)}, got {mirrors!r}")
    if n < 1:
        raise ValueError(f"n must be at least 1, got {n}")
    if limit is not None and limit < 2:
        raise ValueError(f"limit must be at least 2 instances, got {limit}")
    splits = read_manifest(data_dir)["shards"]
    if split not in splits:
        raise ValueError(f"{data_dir}: no {split!r} split; the dataset has {', '.join(splits)}")
    shard_urls(data_dir, split)  # a damaged dataset is refused before anything is written
    target = testset_dir(data_dir, n, seed, out, limit, mirrors, split).resolve()
    parameters = _parameters(data_dir, n, seed, split, min_frames, mirrors, limit)
    target.parent.mkdir(parents=True, exist_ok=True)
    # two commands building one test set (two evaluations of a new dataset): the later waits
    # seconds, then reuses what the first wrote
    with holding(target.parent / f".{target.name}.lock", f"{target}: another command is writing it", wait=True):
        _remove_leftovers(target)
        return _reuse_or_build(data_dir, target, parameters, force)


def _reuse_or_build(data_dir: Path, target: Path, parameters: dict[str, Any], force: bool) -> dict[str, Any]:
    """:func:`build_testset`'s work, with ``target`` held."""
    n, seed, split, limit = parameters["n"], parameters["seed"], parameters["split"], parameters["limit"]
    min_frames, mirrors = parameters["min_frames"], parameters["mirrors"]
    if (target / MANIFEST).exists() and not force:
        existing = json.loads((target / MANIFEST).read_text(encoding="utf-8"))
        if not _same_parameters(existing, parameters):
            raise FileExistsError(
                f"{target}: a test set built with other parameters or from another version "
                "of the dataset is there; pass force=True (--force) to replace it"
            )
        problems = check_testset(target)
        if problems:
            raise FileExistsError(
                f"{target}: the existing test set is damaged ({problems[0]}); pass force=True (--force) to rebuild it"
            )
        return {**existing, "path": str(target), "reused": True}

    source_manifest = read_manifest(data_dir)
    pool, counts = _scan_pool(data_dir, split, min_frames, mirrors)
    instances = draw_instances(pool, n, seed)[:limit]
    if not instances:
        raise ValueError(
            f"{data_dir}: only {len({e.motion for e in pool})} distinct {split} motions have a "
            f"usable single-verb caption, fewer than n = {n}"
        )
    wanted = {entry.key for group in instances for entry in group}
    features: dict[str, np.ndarray] = {}
    for url in shard_urls(data_dir, split):
        for key, raw in _iter_members(url, "motion.npy"):
            if key in wanted:
                features[key] = np.load(io.BytesIO(raw), allow_pickle=False)

    staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".partial", dir=target.parent))
    try:
        lines = [
            json_bytes({"index": index, "items": [_item_record(e) for e in group]}) + b"\n"
            for index, group in enumerate(instances)
        ]
        (staging / INSTANCES).write_bytes(b"".join(lines))
        _write_npz(
            staging / MOTIONS,
            [
                (item_name(index, position), np.ascontiguousarray(features[e.key][e.first : e.end], dtype=np.float32))
                for index, group in enumerate(instances)
                for position, e in enumerate(group)
            ],
        )
        manifest = {
            "kind": KIND,
            "schema_version": SCHEMA_VERSION,
            **parameters,
            "dataset": source_manifest.get("dataset"),
            "fps": source_manifest.get("fps"),
            "feature_dim": source_manifest.get("feature_dim"),
            "rule": "exactly one VERB tag in the caption's tokens, agreeing with its decomposition "
            "(one verb, the same lemma, one action sentence); span >= min_frames; "
            f"no motion twice (mirrors: {mirrors})",
            "pool": {
                **asdict(counts),
                "entries": len(pool),
                "keys": len({e.key for e in pool}),
                "motions": len({e.motion for e in pool}),
            },
            "instances": len(instances),
            "items": len(instances) * n,
            "verbs": dict(sorted(Counter(e.verb for g in instances for e in g).items())),
            "files": {INSTANCES: _file_record(staging / INSTANCES), MOTIONS: _file_record(staging / MOTIONS)},
            "code_version": m2d2m.__version__,
        }
        write_json_atomically(staging / MANIFEST, manifest)
        os.chmod(staging, 0o755)
        _replace_dir(staging, target)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return {**manifest, "path": str(target), "reused": False}


def _remove_leftovers(target: Path) -> None:
    """What a killed build of ``target`` left beside it (its lock held, so no build is under
    way): a half-written ``.partial`` folder, or the old test set a ``--force`` had moved
    aside, put back when the kill came before the new one was in place."""
    for leftover in sorted(target.parent.glob(f".{target.name}.*.old")):
        if not target.exists() and (leftover / target.name).is_dir():
            os.replace(leftover / target.name, target)
        shutil.rmtree(leftover, ignore_errors=True)
    for leftover in target.parent.glob(f".{target.name}.*.partial"):
        shutil.rmtree(leftover, ignore_errors=True)


def _replace_dir(staging: Path, target: Path) -> None:
    """Rename ``staging`` to ``target``; an existing ``target`` is moved aside first and removed
    after, so a reader sees either the old or the new complete directory."""
    if not target.exists():
        os.replace(staging, target)
        return
    old = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".old", dir=target.parent))
    os.replace(target, old / target.name)
    os.replace(staging, target)
    shutil.rmtree(old, ignore_errors=True)


# ----------------------------------------------------------------------------------- reading


@dataclass(frozen=True)
class TestItem:
    key: str
    motion: str
    caption_index: int
    caption: str
    action: str
    verb: str
    first: int
    end: int
    length: int


@dataclass(frozen=True)
class TestInstance:
    index: int
    items: tuple[TestItem, ...]

    @property
    def actions(self) -> list[str]:
        """The action sentences, in order: the N conditions of a multi-action generation."""
        return [item.action for item in self.items]

    @property
    def lengths(self) -> list[int]:
        """The ground-truth length in frames of each action."""
        return [item.length for item in self.items]


@dataclass
class TestSet:
    """A test set read back: its manifest, its instances, and the ground-truth segments."""

    path: Path
    manifest: dict[str, Any]
    instances: list[TestInstance]
    _npz: Any = field(default=None, repr=False)

    __test__ = False  # not a pytest class

    @property
    def n(self) -> int:
        return int(self.manifest["n"])

    def __len__(self) -> int:
        return len(self.instances)

    def __iter__(self) -> Iterator[TestInstance]:
        return iter(self.instances)

    def features(self, instance: int, position: int) -> np.ndarray:
        """The ground-truth features (length, D) float32, un-normalised, of one item."""
        if self._npz is None:
            self._npz = np.load(self.path / MOTIONS, allow_pickle=False)
        return self._npz[item_name(instance, position)]

    def close(self) -> None:
        if self._npz is not None:
            self._npz.close()
            self._npz = None

    def __enter__(self) -> TestSet:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


TestItem.__test__ = False  # type: ignore[attr-defined]
TestInstance.__test__ = False  # type: ignore[attr-defined]


def load_testset(path: str | Path) -> TestSet:
    """Read a test set directory (its manifest must exist: a directory without one is incomplete)."""
    path = Path(path)
    manifest = read_manifest(path)
    if manifest.get("kind") != KIND:
        raise ValueError(f"{path}: not a test set (manifest kind {manifest.get('kind')!r})")
    instances = []
    for line in (path / INSTANCES).read_text(encoding="utf-8").splitlines():
        record = json.loads(line)
        instances.append(TestInstance(record["index"], tuple(TestItem(**item) for item in record["items"])))
    return TestSet(path, manifest, instances)


def check_testset(path: str | Path) -> list[str]:
    """Problems of a test set against its manifest: missing files, checksums, instance and item
    counts, re-used motions, spans, the ground-truth arrays; and whether its source dataset, when
    present, has changed since."""
    path = Path(path)
    manifest_path = path / MANIFEST
    if not manifest_path.exists():
        return [f"{manifest_path}: missing (the test set is incomplete or was never built)"]
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
        n, expected, files = int(manifest["n"]), int(manifest["instances"]), manifest["files"]
        min_frames, feature_dim = int(manifest["min_frames"]), manifest.get("feature_dim")
    except (ValueError, KeyError, TypeError) as error:
        return [f"{manifest_path}: unreadable manifest ({error})"]
    problems = []
    for name in (INSTANCES, MOTIONS):
        file = path / name
        if name not in files:
            problems.append(f"{name}: not in the manifest")
        elif not file.exists():
            problems.append(f"{name}: missing")
        elif sha256_of(file) != files[name]["sha256"]:
            problems.append(f"{name}: sha256 differs from the manifest")
    names: dict[str, int] = {}
    if (path / INSTANCES).exists():
        try:
            records = [json.loads(line) for line in (path / INSTANCES).read_text(encoding="utf-8").splitlines()]
        except (ValueError, UnicodeDecodeError) as error:
            records = []
            problems.append(f"{INSTANCES}: unreadable ({error})")
        if len(records) != expected:
            problems.append(f"{INSTANCES}: {len(records)} instances, manifest says {expected}")
        seen: Counter[str] = Counter()
        for number, record in enumerate(records):
            try:
                if record["index"] != number:
                    problems.append(f"{INSTANCES}: line {number + 1} has index {record['index']}")
                if len(record["items"]) != n:
                    problems.append(f"{INSTANCES}: instance {number} has {len(record['items'])} items, n = {n}")
                for position, item in enumerate(record["items"]):
                    seen[item["motion"]] += 1
                    if item["end"] - item["first"] != item["length"] or item["length"] < min_frames:
                        problems.append(
                            f"{INSTANCES}: instance {number} item {position}: span "
                            f"[{item['first']}, {item['end']}) length {item['length']} (min {min_frames})"
                        )
                    names[item_name(number, position)] = item["length"]
            except (KeyError, TypeError) as error:
                problems.append(f"{INSTANCES}: instance {number} malformed ({error})")
        reused = sorted(m for m, count in seen.items() if count > 1)
        if reused:
            problems.append(f"{INSTANCES}: motions used more than once: {', '.join(reused[:5])}")
    if (path / MOTIONS).exists():
        try:
            with np.load(path / MOTIONS, allow_pickle=False) as arrays:
                stored = set(arrays.files)
                if names and stored != set(names):
                    problems.append(
                        f"{MOTIONS}: {len(stored)} arrays, {len(names)} items "
                        f"({len(stored - set(names))} extra, {len(set(names) - stored)} missing)"
                    )
                for name in sorted(stored & set(names)):
                    array = arrays[name]
                    if (
                        array.dtype != np.float32
                        or array.ndim != 2
                        or len(array) != names[name]
                        or (feature_dim is not None and array.shape[1] != feature_dim)
                    ):
                        problems.append(
                            f"{MOTIONS}: {name} is {array.dtype} {array.shape}, expected float32 "
                            f"({names[name]}, {feature_dim})"
                        )
        except (OSError, ValueError, zipfile.BadZipFile) as error:
            problems.append(f"{MOTIONS}: unreadable ({error})")
    source = source_dir(path, manifest)
    if source is not None and (source / MANIFEST).exists():
        if sha256_of(source / MANIFEST) != manifest["source"]["manifest_sha256"]:
            problems.append(f"source dataset {source} changed since the test set was built (rebuild it)")
    return problems


def describe(summary: dict[str, Any]) -> str:
    """One line for people: where, how many instances, from what pool."""
    pool = summary["pool"]
    return (
        f"{summary['path']}: {summary['instances']} instances of {summary['n']} actions "
        f"({'reused' if summary.get('reused') else 'built'}; seed {summary['seed']}) from {pool['entries']} "
        f"single-verb {summary['split']} captions of {pool['motions']} motions ({pool['keys']} clips, "
        f"mirrors {summary['mirrors']}); {pool['disagreements']} tag/decomposition disagreements and "
        f"{pool['too_short']} spans < {summary['min_frames']} frames dropped"
    )
