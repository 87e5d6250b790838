"""The denoising transformer: shapes, padding invariance, the null condition, extrapolation, size."""

from __future__ import annotations

import time

import pytest
import torch

from m2d2m.networks.config import ConfigError
from m2d2m.networks.m2d2m_denoiser import DenoiserConfig, MotionDenoiser, guided_logits, relative_position_bucket

SMALL = DenoiserConfig(
    codebook_size=16, layers=2, heads=4, width=32, ffn=64, text_dim=24, steps=10, max_distance=16, num_buckets=8
)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def small_model(seed: int = 0) -> MotionDenoiser:
    torch.manual_seed(seed)
    return MotionDenoiser(SMALL).eval()


def inputs(batch: int = 3, length: int = 10, text_length: int = 5, seed: int = 1):
    generator = torch.Generator().manual_seed(seed)
    tokens = torch.randint(0, SMALL.codebook_size + 1, (batch, length), generator=generator)
    mask = torch.ones(batch, length, dtype=torch.bool)
    t = torch.randint(1, SMALL.steps + 1, (batch,), generator=generator)
    text = torch.randn(batch, text_length, SMALL.text_dim, generator=generator)
    text_mask = torch.ones(batch, text_length, dtype=torch.bool)
    return tokens, mask, t, text, text_mask


def test_config_round_trip_and_rejects_unknown_keys():
    assert DenoiserConfig.from_dict(SMALL.to_dict()) == SMALL
    with pytest.raises(ValueError, match="unknown DenoiserConfig keys: layer"):
        DenoiserConfig.from_dict({"layer": 3})
    with pytest.raises(ValueError, match="divisible"):
        DenoiserConfig(width=30, heads=4)


def test_a_network_config_with_a_key_it_does_not_know_is_refused():
    """A typo (or a key of a retired format) is an error, never silently dropped."""
    with pytest.raises(ConfigError, match="unknown DenoiserConfig keys: condition_drop"):
        DenoiserConfig.from_dict({**SMALL.to_dict(), "condition_drop": 0.1})


def test_output_shape_excludes_the_mask_class():
    model = small_model()
    tokens, mask, t, text, text_mask = inputs()
    logits = model(tokens, mask, t, text, text_mask)
    assert logits.shape == (3, 10, SMALL.codebook_size)
    assert torch.isfinite(logits).all()


def test_appended_motion_padding_does_not_change_real_positions():
    model = small_model()
    tokens, mask, t, text, text_mask = inputs()
    reference = model(tokens, mask, t, text, text_mask)
    padded_tokens = torch.cat([tokens, torch.randint(0, SMALL.codebook_size + 1, (3, 7))], dim=1)
    padded_mask = torch.cat([mask, torch.zeros(3, 7, dtype=torch.bool)], dim=1)
    padded = model(padded_tokens, padded_mask, t, text, text_mask)
    torch.testing.assert_close(padded[:, :10], reference, atol=1e-5, rtol=0)


def test_ragged_batch_matches_each_sample_alone():
    model = small_model()
    tokens, mask, t, text, text_mask = inputs()
    mask[1, 6:] = False
    together = model(tokens, mask, t, text, text_mask)
    alone = model(tokens[1:2, :6], None, t[1:2], text[1:2], text_mask[1:2])
    torch.testing.assert_close(together[1:2, :6], alone, atol=1e-5, rtol=0)


def test_appended_text_padding_does_not_change_logits():
    model = small_model()
    tokens, mask, t, text, text_mask = inputs()
    reference = model(tokens, mask, t, text, text_mask)
    padded_text = torch.cat([text, torch.randn(3, 4, SMALL.text_dim)], dim=1)
    padded_mask = torch.cat([text_mask, torch.zeros(3, 4, dtype=torch.bool)], dim=1)
    torch.testing.assert_close(model(tokens, mask, t, padded_text, padded_mask), reference, atol=1e-5, rtol=0)


def test_text_none_is_the_learned_null_condition():
    model = small_model()
    tokens, mask, t, text, text_mask = inputs()
    null_text, null_mask = model.null_condition(3)
    unconditional = model(tokens, mask, t)
    torch.testing.assert_close(unconditional, model(tokens, mask, t, null_text, null_mask))
    assert not torch.allclose(unconditional, model(tokens, mask, t, text, text_mask))
    unconditional.sum().backward()
    assert model.null_text.grad is not None and model.null_text.grad.abs().sum() > 0


def test_drop_condition_with_p_one_is_null_for_every_sample_and_p_zero_for_none():
    model = small_model()
    tokens, mask, t, text, text_mask = inputs()
    generator = torch.Generator().manual_seed(0)
    kept_text, kept_mask = model.drop_condition(text, text_mask, 0.0, generator)
    assert torch.equal(kept_text, text) and torch.equal(kept_mask, text_mask)
    dropped_text, dropped_mask = model.drop_condition(text, text_mask, 1.0, generator)
    assert dropped_text.shape == text.shape
    assert dropped_mask[:, 0].all() and not dropped_mask[:, 1:].any()
    torch.testing.assert_close(
        model(tokens, mask, t, dropped_text, dropped_mask), model(tokens, mask, t), atol=1e-5, rtol=0
    )


def test_drop_condition_rate_and_generator_reproducibility():
    model = small_model()
    text = torch.randn(4000, 2, SMALL.text_dim)
    text_mask = torch.ones(4000, 2, dtype=torch.bool)
    first = model.drop_condition(text, text_mask, 0.1, torch.Generator().manual_seed(5))[1]
    second = model.drop_condition(text, text_mask, 0.1, torch.Generator().manual_seed(5))[1]
    assert torch.equal(first, second)
    rate = (~first[:, 1]).float().mean().item()
    assert 0.08 < rate < 0.12


def test_relative_buckets_saturate_beyond_max_distance():
    offsets = torch.tensor([-10_000, -SMALL.max_distance, 0, 1, SMALL.max_distance - 1, SMALL.max_distance, 10_000])
    buckets = relative_position_bucket(offsets, SMALL.num_buckets, SMALL.max_distance).tolist()
    half = SMALL.num_buckets // 2
    assert buckets[0] == buckets[1] == half - 1
    assert buckets[2] == 0 and buckets[3] == half + 1
    assert buckets[5] == buckets[6] == SMALL.num_buckets - 1
    forward = relative_position_bucket(torch.arange(0, 300), SMALL.num_buckets, SMALL.max_distance)
    assert (forward.diff() >= 0).all() and forward.min() == 0 and forward.max() == SMALL.num_buckets - 1
    assert len(forward.unique()) == SMALL.num_buckets // 2  # offset 0, then half + 1 ... num_buckets - 1


def test_runs_on_four_times_the_training_length():
    model = small_model()
    train_length = 12
    tokens, mask, t, text, text_mask = inputs(batch=2, length=4 * train_length)
    logits = model(tokens, mask, t, text, text_mask)
    assert logits.shape == (2, 4 * train_length, SMALL.codebook_size)
    assert torch.isfinite(logits).all()
    # Far apart pairs all read the last bucket's bias, so the model never meets an unseen position.
    bias = model.relative_position_bias(4 * train_length, torch.device("cpu"))
    torch.testing.assert_close(
        bias[:, 0, SMALL.max_distance :],
        model.relative_bias.weight[-1][:, None].expand(-1, 4 * train_length - SMALL.max_distance),
    )


def test_guided_logits_is_the_papers_eq_9():
    """log p = (s + 1)·log p(c) − s·log p(∅): s = 0 is the conditional model alone, and s = 3 is
    VQ-Diffusion's u + 4·(c − u)."""
    cond = torch.randn(2, 5, 7)
    uncond = torch.randn(2, 5, 7)
    torch.testing.assert_close(guided_logits(cond, uncond, 0.0), torch.log_softmax(cond, -1))
    torch.testing.assert_close(guided_logits(cond, uncond, -1.0), torch.log_softmax(uncond, -1))
    expected = torch.log_softmax(4.0 * torch.log_softmax(cond, -1) - 3.0 * torch.log_softmax(uncond, -1), -1)
    torch.testing.assert_close(guided_logits(cond + 4.0, uncond - 2.0, 3.0), expected)
    torch.testing.assert_close(guided_logits(cond, uncond, 3.0), torch.log_softmax(uncond + 4.0 * (cond - uncond), -1))
    assert torch.allclose(guided_logits(cond, uncond, 3.0).exp().sum(-1), torch.ones(2, 5))


def test_eval_mode_is_deterministic_and_dropout_trains_stochastically():
    torch.manual_seed(0)
    model = MotionDenoiser(DenoiserConfig.from_dict({**SMALL.to_dict(), "dropout": 0.3})).eval()
    tokens, mask, t, text, text_mask = inputs()
    assert torch.equal(model(tokens, mask, t, text, text_mask), model(tokens, mask, t, text, text_mask))
    model.train()
    assert not torch.equal(model(tokens, mask, t, text, text_mask), model(tokens, mask, t, text, text_mask))


def test_timestep_changes_the_output():
    model = small_model()
    tokens, mask, t, text, text_mask = inputs()
    early = model(tokens, mask, torch.ones_like(t), text, text_mask)
    late = model(tokens, mask, torch.full_like(t, SMALL.steps), text, text_mask)
    assert not torch.allclose(early, late)


def test_bf16_autocast_gives_finite_logits_with_padding():
    model = small_model()
    tokens, mask, t, text, text_mask = inputs()
    mask[0, 4:] = False
    text_mask[0, 2:] = False
    with torch.autocast("cpu", dtype=torch.bfloat16):
        logits = model(tokens, mask, t, text, text_mask)
    assert torch.isfinite(logits.float()).all()
    torch.testing.assert_close(logits.float(), model(tokens, mask, t, text, text_mask), atol=0.1, rtol=0.1)


def test_under_autocast_the_attention_masks_come_in_its_dtype(monkeypatch):
    """The (B, heads, L, L) self-attention mask is built once in the dtype the attention computes in,
    so no block converts it (on CUDA autocast casts a float32 mask inside every attention call)."""
    model = small_model()
    tokens, mask, t, text, text_mask = inputs()
    seen = []
    attention = torch.nn.functional.scaled_dot_product_attention

    def recording(query, key, value, attn_mask=None, **options):
        seen.append((query.dtype, attn_mask.dtype))
        return attention(query, key, value, attn_mask=attn_mask, **options)

    monkeypatch.setattr(torch.nn.functional, "scaled_dot_product_attention", recording)
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
        model(tokens, mask, t, text, text_mask)
    assert seen and set(seen) == {(torch.bfloat16, torch.bfloat16)}


def test_every_attention_call_has_the_layout_a_gpu_s_fused_kernels_take(monkeypatch):
    """A GPU's fused attention kernels (cuDNN's, the memory-efficient one) need the last dimension
    of the queries, keys, values and mask at stride 1, or SDPA falls back to its math path: on an
    H200 the self-attention over 3,283 tokens took 8.1 ms a call there against 0.76 ms fused, and
    its mask — a permuted (L, L, heads) bias lookup — had stride 16 (BENCHMARKS.md, "On a GPU").
    A CPU takes any stride, so only this check sees it."""
    model = small_model()
    tokens, mask, t, text, text_mask = inputs()
    strides = []
    attention = torch.nn.functional.scaled_dot_product_attention

    def recording(query, key, value, attn_mask=None, **options):
        strides.append(tuple(x.stride(-1) for x in (query, key, value, attn_mask)))
        return attention(query, key, value, attn_mask=attn_mask, **options)

    monkeypatch.setattr(torch.nn.functional, "scaled_dot_product_attention", recording)
    with torch.no_grad():
        model(tokens, mask, t, text, text_mask)
    assert len(strides) == 2 * len(model.blocks) and set(strides) == {(1, 1, 1, 1)}


def test_paper_size_parameter_count_and_forward(capsys):
    torch.set_num_threads(4)
    torch.manual_seed(0)
    model = MotionDenoiser(DenoiserConfig()).eval()
    count = sum(p.numel() for p in model.parameters())
    assert 60_000_000 < count < 70_000_000
    tokens = torch.randint(0, 513, (2, 49))
    text = torch.randn(2, 77, 512)
    text_mask = torch.ones(2, 77, dtype=torch.bool)
    text_mask[1, 20:] = False
    with torch.no_grad():
        start = time.perf_counter()
        logits = model(tokens, None, torch.tensor([1, 100]), text, text_mask)
        elapsed = time.perf_counter() - start
    assert logits.shape == (2, 49, 512) and torch.isfinite(logits).all()
    with capsys.disabled():
        print(f"\npaper-size denoiser: {count:,} parameters, forward (2, 49) on CPU {elapsed * 1000:.0f} ms")


# --------------------------------------------------------------------- positions within the action
def trained_on_positions(positions: str, steps: int = 150) -> MotionDenoiser:
    """A tiny denoiser trained on all-[MASK] inputs whose target code is the position's index
    (clips of 4 to 8 tokens): the denoiser can learn it only if it knows where each token is."""
    torch.manual_seed(0)
    config = DenoiserConfig.from_dict({**SMALL.to_dict(), "positions": positions})
    model = MotionDenoiser(config)
    optimiser = torch.optim.Adam(model.parameters(), lr=3e-3)
    generator = torch.Generator().manual_seed(0)
    for _ in range(steps):
        lengths = torch.randint(4, 9, (16,), generator=generator)
        valid = torch.arange(8)[None, :] < lengths[:, None]
        tokens = torch.full((16, 8), config.codebook_size)
        targets = torch.arange(8).expand(16, -1)
        logits = model(tokens, valid, torch.full((16,), config.steps), None)
        loss = torch.nn.functional.cross_entropy(logits[valid], targets[valid])
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    return model.eval()


def test_all_mask_logits_tell_positions_apart_only_with_action_offsets():
    """The paper's relative bias alone gives every position of an all-[MASK] input the same logits
    (what the issue measured on the demo model: 2.6e-6 apart); offsets within the action let a
    trained denoiser tell them apart, and predict each position's own code."""
    tokens = torch.full((1, 8), SMALL.codebook_size)
    t = torch.tensor([SMALL.steps])
    models = {positions: trained_on_positions(positions) for positions in ("relative", "action")}
    with torch.no_grad():
        relative, action = (models[positions](tokens, None, t, None) for positions in ("relative", "action"))
    assert float((relative - relative[:, :1]).abs().max()) < 1e-4
    assert float((action - action[:, :1]).abs().max()) > 1.0
    assert torch.equal(action[0].argmax(dim=-1), torch.arange(8))


def test_action_offsets_restart_at_each_action_and_match_one_action_rows():
    from m2d2m.networks.m2d2m_denoiser import action_offsets, row_offsets

    offsets = action_offsets([[3, 2], [4]], 6)
    assert offsets[0, :, 0].tolist() == [0, 1, 2, 0, 1, 0] and offsets[0, :, 1].tolist() == [2, 1, 0, 1, 0, 0]
    assert offsets[1, :, 0].tolist() == [0, 1, 2, 3, 0, 0] and offsets[1, :, 1].tolist() == [3, 2, 1, 0, 0, 0]
    valid = torch.tensor([[True] * 4 + [False] * 2, [True] * 6])
    assert torch.equal(row_offsets(valid), action_offsets([[4], [6]], 6))


def test_a_joint_row_of_two_actions_sees_each_actions_offsets():
    """Two actions in one row (the joint phase) are embedded with their own offsets: the logits
    differ from reading the row as one action, and padding after the row still changes nothing."""
    torch.manual_seed(0)
    model = MotionDenoiser(DenoiserConfig.from_dict({**SMALL.to_dict(), "positions": "action"})).eval()
    tokens, _, t, text, text_mask = inputs(batch=1, length=10)
    from m2d2m.networks.m2d2m_denoiser import action_offsets

    with torch.no_grad():
        joint = model(tokens, None, t, text, text_mask, action_offsets([[4, 6]], 10))
        whole = model(tokens, None, t, text, text_mask)
        padded = model(
            torch.cat([tokens, tokens[:, :3]], 1),
            torch.arange(13)[None] < 10,
            t,
            text,
            text_mask,
            action_offsets([[4, 6]], 13),
        )
    assert not torch.allclose(joint, whole, atol=1e-3)
    torch.testing.assert_close(padded[:, :10], joint, atol=1e-5, rtol=0)


def test_codebook_embedding_projects_the_frozen_code_vectors_and_travels_in_the_state_dict():
    codebook = torch.randn(SMALL.codebook_size, 6, generator=torch.Generator().manual_seed(2))
    config = DenoiserConfig.from_dict({**SMALL.to_dict(), "embedding": "codebook", "code_dim": 6})
    torch.manual_seed(0)
    model = MotionDenoiser(config, codebook).eval()
    tokens = torch.tensor([[0, 3, SMALL.codebook_size, 3]])
    embedded = model.embed(tokens)
    torch.testing.assert_close(embedded[0, 1], model.code_projection(codebook[3]))
    torch.testing.assert_close(embedded[0, 3], embedded[0, 1])
    torch.testing.assert_close(embedded[0, 2], model.mask_vector)
    assert not any(name == "codebook" for name, _ in model.named_parameters())  # frozen: a buffer
    again = MotionDenoiser(config)  # a saved state dict brings the codebook
    again.load_state_dict(model.state_dict())
    torch.testing.assert_close(again.codebook, codebook)
    tokens, mask, t, text, text_mask = inputs()
    with torch.no_grad():
        torch.testing.assert_close(
            again.eval()(tokens, mask, t, text, text_mask), model(tokens, mask, t, text, text_mask)
        )
    with pytest.raises(ValueError, match=r"the codebook is \(16, 5\), the config asks for \(16, 6\)"):
        MotionDenoiser(config, torch.zeros(SMALL.codebook_size, 5))
