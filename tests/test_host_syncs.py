"""The hot paths never make the host wait for the device, counted on the CPU (tests/host_syncs.py).

On a GPU a training or sampling step that reads a tensor back on the host (``.item()``, a
``nonzero``, a boolean index, ``tolist``) stalls the queue of kernels until the device catches up,
every step (issue 37: 55 ``nonzero`` a training step, the GPU 0–9 % busy). On the CPU such a read
costs nothing, so it would creep back unnoticed: here each hot path runs once to fill its caches,
then once counted, and must make no such read at all.

A case is a :class:`HotPath`: a name and a ``prepare`` that builds a tiny model and its inputs and
returns the step to count. Another model's steps are more entries in :data:`HOT_PATHS`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import pytest
import torch

from m2d2m.generators.m2d2m.options import M2D2MOptions
from m2d2m.generators.m2d2m.sampling import FREE, TokenRequest
from tests.host_syncs import host_syncs
from tests.test_m2d2m_module import SENTENCES, make_batch, make_module

pytestmark = pytest.mark.usefixtures("one_torch_thread")

Step = Callable[[], object]


@dataclass(frozen=True)
class HotPath:
    """A step to count: ``prepare()`` builds what it needs and returns it."""

    name: str
    prepare: Callable[[], Step]


def _quiet(module: torch.nn.Module) -> torch.nn.Module:
    """The module with Lightning's ``log`` replaced by a no-op: what Lightning does with a logged
    tensor is Lightning's (it reads them when it writes its logs), the step's own code is counted."""
    module.log = lambda *args, **kwargs: None
    return module


def m2d2m_training_step(timestep_sampling: str) -> Callable[[], Step]:
    """M2D2M's training step and its backward pass (the optimiser's step is counted apart)."""

    def prepare() -> Step:
        module = _quiet(make_module(timestep_sampling=timestep_sampling))
        batch = make_batch()
        return lambda: module.training_step(batch, 0).backward()

    return prepare


def m2d2m_validation_step() -> Step:
    module = _quiet(make_module())
    batch = make_batch()

    @torch.no_grad()
    def step() -> None:
        module.validation_step(batch, 1)

    return step


def m2d2m_sample(**options: object) -> Callable[[], Step]:
    """A whole short ``TokenSampler.sample`` call: its setup, both phases' steps, its results."""

    slerp = options.get("method") == "slerp"  # editing by given tokens is every method's but slerp's

    def prepare() -> Step:
        sampler = make_module().sampler()
        given = torch.full((9,), FREE)
        given[:2] = torch.tensor([3, 1])
        requests = [
            TokenRequest([[SENTENCES[0]], [SENTENCES[1]]], [5, 4], seed=1, given=None if slerp else given),
            TokenRequest([[SENTENCES[2]], [""], [SENTENCES[3]]], [6, 3, 5], seed=2),
        ]
        chosen = M2D2MOptions(**{"ts": 6, **options})
        return lambda: sampler.sample(requests, chosen)

    return prepare


HOT_PATHS = [
    HotPath("m2d2m training step", m2d2m_training_step("uniform")),
    HotPath("m2d2m training step, importance-sampled t", m2d2m_training_step("importance")),
    HotPath("m2d2m validation step", m2d2m_validation_step),
    HotPath("m2d2m tps", m2d2m_sample(method="tps", guidance=2.0)),
    HotPath(
        "m2d2m independent, unguided, truncated, 3 jumps",
        m2d2m_sample(method="independent", guidance=0.0, truncation=0.7, steps=3),
    ),
    HotPath("m2d2m handshake", m2d2m_sample(method="handshake", handshake=2)),
    HotPath("m2d2m slerp, another eta", m2d2m_sample(method="slerp", eta=1.5)),
]


@pytest.mark.parametrize("path", HOT_PATHS, ids=lambda path: path.name)
def test_a_hot_path_never_makes_the_host_wait(path: HotPath):
    step = path.prepare()
    step()  # first calls fill caches (position buckets, the schedule at another η)
    with host_syncs() as found:
        step()
    assert not found, f"{path.name} makes the host wait:\n{found.report()}"


def test_the_fused_optimiser_step_never_makes_the_host_wait():
    """AdamW runs fused (training/step.py): its step counters live beside the parameters and one
    kernel updates them all, so nothing is read on the host. The for-loop AdamW read each counter
    with ``.item()`` (kept on the CPU, so nothing waited, but one host call per parameter); fused
    had been refused by Lightning's clipping of an optimiser that unscales its own gradients
    (lightning/pytorch/plugins/precision/amp.py), which the module now does itself."""
    module = _quiet(make_module())
    optimizer = module.configure_optimizers()["optimizer"]
    module.training_step(make_batch(), 0).backward()
    optimizer.step()
    with host_syncs() as found:
        optimizer.step()
    assert optimizer.defaults["fused"]
    assert not found, found.report()
