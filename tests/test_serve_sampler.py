"""The serving sampler on a stand-in generator (no model): batches by key, one refused request
retried alone, waiting jobs of clients that left dropped, a batch stopped when all its clients
left, and a bounded queue."""

from __future__ import annotations

import threading
import time
from dataclasses import replace

import numpy as np
import pytest

from m2d2m.generators.protocol import Keep
from m2d2m.motion.clip import Motion
from orchestration.web.sampler import Cancelled, Job, QueueFull, Sampler


class CountingGenerator:
    """Answers each sequence with a motion whose joints hold its seed; refuses seed 13; calls
    ``progress`` ``steps`` times, ``step_s`` apart; records the keeps it was given."""

    def __init__(self, steps: int = 1, step_s: float = 0.0) -> None:
        self.calls: list[list[int]] = []
        self.steps, self.step_s = steps, step_s
        self.started = threading.Event()
        self.keeps = None

    def generate(self, actions, frames, options, seeds, keep=None, progress=None):
        self.calls.append(list(seeds))
        self.keeps = keep
        self.started.set()
        if 13 in seeds:
            raise ValueError("seed 13 is refused")
        for step in range(self.steps):
            time.sleep(self.step_s)
            progress((step + 1) / self.steps)
        return [
            Motion(np.zeros((4, 263)), np.full((4, 22, 3), seed, np.float32), 20.0, "t2m", ["a"], [(0, 4)])
            for seed in seeds
        ]


def job(generator, seed: int, key: str = "a") -> Job:
    return Job(generator, key, None, ["a person walks"], [4], seed)


def test_jobs_that_arrive_together_share_a_call_by_key_and_a_refused_one_is_retried_alone():
    generator = CountingGenerator()
    sampler = Sampler(capacity=8, max_batch=3, gather_s=0.3)
    jobs = [job(generator, seed, key) for seed, key in ((1, "a"), (2, "b"), (3, "a"), (13, "a"), (5, "a"))]
    for each in jobs:
        sampler.submit(each)
    sampler.start()
    sampler.stop()
    assert generator.calls[0] == [1, 3, 13]  # the oldest key first, at most three
    assert generator.calls[1:4] == [[1], [3], [13]]  # 13 failed the batch: each alone
    assert generator.calls[4:] == [[2], [5]]
    for each in jobs:
        if each.seed == 13:
            with pytest.raises(ValueError, match="seed 13 is refused"):
                each.done.result()
        else:
            assert each.done.result().joints[0, 0, 0] == each.seed
    assert sampler.stats().served == 5 and sampler.stats().largest_batch == 3


def test_a_left_client_is_dropped_while_waiting_and_stops_its_batch_while_sampling():
    generator = CountingGenerator(steps=50, step_s=0.02)
    sampler = Sampler(capacity=8, gather_s=0.0)
    sampler.start()
    running = job(generator, 1)
    sampler.submit(running)
    assert generator.started.wait(10)
    waiting = job(generator, 2, key="other")
    sampler.submit(waiting)
    waiting.cancel()
    running.cancel()
    with pytest.raises(Cancelled):
        running.done.result(timeout=10)
    with pytest.raises(Cancelled):
        waiting.done.result(timeout=10)
    sampler.stop()
    assert generator.calls == [[1]] and sampler.stats().cancelled == 2 and sampler.stats().served == 0


def test_the_queue_is_bounded_and_events_say_where_a_job_waits():
    generator = CountingGenerator()
    sampler = Sampler(capacity=2)
    events = []
    first, second = job(generator, 1), job(generator, 2)
    first.listener = events.append
    sampler.submit(first)
    sampler.submit(second)
    with pytest.raises(QueueFull, match="2 requests are waiting already"):
        sampler.submit(job(generator, 3))
    sampler.start()
    sampler.stop()
    assert events[0] == {"queued": 1} and events[-1] is None and {"progress": 1.0} in events


def test_an_edits_keep_reaches_the_generator_beside_jobs_without_one():
    generator = CountingGenerator()
    sampler = Sampler(capacity=8, max_batch=3, gather_s=0.3)
    kept = Keep(np.zeros((4, 263)), np.array([True, True, False, False]))
    jobs = [job(generator, 1), replace(job(generator, 2), keep=kept)]
    for each in jobs:
        sampler.submit(each)
    sampler.start()
    sampler.stop()
    assert generator.calls == [[1, 2]] and generator.keeps == [None, kept]
