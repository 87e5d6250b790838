"""Progress a person can follow wherever the output goes: tqdm's bar on a terminal, and when
stderr is a file, a pipe, CI or a cluster job's log, plain lines at a steady pace — one at each
tenth of the job, at most one every ``MIN_SECONDS``, and one at least every ``MAX_SECONDS`` —
each a whole line without a bar's carriage returns or escape codes (docs/reliability.md).

Only the standard library here; tqdm is imported when there is a terminal to draw on.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TextIO

PARTS = 10  # a line at every tenth of the job
MIN_SECONDS = 5.0  # but not more often: a job of seconds prints no more than its last line
MAX_SECONDS = 30.0  # and at least this often, whatever the fraction


def on_terminal(stream: TextIO | None = None) -> bool:
    stream = sys.stderr if stream is None else stream
    return bool(getattr(stream, "isatty", lambda: False)())


def duration(seconds: float) -> str:
    """``42 s``, ``3 min 5 s``, ``2 h 10 min``."""
    seconds = max(0, round(seconds))
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60} min"


class ProgressLines:
    """A counter with tqdm's calls (``update``, ``set_description``, ``set_postfix_str``, ``n``,
    iteration, a context manager) that prints plain lines: ``desc: 40/100 batch (40 %), 2.1
    batch/s, 29 s left, loss 0.123``."""

    def __init__(
        self,
        iterable: Iterable | None = None,
        total: float | None = None,
        desc: str = "",
        unit: str = "it",
        file: TextIO | None = None,
        clock: Callable[[], float] = time.monotonic,
        initial: float = 0,
    ) -> None:
        self.iterable = iterable
        self.total = total if total is not None or iterable is None else _length(iterable)
        self.desc, self.unit = desc, unit
        self.file = file
        self.clock = clock
        self.n = self._initial = initial  # a resumed job counts from where it was; its rate from now
        self.postfix = ""
        self._start = self._last = clock()
        self._tenths = self._parts_done(initial)
        self._printed_at: float | None = None

    def __iter__(self) -> Iterator:
        for item in self.iterable or ():
            yield item
            self.update()
        self.close()

    def __enter__(self) -> ProgressLines:
        return self

    def __exit__(self, kind: Any, error: Any, trace: Any) -> None:
        if kind is None:
            self.close()

    def set_description(self, desc: str) -> None:
        self.desc = desc

    def set_postfix_str(self, postfix: str) -> None:
        self.postfix = postfix

    def update(self, n: float = 1) -> None:
        self.n += n
        now = self.clock()
        tenths = self._parts_done(self.n)
        if (tenths > self._tenths and now - self._last >= MIN_SECONDS) or now - self._last >= MAX_SECONDS:
            self._print(now)
        self._tenths = max(self._tenths, tenths)

    def _parts_done(self, n: float) -> int:
        return int(n * PARTS / self.total + 1e-9) if self.total else 0

    def close(self) -> None:
        """The last line, when the job printed any or took more than ``MIN_SECONDS``."""
        now = self.clock()
        if self._printed_at != self.n and (self._printed_at is not None or now - self._start >= MIN_SECONDS):
            self._print(now)

    def line(self, now: float) -> str:
        elapsed = now - self._start
        rate = (self.n - self._initial) / elapsed if elapsed > 0 else 0.0
        if self.unit == "%":
            parts = [f"{self.n:.0f} %"]
        elif self.total:
            parts = [f"{self.n:g}/{self.total:g} {self.unit} ({100 * self.n / self.total:.0f} %)"]
        else:
            parts = [f"{self.n:g} {self.unit}"]
        if rate > 0 and self.unit != "%":
            parts.append(f"{rate:.3g} {self.unit}/s" if rate >= 1 else f"{1 / rate:.3g} s/{self.unit}")
        if rate > 0 and self.total:
            parts.append(f"{duration((self.total - self.n) / rate)} left")
        parts.append(f"{duration(elapsed)} so far" if not self.total else "")
        text = ", ".join(part for part in [*parts, self.postfix] if part)
        return f"{self.desc}: {text}" if self.desc else text

    def _print(self, now: float) -> None:
        print(self.line(now), file=self.file if self.file is not None else sys.stderr, flush=True)
        self._last, self._printed_at = now, self.n


def progress(
    iterable: Iterable | None = None,
    total: float | None = None,
    desc: str = "",
    unit: str = "it",
    leave: bool = True,
    file: TextIO | None = None,
    disable: bool = False,
) -> Any:
    """tqdm's bar when ``file`` (stderr) is a terminal, :class:`ProgressLines` otherwise; with
    ``disable``, the iterable as it is or a counter that prints nothing."""
    stream = sys.stderr if file is None else file
    if not disable and not on_terminal(stream):
        return ProgressLines(iterable, total, desc, unit, stream)
    from tqdm import tqdm

    return tqdm(iterable, total=total, desc=desc, unit=unit, leave=leave, file=stream, disable=disable)


def _length(iterable: Iterable) -> float | None:
    return len(iterable) if hasattr(iterable, "__len__") else None  # type: ignore[arg-type]
