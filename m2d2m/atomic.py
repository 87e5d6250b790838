"""Files that appear whole or not at all: each is written under a temporary name in its own folder
and renamed onto its name (``os.replace``, atomic within one file system: POSIX rename(2)), so an
interrupted write (Ctrl-C, SIGTERM, a full disk) never leaves a truncated file under the final
name — such as the 0-byte GIF a stopped generation once left. A SIGKILL leaves its temporary file;
the next write of the same name removes it.

Several files that belong together (a clip's npy, json, BVH, GLB, …) are written into a temporary
folder first and moved into place when every one is written (:func:`atomic_folder`,
:func:`atomic_files`), so a folder never holds two clips' files, nor a failed run's half."""

from __future__ import annotations

import glob
import os
import shutil
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` to write to (same suffix, so tools that read the format
    from the name still can); renamed onto ``path`` when the block ends, removed if it raises."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _remove_killed_writes(path)
    partial = _temporary(path, "partial")
    try:
        yield partial
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)


@contextmanager
def atomic_folder(path: str | Path) -> Iterator[Path]:
    """A temporary folder beside ``path`` to fill; when the block ends it takes ``path``'s place
    whole — a folder there before is moved aside and removed after, so none of its files stay
    beside the new ones — and it is removed if the block raises."""
    path = Path(path)
    with _scratch(path) as partial:
        yield partial
        if path.is_dir() and any(path.iterdir()):
            replaced = _temporary(path, "replaced")
            os.replace(path, replaced)
            os.replace(partial, path)
            shutil.rmtree(replaced)
        else:
            os.replace(partial, path)  # onto nothing, or onto an empty folder (rename(2) allows it)


@contextmanager
def atomic_files(folder: str | Path, stem: str, owned: Iterable[str]) -> Iterator[Path]:
    """A temporary folder in ``folder`` to write files named ``stem…`` into; when the block ends
    each is renamed into ``folder`` (each whole, by :func:`os.replace`), and the names in ``owned``
    (every file such a write may make) that this one did not make are removed, so no file of an
    earlier write of ``stem`` is left beside the new ones. Removed if the block raises."""
    folder = Path(folder)
    with _scratch(folder / stem) as partial:
        yield partial
        written = {file.name for file in partial.iterdir()}
        for name in written:
            os.replace(partial / name, folder / name)
        for name in set(owned) - written:
            (folder / name).unlink(missing_ok=True)


@contextmanager
def _scratch(path: Path) -> Iterator[Path]:
    """A new temporary folder named after ``path``, beside it; removed when the block ends."""
    path.parent.mkdir(parents=True, exist_ok=True)
    _remove_killed_writes(path)
    partial = _temporary(path, "partial")
    partial.mkdir()
    try:
        yield partial
    finally:
        shutil.rmtree(partial, ignore_errors=True)


def _temporary(path: Path, kind: str) -> Path:
    """``path``'s temporary name of this process: hidden, beside it, with its suffix."""
    return path.with_name(f".{path.stem}.{os.getpid()}.{kind}{path.suffix}")


def _remove_killed_writes(path: Path) -> None:
    """The temporary files and folders of ``path`` whose writer is gone (killed before it could
    remove them); those of a process still writing stay."""
    for kind in ("partial", "replaced"):
        for stale in path.parent.glob(f".{glob.escape(path.stem)}.*.{kind}{glob.escape(path.suffix)}"):
            writer = stale.name[len(path.stem) + 2 :].split(".", 1)[0]
            if writer.isdigit() and not _alive(int(writer)):
                if stale.is_dir():
                    shutil.rmtree(stale, ignore_errors=True)
                else:
                    stale.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True
