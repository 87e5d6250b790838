"""Which token set belongs to a VQ-VAE: the dataset it encodes and the folder of that dataset's
tokens under it, ``<data>/tokens/<VQ run>`` (docs/data.md), made by :mod:`pipelines.tokenize`
when missing or stale."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from m2d2m.layout import TOKENS, recorded_path


def token_set(
    vq_path: Path, data_dir: str | Path | None = None, extra: dict[str, Any] | None = None
) -> tuple[Path, Path]:
    """The dataset a VQ-VAE encodes (``data_dir``, else the one it was trained on) and the folder
    of its tokens under that VQ-VAE. ``extra`` is the VQ file's record when the caller has loaded
    the file already; otherwise the whole model is read here, so that a damaged or foreign file is
    a FileNotFoundError or ValueError in one line rather than a traceback inside Ray."""
    if extra is None:
        from m2d2m.networks.vqvae import load_vq

        extra = load_vq(vq_path)[2]["extra"]
    if not (data_dir or extra.get("data_dir")):
        raise ValueError(f"{vq_path} does not say which dataset it was trained on: pass the dataset directory")
    data = Path(data_dir) if data_dir else recorded_path(extra["data_dir"], vq_path)
    return data, data / TOKENS / extra.get("run", vq_path.parent.name)


def ensure_tokens(vq_path: Path, extra: dict[str, Any] | None = None) -> tuple[Path, Path]:
    """:func:`token_set`, the tokens made first when they are missing or stale (so that a sweep's
    driver makes them once, before parallel trials would race to); another command making them is
    a :class:`m2d2m.locks.Busy` (a ValueError). A local Ray started to tokenize is shut down
    after it: the training that follows needs none, and shut down at the process's exit it held
    the command 10 s after its last line (a sweep's driver, which started Ray, keeps it). Ray is
    imported only then: a training on current tokens runs where Ray is not installed (a GPU
    machine given only what training needs, bench/gpu_carry.py)."""
    from pipelines.tokenize import current_tokens, tokenize_dataset

    data_dir, tokens_dir = token_set(vq_path, extra=extra)
    if current_tokens(data_dir, vq_path, tokens_dir) is None:
        import ray

        print(f"tokenizing {data_dir} with {vq_path} first")
        running = ray.is_initialized()
        tokenize_dataset(data_dir, vq_path, tokens_dir)
        if not running:
            ray.shutdown()
    return data_dir, tokens_dir
