"""The VQ-VAE's training losses: T2M-GPT's terms, and the optional acceleration term."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from training.vq_module import VQVAEModule

MODEL = {"width": 16, "depth": 1, "code_dim": 8, "codebook_size": 16}
LOSS = {"recon": 1.0, "joint": 0.5, "commit": 0.02}


def module(**loss: float) -> VQVAEModule:
    torch.manual_seed(0)
    return VQVAEModule(MODEL, {}, {**LOSS, **loss}, feature_dim=263, skeleton="t2m").eval()  # a fixed codebook


def test_without_an_acceleration_weight_the_loss_is_t2m_gpts():
    x = torch.randn(2, 16, 263)
    losses = module()._losses(x)
    assert "acceleration" not in losses
    expected = losses["recon"] + 0.5 * losses["joint"] + 0.02 * losses["commit"]
    assert losses["loss"].item() == pytest.approx(expected.item())


def test_acceleration_term_is_the_smooth_l1_of_the_positions_second_differences():
    x = torch.randn(2, 16, 263)
    plain, weighted = module(acceleration=0.0), module(acceleration=2.0)
    weighted.load_state_dict(plain.state_dict())
    a, b = plain._losses(x), weighted._losses(x)
    reconstruction = weighted.model(x).reconstruction[..., 4:67]
    second = lambda y: y[:, 2:] - 2 * y[:, 1:-1] + y[:, :-2]  # noqa: E731
    by_hand = F.smooth_l1_loss(second(reconstruction), second(x[..., 4:67]))
    assert b["acceleration"].item() == pytest.approx(by_hand.item(), rel=1e-5)
    assert b["loss"].item() == pytest.approx((a["loss"] + 2.0 * by_hand).item(), rel=1e-5)


@pytest.mark.parametrize("name", ["demo", "humanml3d", "kit"])
def test_every_shipped_config_keeps_t2m_gpts_decoder_and_loss(name):
    """On the calibrated corpus T2M-GPT's recipe already decodes as smoothly as the data
    (docs/training.md, "Smooth decoding"); both departures stay opt-in."""
    from orchestration.config import load_config

    config = load_config("vq", name)
    assert config["model"]["output_smoothing"] == 0.0 and config["loss"]["acceleration"] == 0.0
