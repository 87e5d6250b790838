"""The Ray Data job behind ``m2d2m tokenize``: a processed dataset and a VQ model file in,
``data/<name>/tokens/<vq-run-id>/`` out.

Each motion shard is one task that encodes its motions, in order, into the token shard of the
same name (or, with ``samples_per_shard``, into consecutively numbered smaller ones), so token
and motion samples match one to one and the counts can be checked shard by shard. The VQ model
file travels with the tokens (``vq.pt``: the denoiser builds its transitions from the codebook,
generation decodes tokens with the decoder, both normalise with its statistics), together with
``codebook.npy`` for inspection and the dataset's ``stats.npz``. The manifest, written last,
records the dataset's shard checksums and the VQ file's sha256, so a token set made from another
dataset build or another model is recognised as stale.
"""

from __future__ import annotations

import functools
import io
import json
import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import torch

from m2d2m.layout import (
    MANIFEST,
    STATS,
    TOKENS_KIND,
    VQ_FILE,
    read_manifest,
    recorded_path,
    relative_to_project,
    shard_urls,
    token_shard_urls,
)
from m2d2m.locks import holding
from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.networks.vqvae import MotionVQVAE, load_vq
from pipelines.corpora import SPLITS
from pipelines.shards import (
    PARTIAL_SUFFIX,
    SCHEMA_VERSION,
    ShardWriter,
    iter_tar_samples,
    npy_bytes,
    sha256_of,
    shard_records,
    verify_shards,
    write_json_atomically,
)

CODEBOOK = "codebook.npy"
TOKEN_MEMBERS = {"tokens.npy", "meta.json"}
MAX_CODEBOOK_SIZE = 2**15  # tokens are stored as int16


def _source_shards(dataset_manifest: dict[str, Any]) -> dict[str, list[dict[str, str]]]:
    """The identity of a dataset build: every motion shard's name and checksum, per split."""
    return {
        split: [{"name": s["name"], "sha256": s["sha256"]} for s in dataset_manifest["shards"][split]]
        for split in SPLITS
    }


def _require_vq_file(vq_path: Path) -> None:
    if not vq_path.is_file():
        raise FileNotFoundError(f"{vq_path}: no VQ model file; train one with `m2d2m train-vq` or pass --vq")


def current_tokens(
    data_dir: str | Path, vq_path: str | Path, out_dir: str | Path, samples_per_shard: int | None = None
) -> dict[str, Any] | None:
    """The manifest of ``out_dir`` when it holds the tokens of exactly this dataset build and
    this VQ file (same shard checksums, same sha256, same sharding) and its token shards still
    match it, else None: a damaged token set is made again rather than read."""
    manifest_path = Path(out_dir) / MANIFEST
    if not manifest_path.exists():
        return None
    vq_path = Path(vq_path)
    _require_vq_file(vq_path)
    existing = json.loads(manifest_path.read_text(encoding="utf-8"))
    wanted = {
        "kind": TOKENS_KIND,
        "source_shards": _source_shards(read_manifest(data_dir)),
        "vq_sha256": sha256_of(vq_path),
        "samples_per_shard": samples_per_shard,
    }
    if any(existing.get(key) != value for key, value in wanted.items()):
        return None
    try:
        for split in SPLITS:
            token_shard_urls(out_dir, split)
    except (FileNotFoundError, ValueError):
        return None
    return existing


def plan_token_shards(
    data_dir: Path, dataset_manifest: dict[str, Any], samples_per_shard: int | None
) -> list[dict[str, Any]]:
    """One task per motion shard, in split and shard order. Each task owns the range of token
    shard numbers its samples fill, so with ``samples_per_shard=None`` the token shard has the
    motion shard's name, and otherwise a split's tokens stay in the motion order. The motion
    shards are checked against the dataset's manifest first (``m2d2m.layout.shard_urls``)."""
    tasks = []
    for split in SPLITS:
        first_index = 0
        for shard, source in zip(dataset_manifest["shards"][split], shard_urls(data_dir, split)):
            per_shard = samples_per_shard or shard["samples"]
            tasks.append({"split": split, "index": first_index, "source": source, "samples_per_shard": per_shard})
            first_index += math.ceil(shard["samples"] / per_shard)
    return tasks


@functools.lru_cache(maxsize=1)
def _cached_vq(path: str, sha256: str) -> tuple[MotionVQVAE, Normalizer]:
    """The model, loaded once per Ray worker process rather than once per shard; keyed by the
    file's checksum so that a rebuild with another model in the same directory reloads it."""
    model, normalizer, _ = load_vq(path)
    return model, normalizer


def encode_motion(model: MotionVQVAE, normalizer: Normalizer, motion: np.ndarray) -> np.ndarray:
    """Tokens (ceil(T / frames_per_token),) int16 of one un-normalised motion (T, D), encoded
    alone at its full length, as the denoiser will see it."""
    features = torch.from_numpy(normalizer.normalize(np.asarray(motion, dtype=np.float32)))
    with torch.no_grad():
        return model.encode(features[None])[0].numpy().astype(np.int16)


def encode_shard(task: dict[str, Any], out_dir: str, vq_path: str, vq_sha256: str) -> dict[str, Any]:
    """Encode one motion shard into token shards (a Ray task); returns their records and counts.
    One torch thread: parallelism comes from running one task per CPU."""
    torch.set_num_threads(1)
    model, normalizer = _cached_vq(vq_path, vq_sha256)
    samples = tokens = 0
    writer = ShardWriter(out_dir, task["split"], task["samples_per_shard"], first_index=task["index"])
    with writer:
        for key, members in iter_tar_samples(task["source"]):
            codes = encode_motion(model, normalizer, np.load(io.BytesIO(members["motion.npy"]), allow_pickle=False))
            writer.write(key, {"tokens.npy": npy_bytes(codes), "meta.json": members["meta.json"]})
            samples += 1
            tokens += len(codes)
    source = Path(task["source"]).name
    return {
        "split": task["split"],
        "samples": samples,
        "tokens": tokens,
        "shards": [{**record, "source": source} for record in shard_records(writer.shards)],
    }


def _clear(out_dir: Path) -> None:
    """Remove a previous token set's files (manifest first: the directory is invalid from then on)."""
    (out_dir / MANIFEST).unlink(missing_ok=True)
    for pattern in ("*.tar", f"*{PARTIAL_SUFFIX}", VQ_FILE, CODEBOOK, STATS):
        for path in out_dir.glob(pattern):
            path.unlink()


def tokenize_dataset(
    data_dir: str | Path,
    vq_path: str | Path,
    out_dir: str | Path,
    workers: int = 2,
    ray_address: str | None = None,
    samples_per_shard: int | None = None,
) -> dict[str, Any]:
    """Encode every motion of every split of ``data_dir`` with the VQ model file ``vq_path`` into
    token shards in ``out_dir`` (one token shard per motion shard unless ``samples_per_shard`` caps
    them); returns the manifest. A complete token set of the same dataset build and VQ file is
    reused as it is (see :func:`current_tokens`)."""
    data_dir, vq_path, out_dir = Path(data_dir).resolve(), Path(vq_path).resolve(), Path(out_dir).resolve()
    dataset_manifest = read_manifest(data_dir)
    _require_vq_file(vq_path)
    if samples_per_shard is not None and samples_per_shard <= 0:
        raise ValueError(f"samples_per_shard must be positive, got {samples_per_shard}")
    existing = current_tokens(data_dir, vq_path, out_dir, samples_per_shard)
    if existing is not None:
        return existing

    # one writer of a token set at a time: a second tokenize (or a training tokenizing first)
    # refuses in one line instead of clearing the shards the first one is writing
    busy = f"{out_dir}: another command is writing these tokens; let it finish, then run this again"
    with holding(out_dir.parent / f".{out_dir.name}.lock", busy):
        if (finished := current_tokens(data_dir, vq_path, out_dir, samples_per_shard)) is not None:
            return finished  # written by a command that finished since the check above
        model, _, _ = load_vq(vq_path)
        config = model.config
        if config.feature_dim != dataset_manifest["feature_dim"]:
            raise ValueError(
                f"{vq_path}: the VQ-VAE encodes {config.feature_dim}-d features but {data_dir} holds "
                f"{dataset_manifest['feature_dim']}-d ones; train one on this dataset with `m2d2m train-vq`"
            )
        if config.codebook_size > MAX_CODEBOOK_SIZE:
            raise ValueError(
                f"{vq_path}: {config.codebook_size} codes do not fit int16 tokens (at most {MAX_CODEBOOK_SIZE})"
            )

        # pipelines.features brings spaCy: imported where tokens are made, so that a training on
        # current tokens, which checks them here, runs where spaCy is not installed (bench/gpu_carry.py)
        from pipelines.features import code_version, run_json_tasks

        tasks = plan_token_shards(data_dir, dataset_manifest, samples_per_shard)  # before anything is removed
        out_dir.mkdir(parents=True, exist_ok=True)
        _clear(out_dir)
        # Plain copies: nothing in out_dir is trusted before the manifest lands.
        shutil.copyfile(vq_path, out_dir / VQ_FILE)
        shutil.copyfile(data_dir / STATS, out_dir / STATS)
        np.save(out_dir / CODEBOOK, model.codebook.detach().cpu().numpy().astype(np.float32))
        vq_sha256 = sha256_of(out_dir / VQ_FILE)

        results = run_json_tasks(
            encode_shard,
            tasks,
            workers,
            ray_address,
            out_dir=str(out_dir),
            vq_path=str(out_dir / VQ_FILE),
            vq_sha256=vq_sha256,
        )
        splits = {split: {"samples": 0, "tokens": 0} for split in SPLITS}
        shards: dict[str, list[dict[str, Any]]] = {split: [] for split in SPLITS}
        for result in results:
            splits[result["split"]]["samples"] += result["samples"]
            splits[result["split"]]["tokens"] += result["tokens"]
            shards[result["split"]] += result["shards"]

        manifest = {
            "schema_version": SCHEMA_VERSION,
            "kind": TOKENS_KIND,
            "dataset": dataset_manifest["dataset"],
            "source_dir": relative_to_project(data_dir),
            "source_shards": _source_shards(dataset_manifest),
            "vq_file": VQ_FILE,
            "vq_source": relative_to_project(vq_path),
            "vq_sha256": vq_sha256,
            "feature_dim": config.feature_dim,
            "codebook_size": config.codebook_size,
            "code_dim": config.code_dim,
            "frames_per_token": model.frames_per_token,
            "samples_per_shard": samples_per_shard,
            "splits": splits,
            "shards": shards,
            "code_version": code_version(),
        }
        write_json_atomically(out_dir / MANIFEST, manifest)
        return manifest


def token_sample_problems(key: str, members: dict[str, bytes], codebook_size: int, frames_per_token: int) -> list[str]:
    """Everything wrong with one token sample: members, dtype, shape, code range, and a token
    count that does not match the motion's frame count."""
    if set(members) != TOKEN_MEMBERS:
        return [f"members {sorted(members)}, expected {sorted(TOKEN_MEMBERS)}"]
    try:
        tokens = np.load(io.BytesIO(members["tokens.npy"]), allow_pickle=False)
    except ValueError as error:
        return [f"tokens.npy unreadable ({error})"]
    problems = []
    if tokens.dtype != np.int16 or tokens.ndim != 1:
        problems.append(f"tokens.npy is {tokens.dtype} {tokens.shape}, expected int16 (L,)")
    elif len(tokens) and (tokens.min() < 0 or tokens.max() >= codebook_size):
        problems.append(f"tokens outside [0, {codebook_size}): min {tokens.min()}, max {tokens.max()}")
    try:
        meta = json.loads(members["meta.json"])
    except ValueError as error:
        return problems + [f"meta.json unreadable ({error})"]
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), int):
        return problems + ["meta.json has no integer 'frames'"]
    if meta.get("id") != key:
        problems.append(f"meta.json id {meta.get('id')!r} differs from the key")
    if len(tokens) != math.ceil(meta["frames"] / frames_per_token):
        problems.append(
            f"{len(tokens)} tokens for {meta['frames']} frames, expected {math.ceil(meta['frames'] / frames_per_token)}"
        )
    return problems


def check_tokens(out_dir: str | Path) -> list[str]:
    """Problems of a token set against its manifest: files, checksums, counts, sample schema, the
    VQ file, and whether the dataset it was made from has been rebuilt since."""
    out_dir = Path(out_dir)
    manifest_path = out_dir / MANIFEST
    if not manifest_path.exists():
        return [f"{manifest_path}: missing (the token set is incomplete; run `m2d2m tokenize`)"]
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
        codebook_size, frames_per_token = manifest["codebook_size"], manifest["frames_per_token"]
        shards = [s for split in SPLITS for s in manifest["shards"][split]]
        counts = {split: manifest["splits"][split] for split in SPLITS}
    except (ValueError, KeyError) as error:
        return [f"{manifest_path}: unreadable manifest ({error})"]
    tokens_seen = 0

    def check_sample(key: str, members: dict[str, bytes]) -> list[str]:
        nonlocal tokens_seen
        problems = token_sample_problems(key, members, codebook_size, frames_per_token)
        if not problems:
            tokens_seen += len(np.load(io.BytesIO(members["tokens.npy"])))
        return problems

    problems = verify_shards(out_dir, shards, check_sample)
    for split in SPLITS:
        in_shards = sum(s["samples"] for s in manifest["shards"][split])
        if in_shards != counts[split]["samples"]:
            problems.append(f"{split}: shards hold {in_shards} samples, manifest counts {counts[split]['samples']}")
    tokens_counted = sum(c["tokens"] for c in counts.values())
    if not problems and tokens_seen != tokens_counted:
        problems.append(f"shards hold {tokens_seen} tokens, manifest counts {tokens_counted}")
    vq_file = out_dir / VQ_FILE
    if not vq_file.exists():
        problems.append(f"{VQ_FILE}: missing")
    elif sha256_of(vq_file) != manifest["vq_sha256"]:
        problems.append(f"{VQ_FILE}: sha256 differs from the manifest")
    codebook = out_dir / CODEBOOK
    if not codebook.exists() or np.load(codebook).shape != (codebook_size, manifest["code_dim"]):
        problems.append(f"{CODEBOOK}: missing or not ({codebook_size}, {manifest['code_dim']})")
    source = recorded_path(manifest["source_dir"], out_dir)
    if (source / MANIFEST).exists() and _source_shards(read_manifest(source)) != manifest["source_shards"]:
        problems.append(f"{source} was rebuilt after these tokens were made; run `m2d2m tokenize` again")
    return problems
