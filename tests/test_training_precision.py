"""No model's training step computes in float64 (issue 54: "no float64 on the GPU unless a test
shows it is needed"); tests/host_syncs.py, ``float64_ops``, says why and how it is found.

Each step is watched under a Lightning Trainer set up as ``orchestration/train.py`` sets it up
(tests/test_host_syncs_models.py, ``run``): forward, loss, backward, clipping, the optimiser, the
logging. The first step is watched too: the schedules a step casts once and keeps (M2D2M's
transition matrices, MotionDiffuse's noise schedule; both built in float64) are cast there, and
nothing else is float64.
"""

from __future__ import annotations

from typing import Any

import lightning.pytorch as pl
import pytest
import torch

from m2d2m.processes.discrete_diffusion import TransitionSchedule
from m2d2m.processes.discrete_diffusion_loss import diffusion_loss
from tests.host_syncs import float64_ops
from tests.test_host_syncs_models import STEPS, evaluator, mmm, mmm_body, motiondiffuse, run, vq
from tests.test_m2d2m_module import make_batch, make_module

pytestmark = pytest.mark.usefixtures("one_torch_thread")

# where the schedules built in float64 are cast to the step's dtype, once, at the first step
SCHEDULE_CASTS = {"m2d2m/processes/discrete_diffusion.py", "m2d2m/processes/gaussian_diffusion.py"}
CASTING = {"aten::_to_copy", "aten::lift_fresh"}


def m2d2m(timestep_sampling: str):
    def build() -> tuple[pl.LightningModule, dict[str, Any]]:
        return make_module(timestep_sampling=timestep_sampling), make_batch()

    return build


@pytest.mark.parametrize(
    ("build", "validate"),
    [
        (m2d2m("uniform"), True),
        (m2d2m("importance"), True),
        (mmm, True),
        (mmm_body, True),
        (motiondiffuse, True),
        (vq(1), False),  # its batch has no lengths, which its validation reconstructs by
        (evaluator, True),
    ],
    ids=["m2d2m", "m2d2m-importance", "mmm", "mmm-body", "motiondiffuse", "vq", "evaluator"],
)
def test_no_training_step_computes_in_float64(build, validate, tmp_path):
    watched = run(build, tmp_path, validate=validate, watch=float64_ops)
    first, *rest = watched.training
    assert len(watched.training) == STEPS and len(watched.validation) == (2 if validate else 0)
    casts = {place.split(":")[0] for _, place in first.calls}
    assert casts <= SCHEDULE_CASTS and {op for op, _ in first.calls} <= CASTING, first.report()
    for step in [*rest, *watched.validation]:
        assert not step, step.report()


def test_the_float32_loss_is_the_float64_one_to_float32_rounding():
    """M2D2M's loss in float32 (a training step's) against the same in float64, at every t of a
    100-step schedule, for the paper's dynamic β(t, d) at several η and the uniform and absorbing
    schedules: the loss, each sample's L_vlb and every gradient agree to float32's rounding."""
    generator = torch.Generator().manual_seed(0)
    codes, steps, length = 64, 100, 12
    codebook = torch.randn(codes, 8, generator=generator, dtype=torch.float64)
    t = torch.arange(1, steps + 1)
    z0 = torch.randint(codes, (steps, length), generator=generator)
    logits = 4.0 * torch.randn(steps, length, codes, generator=generator, dtype=torch.float64)
    valid = torch.rand(steps, length, generator=generator) < 0.9
    schedules = {
        f"dynamic eta={eta}": TransitionSchedule.build(codebook, steps, "dynamic", eta=eta) for eta in (0.25, 0.5, 2.0)
    }
    schedules["uniform"] = TransitionSchedule.build(codebook, steps, "uniform")
    schedules["absorbing"] = TransitionSchedule.build(codebook, steps, "uniform", schedule="absorbing")
    for name, schedule in schedules.items():
        z_t = schedule.q_sample(z0, t[:, None], generator=generator)
        results = []
        for dtype in (torch.float64, torch.float32):
            leaf = logits.to(dtype).clone().requires_grad_()
            out = diffusion_loss(schedule, leaf, z0, z_t, t, valid=valid, aux_weight=0.01)
            out.loss.backward()
            results.append((out.loss.double(), out.vlb.double(), leaf.grad.double()))
        (loss64, vlb64, grad64), (loss32, vlb32, grad32) = results
        assert torch.isclose(loss32, loss64, rtol=1e-5, atol=0), name
        assert torch.allclose(vlb32, vlb64, rtol=1e-4, atol=1e-6), name
        assert torch.allclose(grad32, grad64, rtol=1e-3, atol=1e-6 * float(grad64.abs().max())), name
