"""The motion VQ-VAE: the EMA quantizer on hand-made inputs, shapes, files, and a tiny overfit."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch
import torch.multiprocessing as mp

from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.networks.vqvae import VQ_FORMAT, EMACodebook, MotionVQVAE, VQConfig, load_vq

SMALL = VQConfig(feature_dim=12, width=32, depth=2, code_dim=16, codebook_size=32)

pytestmark = pytest.mark.usefixtures("one_torch_thread")


CORNERS = torch.tensor([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0]])


def set_codebook(quantizer: EMACodebook, codes: torch.Tensor, counts: list[float]) -> None:
    """Put the quantizer in a known state: the given codes, with EMA sums consistent with counts."""
    count = torch.tensor(counts)
    quantizer.codebook.copy_(codes)
    quantizer.code_count.copy_(count)
    quantizer.code_sum.copy_(codes * count[:, None])
    quantizer.initialised.fill_(True)


def random_walks(batch: int, frames: int, dim: int, seed: int) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    steps = 0.3 * torch.randn(batch, frames, dim, generator=generator)
    walk = steps.cumsum(1)
    return walk - walk.mean(1, keepdim=True)


# ---------------------------------------------------------------------------------------- quantizer


def test_first_training_forward_fills_the_codebook_from_the_batch():
    torch.manual_seed(0)
    quantizer = EMACodebook(4, 2, decay=0.99).train()
    batch = CORNERS[[2, 0, 3, 1]] + 0.5
    quantizer(batch)
    # Each code is one batch vector, assigned only to itself, so the EMA leaves it in place.
    torch.testing.assert_close(torch.tensor(sorted(quantizer.codebook.tolist())), CORNERS[[0, 2, 1, 3]] + 0.5)
    assert bool(quantizer.initialised)

    # Fewer vectors than codes: tiled copies with noise of std 0.01/√D around the data.
    quantizer = EMACodebook(16, 2).train()
    few = torch.tensor([[1.0, 2.0], [-3.0, 4.0]])
    quantizer(few)
    gap = torch.cdist(quantizer.codebook, few).min(1).values
    assert gap.max() < 5 * 0.01 / math.sqrt(2)


def test_vectors_equal_to_codes_map_to_them_with_zero_commitment_loss():
    quantizer = EMACodebook(4, 2)
    set_codebook(quantizer, CORNERS, [5.0] * 4)
    batch = CORNERS[[3, 1, 1, 0, 2]]
    out = quantizer.eval()(batch)
    assert out.indices.tolist() == [3, 1, 1, 0, 2]
    assert out.commit_loss.item() == 0.0 and torch.equal(out.quantized, batch)
    # Training mode quantizes with the codebook after its EMA step (as T2M-GPT does), which
    # moves these codes by rounding error only.
    out = quantizer.train()(batch)
    assert out.indices.tolist() == [3, 1, 1, 0, 2]
    assert out.commit_loss.item() < 1e-10


def test_ema_update_matches_the_hand_computed_values():
    mu = 0.9
    quantizer = EMACodebook(4, 2, decay=mu).train()
    set_codebook(quantizer, CORNERS, [2.0, 2.0, 2.0, 2.0])
    batch = torch.tensor([[1.0, 0.0], [-1.0, 2.0], [9.0, 1.0], [0.0, 11.0]])
    out = quantizer(batch)
    assert out.indices.tolist() == [0, 0, 1, 2]
    # Code 0: count 2 and two vectors of mean (0, 1): moves exactly (1 − μ) of the way there.
    # Code 1: sum 0.9·(20, 0) + 0.1·(9, 1), count 0.9·2 + 0.1·1.
    # Code 2: sum 0.9·(0, 20) + 0.1·(0, 11), count 1.9.  Code 3: unused but still live (1.8 ≥ 1).
    expected = torch.tensor(
        [
            [0.0, mu * 0.0 + (1 - mu) * 1.0],
            [(18.0 + 0.9) / 1.9, 0.1 / 1.9],
            [0.0, (18.0 + 1.1) / 1.9],
            [10.0, 10.0],
        ]
    )
    torch.testing.assert_close(quantizer.codebook, expected)
    torch.testing.assert_close(quantizer.code_count, torch.tensor([2.0, 1.9, 1.9, 1.8]))
    assert out.active_codes.item() == 3


def test_dead_codes_are_reset_to_batch_vectors_and_live_codes_are_not():
    torch.manual_seed(1)
    quantizer = EMACodebook(4, 2, decay=0.9).train()
    set_codebook(quantizer, CORNERS, [2.0, 2.0, 1.0, 1.0])  # codes 2 and 3 will get no vector
    batch = torch.tensor([[1.0, 0.0], [9.0, 1.0], [2.0, 1.0], [8.0, -1.0]])
    quantizer(batch)
    # Live codes: the EMA mean (count 2·0.9 + 0.1·2 = 2; sum 0.9·2·c + 0.1·Σx).
    torch.testing.assert_close(quantizer.codebook[0], (0.1 * torch.tensor([3.0, 1.0])) / 2.0)
    torch.testing.assert_close(quantizer.codebook[1], torch.tensor([18.0 + 0.1 * 17.0, 0.0]) / 2.0)
    # Dead codes (count 0.9 < 1): each replaced by one of the batch's vectors.
    for row in quantizer.codebook[2:]:
        assert any(torch.equal(row, vector) for vector in batch)


def test_eval_mode_leaves_every_buffer_unchanged():
    quantizer = EMACodebook(4, 2)
    set_codebook(quantizer, CORNERS, [2.0, 0.5, 1.0, 3.0])
    before = {k: v.clone() for k, v in quantizer.state_dict().items()}
    quantizer.eval()(torch.randn(50, 2) * 5)
    uninitialised = EMACodebook(4, 2).eval()
    uninitialised(torch.randn(10, 2))
    assert all(torch.equal(before[k], v) for k, v in quantizer.state_dict().items())
    assert not bool(uninitialised.initialised) and not uninitialised.codebook.any()


def test_perplexity_of_a_uniform_assignment_over_k_codes_is_k():
    quantizer = EMACodebook(8, 2).eval()
    codes = torch.randn(8, 2) * 10
    set_codebook(quantizer, codes, [1.0] * 8)
    for k in (1, 3, 4):
        out = quantizer(codes[:k].repeat(5, 1))
        assert out.perplexity.item() == pytest.approx(k, rel=1e-6)
        assert out.active_codes.item() == k


def test_straight_through_gradient_reaches_the_input():
    quantizer = EMACodebook(4, 2)
    set_codebook(quantizer, CORNERS, [2.0] * 4)
    x = torch.tensor([[1.0, 2.0], [7.0, 8.0]], requires_grad=True)
    weights = torch.tensor([[1.0, -2.0], [3.0, 0.5]])
    (quantizer(x).quantized * weights).sum().backward()
    torch.testing.assert_close(x.grad, weights)

    model = MotionVQVAE(SMALL).train()
    x = torch.randn(2, 16, SMALL.feature_dim, requires_grad=True)
    out = model(x)
    (out.reconstruction.pow(2).mean() + out.commit_loss).backward()
    assert x.grad.abs().sum() > 0
    assert model.encoder[0].weight.grad.abs().sum() > 0


def test_quantizer_stays_float32_under_bf16_autocast():
    torch.manual_seed(0)
    model = MotionVQVAE(SMALL).train()
    x = torch.randn(2, 20, SMALL.feature_dim)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = model(x)
    assert out.commit_loss.dtype == torch.float32
    assert model.codebook.dtype == model.quantizer.code_sum.dtype == torch.float32
    assert out.reconstruction.shape == x.shape and torch.isfinite(out.reconstruction).all()


def _ddp_worker(rank: int, init_file: str, results: str) -> None:
    torch.set_num_threads(1)
    torch.distributed.init_process_group("gloo", init_method=f"file://{init_file}", rank=rank, world_size=2)
    torch.manual_seed(100 + rank)  # different local randomness: replicas must still agree
    quantizer = EMACodebook(8, 3, decay=0.9).train()
    for step in range(3):
        quantizer(torch.randn(5 + rank, 3) + 3 * rank + step)
    torch.save({k: v.clone() for k, v in quantizer.state_dict().items()}, f"{results}.{rank}")
    torch.distributed.destroy_process_group()


@pytest.mark.skipif(not torch.distributed.is_available(), reason="torch.distributed unavailable")
def test_distributed_replicas_keep_identical_codebooks(tmp_path):
    mp.spawn(_ddp_worker, args=(str(tmp_path / "init"), str(tmp_path / "state")), nprocs=2)
    first, second = (torch.load(tmp_path / f"state.{r}") for r in range(2))
    assert all(torch.equal(first[k], second[k]) for k in first)
    # Counts are global: 3 steps of 5 + 6 vectors, EMA from a count of 1 per code.
    expected_total = 0.9**3 * 8 + sum(0.1 * 11 * 0.9**i for i in range(3))
    assert first["code_count"].sum().item() == pytest.approx(expected_total, rel=1e-5)


# -------------------------------------------------------------------------------------------- model


def test_config_round_trip_and_unknown_keys():
    assert VQConfig.from_dict(SMALL.to_dict()) == SMALL
    with pytest.raises(ValueError, match="codebok_size, widht"):
        VQConfig.from_dict({"widht": 3, "codebok_size": 5})
    with pytest.raises(ValueError, match="activation"):
        VQConfig(activation="tanh")


@pytest.mark.parametrize("frames", [1, 2, 3, 4, 5, 61, 62, 63, 64])
def test_shapes_for_any_number_of_frames(frames):
    torch.manual_seed(0)
    model = MotionVQVAE(SMALL).train()
    x = torch.randn(2, frames, SMALL.feature_dim)
    out = model(x)
    tokens = math.ceil(frames / 4)
    assert model.frames_per_token == 4
    assert out.reconstruction.shape == (2, frames, SMALL.feature_dim)
    assert out.tokens.shape == (2, tokens) and out.tokens.dtype == torch.long
    assert model.eval().encode(x).shape == (2, tokens)


def test_decode_any_batch_and_encode_decode_matches_forward():
    torch.manual_seed(0)
    model = MotionVQVAE(SMALL).train()
    model(torch.randn(4, 32, SMALL.feature_dim))  # initialise the codebook
    model.eval()
    assert model.codebook.shape == (32, 16)
    tokens = torch.randint(0, 32, (3, 5))
    assert model.decode(tokens).shape == (3, 20, SMALL.feature_dim)

    x = torch.randn(3, 30, SMALL.feature_dim)
    before = {k: v.clone() for k, v in model.quantizer.state_dict().items()}
    with torch.no_grad():
        out = model(x)
        tokens = model.encode(x)
        assert torch.equal(tokens, out.tokens)
        assert torch.equal(model.decode(tokens)[:, :30], out.reconstruction)
    assert all(torch.equal(before[k], v) for k, v in model.quantizer.state_dict().items())


def test_save_load_round_trip_and_foreign_files(tmp_path):
    torch.manual_seed(0)
    model = MotionVQVAE(SMALL).train()
    model(torch.randn(4, 32, SMALL.feature_dim))
    model.eval()
    normalizer = Normalizer(np.linspace(-1, 1, 12), np.linspace(0.5, 2, 12), 4.0)
    VQ_FORMAT.save(
        tmp_path / "vq.pt", model=model, normalizer=normalizer, skeleton="t2m", extra={"run": "abc", "step": 7}
    )
    loaded, loaded_norm, info = load_vq(tmp_path / "vq.pt")
    assert not loaded.training and loaded.config == SMALL
    assert info == {"skeleton": "t2m", "part": "full", "extra": {"run": "abc", "step": 7}}
    np.testing.assert_allclose(loaded_norm.scale, normalizer.scale, rtol=1e-6)
    assert loaded_norm.feat_bias == 4.0
    x = torch.randn(2, 23, SMALL.feature_dim)
    with torch.no_grad():
        a, b = model(x), loaded(x)
    assert torch.equal(a.reconstruction, b.reconstruction) and torch.equal(a.tokens, b.tokens)
    assert [p.name for p in tmp_path.iterdir()] == ["vq.pt"]

    torch.save({"state_dict": model.state_dict()}, tmp_path / "lightning.ckpt")
    (tmp_path / "notes.txt").write_text("hello")
    for name in ("lightning.ckpt", "notes.txt"):
        with pytest.raises(ValueError, match="not a VQ-VAE model file"):
            load_vq(tmp_path / name)
    for bad in (np.zeros(3), np.float64(1.0)):
        with pytest.raises(TypeError, match="numpy|ndarray|float64"):
            VQ_FORMAT.save(
                tmp_path / "bad.pt", model=model, normalizer=normalizer, skeleton="t2m", extra={"value": bad}
            )
    assert not (tmp_path / "bad.pt").exists()


def test_tiny_model_overfits_a_few_random_walks():
    # Few codes for the 32 latents of the batch: the EMA-reset rule keeps a code alive only while
    # it averages at least one vector per batch, so K must be well below the latents per batch.
    torch.manual_seed(0)
    model = MotionVQVAE(replace(SMALL, codebook_size=8)).train()
    x = random_walks(4, 32, SMALL.feature_dim, seed=3)
    optimiser = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(150):
        out = model(x)
        loss = torch.nn.functional.smooth_l1_loss(out.reconstruction, x) + 0.02 * out.commit_loss
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses.append(loss.item())
    assert np.mean(losses[-10:]) < 0.3 * losses[0]


def test_paper_size_default_runs_on_cpu():
    model = MotionVQVAE()
    # T2M-GPT's VQ-VAE: encoder 9,587,200 + decoder 9,849,607 parameters (codebook is a buffer).
    assert sum(p.numel() for p in model.parameters()) == 19_436_807
    assert model.codebook.shape == (512, 512)
    with torch.no_grad():
        out = model.train()(torch.randn(2, 64, 263))
    assert out.reconstruction.shape == (2, 64, 263) and out.tokens.shape == (2, 16)


# ---------------------------------------------------------------------------------- smooth decoding


def test_output_low_pass_is_the_library_gaussian_filter_and_zero_is_t2m_gpts_decoder():
    from m2d2m.motion.representation.smoothing import gaussian_smooth
    from m2d2m.networks.vqvae import TemporalLowPass

    x = np.random.default_rng(1).normal(size=(2, 5, 30))
    filtered = TemporalLowPass(1.5)(torch.tensor(x, dtype=torch.float32)).numpy()
    np.testing.assert_allclose(filtered[1], gaussian_smooth(x[1].T, 1.5).T, atol=1e-5)
    assert torch.equal(TemporalLowPass(0.0)(torch.tensor(x)), torch.tensor(x))

    torch.manual_seed(0)
    plain = MotionVQVAE(SMALL).eval()
    smoothed = MotionVQVAE(replace(SMALL, output_smoothing=1.0)).eval()
    smoothed.load_state_dict(plain.state_dict())  # the filter has no weights: old files still load
    tokens = torch.randint(0, SMALL.codebook_size, (1, 8))
    with torch.no_grad():
        raw, low = plain.decode(tokens)[0].numpy(), smoothed.decode(tokens)[0].numpy()
    np.testing.assert_allclose(low, gaussian_smooth(raw, 1.0), atol=1e-5)
    assert np.abs(np.diff(low, n=3, axis=0)).mean() < 0.5 * np.abs(np.diff(raw, n=3, axis=0)).mean()


@pytest.mark.parametrize("sigma", [-1.0, 9.0, "1"])
def test_output_smoothing_outside_its_range_is_a_config_error(sigma):
    with pytest.raises(ValueError, match="output_smoothing"):
        replace(SMALL, output_smoothing=sigma)


def test_model_files_without_output_smoothing_load_as_t2m_gpts_decoder():
    config = SMALL.to_dict()
    del config["output_smoothing"]
    assert VQConfig.from_dict(config).output_smoothing == 0.0


def test_mmm_reset_waits_for_its_interval_and_spares_codes_used_in_it():
    torch.manual_seed(2)
    quantizer = EMACodebook(4, 2, decay=0.5, reset_every=3).train()
    set_codebook(quantizer, CORNERS, [2.0, 2.0, 2.0, 2.0])
    near = {code: CORNERS[code][None] + 0.1 for code in range(4)}
    quantizer(near[2])  # step 1: code 2 used once in the interval
    for _ in range(2):  # steps 2 and 3: only code 0; codes 1 and 3 unused for the whole interval
        before = quantizer.codebook.clone()
        quantizer(torch.cat([near[0], near[0]]))
    # step 2 reset nothing although counts fell below 1 (code 1: 2·0.5³ = 0.25)
    assert quantizer.code_count[1] < 1
    # step 3 (the interval's end) re-drew codes 1 and 3 from the batch (jittered copies: 2 vectors
    # for 4 codes), kept code 2 (used at step 1)
    for code in (1, 3):
        assert torch.dist(quantizer.codebook[code], near[0][0]) < 5 * 0.01 / math.sqrt(2)
    torch.testing.assert_close(quantizer.codebook[2], before[2])
    assert quantizer.recent_usage.sum() == 0 and int(quantizer.updates) == 3
    assert "recent_usage" not in EMACodebook(4, 2).state_dict()  # T2M-GPT's files keep their buffers
