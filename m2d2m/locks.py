"""Locks between `m2d2m` commands on one project: a file beside what is written, held with
``flock`` for as long as the writer (or a reader that must not see it change) runs. The kernel
releases it when the process ends, a SIGKILL included, so a lock never outlives its command. A
command that finds the lock held refuses in one line rather than writing over another's work
(docs/reliability.md, "Concurrent commands")."""

from __future__ import annotations

import fcntl
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


class Busy(ValueError):
    """Another command holds the lock."""


@contextmanager
def holding(lock_file: Path, busy: str, shared: bool = False, wait: bool = False) -> Iterator[None]:
    """Hold ``lock_file`` (made if missing) exclusively, or ``shared`` with other readers, while
    the block runs; :class:`Busy` with the sentence ``busy`` when another command holds it in a
    way that excludes this one, or with ``wait``, once it lets go (for writes of seconds whose
    result the waiting command then reuses)."""
    lock_file.parent.mkdir(parents=True, exist_ok=True)
    with lock_file.open("a") as handle:
        try:
            fcntl.flock(handle, (fcntl.LOCK_SH if shared else fcntl.LOCK_EX) | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            raise Busy(busy) from None
        yield
