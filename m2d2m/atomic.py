"""Files that appear whole or not at all: each is written under a temporary name in its own folder
and renamed onto its name (``os.replace``, atomic within one file system: POSIX rename(2)), so an
interrupted write (Ctrl-C, SIGTERM, a full disk) never leaves a truncated file under the final
name — such as the 0-byte GIF a stopped generation once left. A SIGKILL leaves its temporary file;
the next write of the same name removes it."""

from __future__ import annotations

import glob
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
    _remove_killed_writes(path)
    partial = path.with_name(f".{path.stem}.{os.getpid()}.partial{path.suffix}")
    try:
        yield partial
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)


def _remove_killed_writes(path: Path) -> None:
    """The temporary files of ``path`` whose writer is gone (killed before it could remove them);
    those of a process still writing stay."""
    for stale in path.parent.glob(f".{glob.escape(path.stem)}.*.partial{glob.escape(path.suffix)}"):
        writer = stale.name[len(path.stem) + 2 :].split(".", 1)[0]
        if writer.isdigit() and not _alive(int(writer)):
            stale.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True
