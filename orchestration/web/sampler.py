"""One thread samples every request, gathering those that arrive together into one call.

Requests for the same model run and the same options are independent sequences of one
:meth:`~m2d2m.generators.protocol.MotionGenerator.generate` call: the protocol draws each
sequence from its own seed, so a result does not depend on the batch it was sampled in, and a
batch of 16 costs far less than 16 calls. One thread, because one call already uses every core
torch is given. The queue is bounded (a full one is refused, HTTP 429); a request whose client went
away is dropped while it waits, and a batch whose clients all went away stops at its next step.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Hashable
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

from m2d2m.generators.protocol import Keep, MotionGenerator
from m2d2m.motion.clip import Motion

Event = dict[str, Any]  # {"queued": n} or {"progress": fraction}; None ends a job's events


class QueueFull(Exception):
    """The queue holds as many requests as it may (HTTP 429)."""


class Cancelled(Exception):
    """The client of a request went away before it was sampled."""


@dataclass(eq=False)
class Job:
    """One sequence to sample: ``actions`` of ``frames`` each, drawn with ``seed``, keeping what
    ``keep`` holds (an edit); ``batch_key`` says which other jobs may share its generator call
    (same generator, same options)."""

    generator: MotionGenerator
    batch_key: Hashable
    options: Any
    actions: list[str]
    frames: list[int]
    seed: int
    keep: Keep | None = None
    listener: Callable[[Event | None], None] = lambda event: None
    done: Future = field(default_factory=Future)
    cancelled: threading.Event = field(default_factory=threading.Event)

    def cancel(self) -> None:
        self.cancelled.set()


@dataclass
class SamplerStats:
    queued: int = 0
    running: int = 0
    served: int = 0
    batches: int = 0
    largest_batch: int = 0
    cancelled: int = 0


class Sampler:
    """The sampling thread and its bounded queue: :meth:`submit` jobs, read their ``done`` future.

    ``gather_s`` is how long the thread waits after a request arrives for others sent with it
    (longer while they keep arriving);
    ``max_batch`` caps the sequences of one call (memory grows with it)."""

    def __init__(self, capacity: int = 64, max_batch: int = 16, gather_s: float = 0.02) -> None:
        self.capacity = capacity
        self.max_batch = max_batch
        self.gather_s = gather_s
        self._pending: deque[Job] = deque()
        self._changed = threading.Condition()
        self._stopping = False
        self._stats = SamplerStats()
        self._thread = threading.Thread(target=self._serve, name="m2d2m-sampler", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        """Finish the queued jobs, then end the thread."""
        with self._changed:
            self._stopping = True
            self._changed.notify()
        if self._thread.is_alive():
            self._thread.join()

    def stats(self) -> SamplerStats:
        with self._changed:
            return SamplerStats(**{**vars(self._stats), "queued": len(self._pending)})

    def submit(self, job: Job) -> None:
        with self._changed:
            if self._stopping:
                raise QueueFull("the server is shutting down")
            if len(self._pending) >= self.capacity:
                raise QueueFull(f"{len(self._pending)} requests are waiting already; try again shortly")
            self._pending.append(job)
            job.listener({"queued": len(self._pending)})
            self._changed.notify()

    # ------------------------------------------------------------------------------ the thread
    def _serve(self) -> None:
        while True:
            with self._changed:
                while not self._pending and not self._stopping:
                    self._changed.wait()
                if not self._pending:
                    return
            self._gather()
            batch = self._take_batch()
            if batch:
                self._sample(batch)

    def _gather(self) -> None:
        """Wait for the requests sent together with the first: ``gather_s``, and again while more
        keep arriving, until a batch is full or eight windows have passed (a burst of 16 clients
        reaches the server over tens of milliseconds)."""
        for _ in range(8):
            with self._changed:
                before = len(self._pending)
            time.sleep(self.gather_s)
            with self._changed:
                if len(self._pending) == before or len(self._pending) >= self.max_batch:
                    return

    def _take_batch(self) -> list[Job]:
        """The oldest job and the jobs waiting with the same batch key, up to ``max_batch``;
        the jobs whose clients left are dropped on the way."""
        with self._changed:
            for job in [job for job in self._pending if job.cancelled.is_set()]:
                self._pending.remove(job)
                self._finish(job, error=Cancelled("the client went away"))
                self._stats.cancelled += 1
            if not self._pending:
                return []
            key = self._pending[0].batch_key
            batch = [job for job in self._pending if job.batch_key == key][: self.max_batch]
            for job in batch:
                self._pending.remove(job)
            for position, job in enumerate(self._pending, start=1):
                job.listener({"queued": position})
            self._stats.running = len(batch)
            self._stats.batches += 1
            self._stats.largest_batch = max(self._stats.largest_batch, len(batch))
            return batch

    def _sample(self, batch: list[Job]) -> None:
        try:
            motions = self._generate(batch)
        except Cancelled as error:
            for job in batch:
                self._finish(job, error=error)
            self._count(cancelled=len(batch))
        except ValueError as error:
            if len(batch) == 1:
                self._finish(batch[0], error=error)
                self._count(served=1)
            else:  # one request the model refuses must not fail the others: each on its own
                for job in batch:
                    self._sample([job])
        except Exception as error:  # reaches every client of the batch as a one-line error
            for job in batch:
                self._finish(job, error=error)
            self._count(served=len(batch))
        else:
            for job, motion in zip(batch, motions):
                self._finish(job, result=motion)
            self._count(served=len(batch))

    def _generate(self, batch: list[Job]) -> list[Motion]:
        last_sent = [-1.0]

        def progress(fraction: float) -> None:
            if all(job.cancelled.is_set() for job in batch):
                raise Cancelled("every client of the batch went away")
            if fraction - last_sent[0] >= 0.01 or fraction >= 1.0:  # a hundred events at most
                last_sent[0] = fraction
                for job in batch:
                    job.listener({"progress": round(float(fraction), 4)})

        first = batch[0]
        return first.generator.generate(
            [job.actions for job in batch],
            [job.frames for job in batch],
            first.options,
            [job.seed for job in batch],
            keep=[job.keep for job in batch],
            progress=progress,
        )

    def _finish(self, job: Job, result: Motion | None = None, error: BaseException | None = None) -> None:
        if error is not None:
            job.done.set_exception(error)
        else:
            job.done.set_result(result)
        job.listener(None)

    def _count(self, served: int = 0, cancelled: int = 0) -> None:
        with self._changed:
            self._stats.running = 0
            self._stats.served += served
            self._stats.cancelled += cancelled
