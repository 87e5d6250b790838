"""Files that appear whole or not at all: each is written under a temporary name in its own folder
and renamed onto its name (``os.replace``, atomic within one file system: POSIX rename(2)), so an
interrupted write (Ctrl-C, SIGTERM, a full disk) never leaves a truncated file under the final
name — such as the 0-byte GIF a stopped generation once left."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write to (same suffix, so tools that read the format
    from the name still can); renamed onto ``path`` when the block ends, removed if it raises."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.stem}.{os.getpid()}.partial{path.suffix}")
    try:
        yield partial
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)
