"""Samplers on a tiny, randomly initialised denoiser: the identities the paper's Algorithm 1 implies,
batch independence, editing, and the baselines' token layouts."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from torch._inductor.exc import InvalidCxxCompiler

from m2d2m.compiling import Compiled, bucket, compiles
from m2d2m.generators.m2d2m.options import M2D2MOptions
from m2d2m.generators.m2d2m.sampling import FREE, RowLayout, TokenRequest, TokenSampler, length_groups, truncate
from m2d2m.networks.m2d2m_denoiser import DenoiserConfig, MotionDenoiser
from m2d2m.processes.discrete_diffusion import TransitionSchedule, categorical
from m2d2m.text import LearnedTextEncoder

CODES, STEPS = 12, 10
WALK, JUMP, SIT = ["a person walks forward"], ["a person jumps"], ["a person sits down"]


@pytest.fixture(scope="module")
def sampler() -> TokenSampler:
    """Weights drawn wider than a real init (std 0.3), so outputs depend visibly on the condition."""
    torch.manual_seed(0)
    words = LearnedTextEncoder.build_vocabulary(WALK + JUMP + SIT)
    text = LearnedTextEncoder(words, dim=16, layers=1, heads=2, dropout=0.0)
    denoiser = MotionDenoiser(
        DenoiserConfig(
            codebook_size=CODES,
            layers=2,
            heads=2,
            width=32,
            ffn=64,
            text_dim=16,
            steps=STEPS,
            max_distance=16,
            num_buckets=8,
        )
    )
    with torch.no_grad():
        for module in (text, denoiser):
            for parameter in module.parameters():
                parameter.normal_(0.0, 0.3)
    schedule = TransitionSchedule.build(
        torch.randn(CODES, 4, generator=torch.Generator().manual_seed(1)), steps=STEPS, kind="dynamic", eta=0.5
    )
    return TokenSampler(denoiser, text, schedule)


def run(sampler: TokenSampler, requests: list[TokenRequest], **options) -> list[list[torch.Tensor]]:
    return sampler.sample(requests, M2D2MOptions(**{"ts": 6, **options}))


def flat(tokens: list[torch.Tensor]) -> torch.Tensor:
    return torch.cat(tokens)


def test_tps_with_ts_equal_to_T_is_independent_sampling(sampler):
    request = TokenRequest([WALK, JUMP, SIT], [6, 5, 7], seed=3)
    tps = run(sampler, [request], method="tps", ts=STEPS)[0]
    independent = run(sampler, [request], method="independent")[0]
    assert all(torch.equal(a, b) for a, b in zip(tps, independent))
    assert [len(x) for x in tps] == [6, 5, 7]


def test_tps_of_one_action_is_single_sampling(sampler):
    request = TokenRequest([WALK], [9], seed=5)
    results = [run(sampler, [request], method="tps", ts=ts)[0][0] for ts in (0, 4, STEPS)]
    assert all(torch.equal(results[0], other) for other in results[1:])
    assert results[0].min() >= 0 and results[0].max() < CODES


def test_joint_phase_attends_across_the_boundary(sampler):
    """Changing the second action's prompt changes the first action's tokens only under TPS (at
    some of five seeds: a draw may land on the same token either way)."""
    changed = []
    for seed in range(11, 16):
        before = TokenRequest([WALK, JUMP], [8, 8], seed=seed)
        after = TokenRequest([WALK, SIT], [8, 8], seed=seed)
        independent = [run(sampler, [r], method="independent")[0][0] for r in (before, after)]
        assert torch.equal(*independent)
        tps = [run(sampler, [r], method="tps", ts=STEPS // 2)[0][0] for r in (before, after)]
        changed.append(not torch.equal(tps[0][-3:], tps[1][-3:]))
    assert any(changed)


def test_length_groups_cover_every_row_once_with_bounded_padding():
    lengths = [49, 11, 23, 30, 12, 49, 37, 20, 15]
    groups = length_groups(lengths)
    assert sorted(i for g in groups for i in g) == list(range(len(lengths)))
    assert groups == [[0, 5, 6], [3, 2], [7, 8], [4, 1]]  # 49 49 37 | 30 23 | 20 15 | 12 11
    assert length_groups([5, 5, 5]) == [[0, 1, 2]] and length_groups([]) == []
    assert all(lengths[i] >= 0.75 * lengths[g[0]] for g in groups for i in g)


CPU = torch.device("cpu")


def test_row_layout_holds_both_phases_the_kept_tokens_and_the_length_groups():
    """TPS's joint rows (one per request, its sentences concatenated) then one row per action, both
    over the requests' streams one after another; the kept tokens stay through a step."""
    given = torch.full((11,), FREE)
    given[:2] = torch.tensor([4, 5])
    requests = [TokenRequest([WALK, JUMP], [5, 6], seed=1, given=given), TokenRequest([SIT], [3], seed=2)]
    layout = RowLayout.of(requests, M2D2MOptions(method="tps", ts=6), STEPS, CPU)
    joint, independent = layout.phases
    assert joint.jumps == [(10, 9), (9, 8), (8, 7), (7, 6)] and independent.jumps[-1] == (1, 0)
    assert [(r.request, r.condition, r.actions) for r in joint.rows] == [(0, WALK + JUMP, [5, 6]), (1, SIT, [3])]
    assert [(r.request, r.stream, r.condition) for r in independent.rows] == [
        (0, slice(0, 5), WALK),
        (0, slice(5, 11), JUMP),
        (1, slice(0, 3), SIT),
    ]
    assert layout.sizes == [11, 3] and joint.groups == [[0], [1]] and independent.groups == [[1, 0], [2]]
    z = torch.arange(14)
    batch = independent.batch(z, fill=-1)
    assert batch.tolist() == [[0, 1, 2, 3, 4, -1], [5, 6, 7, 8, 9, 10], [11, 12, 13, -1, -1, -1]]
    assert torch.equal(independent.tokens(batch), z) and torch.equal(joint.tokens(joint.batch(z, fill=-1)), z)
    assert layout.settle(torch.full((14,), 9)).tolist() == [4, 5] + [9] * 12
    assert [[x.tolist() for x in actions] for actions in layout.split(z)] == [
        [[0, 1, 2, 3, 4], list(range(5, 11))],
        [[11, 12, 13]],
    ]
    assert [
        len(p.jumps) for p in RowLayout.of(requests, M2D2MOptions(method="independent", steps=4), STEPS, CPU).phases
    ] == [4]


def test_row_layout_shares_tokens_between_neighbours_under_handshake():
    """Every later action's row starts with a copy of the previous action's last H tokens: a step
    blends their x0 probabilities with the ramp and copies the earlier draws; the copies are
    dropped from the result."""
    layout = RowLayout.of(
        [TokenRequest([WALK, JUMP, SIT], [4, 3, 5])], M2D2MOptions(method="handshake", handshake=2), STEPS, CPU
    )
    (phase,) = layout.phases
    assert layout.sizes == [16] and [r.stream for r in phase.rows] == [slice(0, 4), slice(4, 9), slice(9, 16)]
    z = layout.settle(torch.arange(16))
    assert z.tolist() == [0, 1, 2, 3, 2, 3, 6, 7, 8, 7, 8, 11, 12, 13, 14, 15]
    assert [x.tolist() for x in layout.split(z)[0]] == [[0, 1, 2, 3], [6, 7, 8], [11, 12, 13, 14, 15]]
    x0 = torch.rand(16, CODES, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    blended = layout.blend(x0.clone())
    for earlier, later, ramp in ((2, 4, 0.0), (3, 5, 0.5), (7, 9, 0.0), (8, 10, 0.5)):
        mixed = (1 - ramp) * x0[earlier] + ramp * x0[later]
        assert torch.equal(blended[earlier], mixed) and torch.equal(blended[later], mixed)
    untouched = [0, 1, 6, 11, 12, 13, 14, 15]
    assert torch.equal(blended[untouched], x0[untouched])


def test_batched_sampling_matches_one_by_one(sampler):
    requests = [
        TokenRequest([WALK, JUMP], [5, 7], seed=1),
        TokenRequest([SIT], [4], seed=2),
        TokenRequest([JUMP, SIT, WALK], [3, 6, 2], seed=3),
    ]
    for method in ("tps", "independent", "handshake", "slerp"):
        extra = {"handshake": 2} if method == "handshake" else {}
        batched = run(sampler, requests, method=method, ts=6, **extra)
        alone = [run(sampler, [r], method=method, ts=6, **extra)[0] for r in requests]
        for many, one in zip(batched, alone):
            assert all(torch.equal(a, b) for a, b in zip(many, one)), method


@pytest.mark.parametrize("method", ["tps", "independent", "handshake"])
def test_editing_keeps_given_tokens(sampler, method):
    lengths = [6, 6]
    given = torch.full((12,), FREE)
    given[:3] = torch.tensor([1, 2, 3])  # prefix
    given[-2:] = torch.tensor([7, 0])  # suffix; the middle is in-betweened
    tokens = flat(
        run(sampler, [TokenRequest([WALK, JUMP], lengths, seed=4, given=given)], method=method, ts=5, handshake=2)[0]
    )
    kept = given != FREE
    assert torch.equal(tokens[kept], given[kept])
    assert tokens.min() >= 0 and tokens.max() < CODES


def test_handshake_and_slerp_lengths(sampler):
    request = TokenRequest([WALK, JUMP, SIT], [6, 5, 7], seed=0)
    handshake = run(sampler, [request], method="handshake", handshake=3)[0]
    assert [len(x) for x in handshake] == [6, 5, 7]
    slerp = run(sampler, [request], method="slerp", slerp=2)[0]
    assert [len(x) for x in slerp] == [6, 3, 5]
    with pytest.raises(ValueError, match="at least 6 tokens"):
        run(sampler, [request], method="handshake", handshake=6)


def test_seeds_matter_and_repeat(sampler):
    first = run(sampler, [TokenRequest([WALK], [10], seed=0)])[0][0]
    again = run(sampler, [TokenRequest([WALK], [10], seed=0)])[0][0]
    other = run(sampler, [TokenRequest([WALK], [10], seed=1)])[0][0]
    assert torch.equal(first, again) and not torch.equal(first, other)


def test_eta_and_truncation_change_samples(sampler):
    request = [TokenRequest([WALK, JUMP], [8, 8], seed=2)]
    base = flat(run(sampler, request)[0])
    assert not torch.equal(base, flat(sampler.sample(request, M2D2MOptions(ts=6, eta=3.0))[0]))
    assert not torch.equal(base, flat(run(sampler, request, truncation=0.3)[0]))
    assert sampler.schedule.config.eta == 0.5  # a sampling-time η never changes the model's schedule


@pytest.mark.parametrize(
    "options, message",
    [
        ({"method": "blend"}, "unknown method"),
        ({"ts": STEPS + 1}, "T_s must lie"),
        ({"guidance": -1.0}, "guidance"),
        ({"truncation": 0.0}, "truncation"),
    ],
)
def test_bad_options(sampler, options, message):
    with pytest.raises(ValueError, match=message):
        run(sampler, [TokenRequest([WALK], [4])], **options)
    with pytest.raises(ValueError, match="eta"):
        sampler.sample([TokenRequest([WALK], [4])], M2D2MOptions(eta=-0.1))


def test_bad_requests():
    with pytest.raises(ValueError, match="one length per action"):
        TokenRequest([WALK, JUMP], [4])
    with pytest.raises(ValueError, match="at least one token"):
        TokenRequest([WALK], [0])
    with pytest.raises(ValueError, match="given must hold 4"):
        TokenRequest([WALK], [4], given=torch.zeros(5, dtype=torch.long))


def test_truncate_keeps_the_top_mass():
    probs = torch.tensor([[0.1, 0.5, 0.3, 0.1]], dtype=torch.float64)
    assert torch.allclose(truncate(probs, 0.7), torch.tensor([[0.0, 0.625, 0.375, 0.0]], dtype=torch.float64))
    assert torch.allclose(truncate(probs, 0.4), torch.tensor([[0.0, 1.0, 0.0, 0.0]], dtype=torch.float64))
    assert truncate(probs, 1.0) is probs


def test_an_empty_sentence_samples_under_the_null_condition(sampler, monkeypatch):
    """Editing "without text" asks with ""; the denoiser must then see its learned null condition,
    exactly what classifier-free training drops a caption to, for that row and no other."""
    denoiser = sampler.denoiser
    text, mask = torch.randn(3, 5, 16), torch.ones(3, 5, dtype=torch.bool)
    nulled, null_mask = denoiser.nullify(text, mask, torch.tensor([True, False, True]))
    dropped, dropped_mask = denoiser.drop_condition(text, mask, 1.0)
    assert torch.equal(nulled[0], dropped[0]) and torch.equal(null_mask[2], dropped_mask[2])
    assert torch.equal(nulled[1], text[1]) and torch.equal(null_mask[1], mask[1])

    seen = []
    original = type(denoiser).condition

    def spying(self, condition, condition_mask, batch=None):
        seen.append((condition.clone(), condition_mask.clone()))
        return original(self, condition, condition_mask, batch)

    monkeypatch.setattr(type(denoiser), "condition", spying)
    run(
        sampler,
        [TokenRequest([[""]], [5], seed=1), TokenRequest([WALK], [5], seed=1)],
        method="independent",
        guidance=0.0,
    )
    condition, condition_mask = seen[0]
    assert torch.equal(condition_mask[0], torch.arange(condition.shape[1]) == 0)
    assert torch.equal(condition[0, 0], denoiser.null_text.reshape(-1))
    assert condition_mask[1].sum() == len(WALK[0].split())


# ------------------------------------------------------------------ reuse of the condition, fewer steps
@pytest.mark.parametrize("method,guidance", [("tps", 2.0), ("independent", 0.0), ("handshake", 4.0)])
def test_reusing_the_condition_changes_no_token(sampler, method, guidance):
    """The text's keys and values computed once per phase give what recomputing them at every step
    gives, token for token, for several requests of several lengths."""
    requests = [TokenRequest([WALK, JUMP, SIT], [6, 5, 7], seed=3), TokenRequest([SIT, WALK], [9, 6], seed=4)]
    options = M2D2MOptions(method=method, ts=6, guidance=guidance, handshake=2)
    fresh = TokenSampler(sampler.denoiser, sampler.text_encoder, sampler.schedule, reuse_condition=False)
    reused = sampler.sample(requests, options)
    recomputed = fresh.sample(requests, options)
    assert all(torch.equal(a, b) for x, y in zip(reused, recomputed) for a, b in zip(x, y))


def test_all_steps_is_the_one_step_reverse_process_draw_for_draw(sampler):
    """steps = T takes every one-step posterior with the request's own uniforms: a loop written
    here from the paper's reverse step (eq. 4) gives the same tokens."""
    from m2d2m.networks.m2d2m_denoiser import guided_logits
    from m2d2m.text import encode_actions

    request = TokenRequest([JUMP], [9], seed=7)
    sampled = sampler.sample([request], M2D2MOptions(method="independent", guidance=2.0, steps=STEPS))[0][0]
    schedule, denoiser = sampler.schedule, sampler.denoiser
    generator = torch.Generator().manual_seed(7)
    z = schedule.sample_prior((9,), generator=generator)
    text, text_mask = encode_actions(sampler.text_encoder, [JUMP])
    with torch.no_grad():
        for t in range(STEPS, 0, -1):
            steps = torch.tensor([t])
            cond = denoiser(z[None], None, steps, text, text_mask)
            uncond = denoiser(z[None], None, steps, None)
            x0 = guided_logits(cond, uncond, 2.0).double().exp()[0]
            z = categorical(schedule.posterior_probs(z, x0, t), torch.rand(9, generator=generator, dtype=torch.float64))
            if t == 1:
                z = torch.where(z == CODES, x0.argmax(dim=-1), z)
    assert torch.equal(sampled, z)


def test_timestep_grid_keeps_T_s_and_scales_both_phases():
    from m2d2m.generators.m2d2m.sampling import timesteps

    joint, independent = timesteps(100, None, 90)
    assert joint == [(t, t - 1) for t in range(100, 90, -1)] and independent == [(t, t - 1) for t in range(90, 0, -1)]
    for taken in (50, 25, 10, 5):
        joint, independent = timesteps(100, taken, 90)
        jumps = joint + independent
        assert jumps[0][0] == 100 and jumps[-1][1] == 0 and joint[-1][1] == 90 == independent[0][0]
        assert all(a[1] == b[0] for a, b in zip(jumps, jumps[1:])) and len(jumps) == taken
        lengths = {t - s for t, s in independent}
        assert max(lengths) - min(lengths) <= 1  # as even as whole steps allow
    assert timesteps(100, 10, 100) == ([], [(100 - 10 * i, 90 - 10 * i) for i in range(10)])
    assert timesteps(100, 4, 0) == ([(100, 75), (75, 50), (50, 25), (25, 0)], [])
    with pytest.raises(ValueError):
        timesteps(100, 0, 90)


def test_fewer_steps_sample_every_position_reproducibly(sampler):
    requests = [TokenRequest([WALK, JUMP], [6, 8], seed=2)]
    for steps in (1, 3, STEPS // 2):
        options = M2D2MOptions(method="tps", ts=6, steps=steps)
        first, again = sampler.sample(requests, options), sampler.sample(requests, options)
        assert all(torch.equal(a, b) for a, b in zip(first[0], again[0]))
        assert all(0 <= int(x.min()) and int(x.max()) < CODES for x in first[0])
    seen = []
    sampler.sample(requests, M2D2MOptions(method="tps", ts=6, steps=4), progress=seen.append)
    assert seen == sorted(seen, reverse=True) and seen[-1] == 0 and 6 in seen
    with pytest.raises(ValueError, match="steps must lie in 1..T"):
        sampler.sample(requests, M2D2MOptions(steps=STEPS + 1))


# ---------------------------------------------------------------------------------- compiled sampling
def test_buckets_pad_by_under_a_half_to_few_sizes():
    assert [bucket(n) for n in range(1, 14)] == [1, 2, 3, 4, 6, 6, 8, 8, 12, 12, 12, 12, 16]
    assert bucket(49) == 64 and bucket(3283) == 4096 and bucket(3, smallest=8) == 8
    assert all(n <= bucket(n) < 1.5 * n or bucket(n) <= 2 for n in range(1, 5000))
    assert len({bucket(n) for n in range(1, 5000)}) == 25  # 1, 2, 3, 4, 6, 8, …, 4096, 6144


def bucketed(sampler: TokenSampler, monkeypatch, compiled) -> TokenSampler:
    """A sampler of the same model whose ``torch.compile`` is ``compiled`` (a stand-in)."""
    monkeypatch.setattr(torch, "compile", lambda function, **options: compiled(function))
    return TokenSampler(sampler.denoiser, sampler.text_encoder, sampler.schedule)


REQUESTS = [
    TokenRequest([WALK, JUMP, SIT], [6, 5, 7], seed=3),
    TokenRequest([SIT, [""]], [9, 13], seed=4),
    TokenRequest([JUMP], [2], seed=5),
]


@pytest.mark.parametrize("method", ["tps", "handshake", "slerp"])
def test_passes_padded_to_buckets_change_no_token(sampler, monkeypatch, method):
    """What compiling adds to the sampler — rows, tokens and text padded to buckets — leaves every
    real position's logits equal to float32 rounding (here with eager kernels): the same draws."""
    padded_passes = []

    def recording(function):
        def run(tokens, valid, t, condition, offsets):
            padded_passes.append(tuple(tokens.shape))
            return function(tokens, valid, t, condition, offsets)

        return run

    options = M2D2MOptions(method=method, ts=6, handshake=2, compile="on")
    eager = sampler.sample(REQUESTS, replace(options, compile="off"))
    padded = bucketed(sampler, monkeypatch, recording).sample(REQUESTS, options)
    assert all(torch.equal(a, b) for x, y in zip(eager, padded) for a, b in zip(x, y))
    assert padded_passes and all(rows == 2 * bucket(rows // 2) and width >= 8 for rows, width in padded_passes)
    assert len(set(padded_passes)) < len(padded_passes)  # steps reuse their shapes


def test_a_compiler_that_fails_leaves_eager_sampling_and_one_logged_line(sampler, monkeypatch, caplog):
    def failing(function):
        def run(*args):
            raise InvalidCxxCompiler()

        return run

    options = M2D2MOptions(ts=6, compile="on")
    fallback = bucketed(sampler, monkeypatch, failing)
    with caplog.at_level("WARNING", logger="m2d2m.compiling"):
        first, again = fallback.sample(REQUESTS, options), fallback.sample(REQUESTS, options)
    eager = sampler.sample(REQUESTS, replace(options, compile="off"))
    assert all(torch.equal(a, b) for x, y in zip(eager, first) for a, b in zip(x, y))
    assert all(torch.equal(a, b) for x, y in zip(first, again) for a, b in zip(x, y))
    assert [record.getMessage() for record in caplog.records] == [
        f"torch.compile failed (InvalidCxxCompiler: {InvalidCxxCompiler()}); the denoiser runs eagerly"
    ]


def test_auto_compiles_on_cuda_only():
    assert compiles("auto", torch.device("cuda")) and not compiles("auto", torch.device("cpu"))
    assert compiles("on", torch.device("cpu")) and not compiles("off", torch.device("cuda"))


@pytest.mark.slow
def test_compiled_sampling_matches_eager(sampler):
    """torch.compile's inductor on the CPU (a C++ compiler builds the kernels: about a minute for
    each of the two shapes here): the denoiser's logits equal eager ones within 1e-5 at the padded
    shapes, and the draws are the same. Slow: compiling takes a minute or more on two cores."""
    request = [TokenRequest([WALK, JUMP], [6, 5], seed=3)]
    options = M2D2MOptions(method="tps", ts=6, compile="on")
    compiled = TokenSampler(sampler.denoiser, sampler.text_encoder, sampler.schedule)
    tokens = compiled.sample(request, options)
    assert isinstance(compiled._compiled, Compiled) and compiled._compiled.compiled
    eager = sampler.sample(request, replace(options, compile="off"))
    assert all(torch.equal(a, b) for a, b in zip(tokens[0], eager[0]))

    denoiser = sampler.denoiser
    z = torch.randint(0, CODES + 1, (4, 8), generator=torch.Generator().manual_seed(0))
    valid = torch.arange(8)[None, :] < torch.tensor([8, 6, 8, 3])[:, None]
    text = torch.randn(4, 8, 16, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        condition = denoiser.condition(text, torch.ones(4, 8, dtype=torch.bool))
        args = (z, valid, torch.tensor([4]), condition, None)
        torch.testing.assert_close(compiled._compiled(*args), denoiser.denoise(*args), atol=1e-5, rtol=0)
