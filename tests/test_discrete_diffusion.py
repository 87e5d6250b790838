"""Brute-force checks of the discrete diffusion (m2d2m/processes/discrete_diffusion.py) on a small codebook.

Everything is rebuilt here with plain Python loops straight from the definitions (docs/training.md
"Diffusion", paper Eq. 7–8) and compared with the vectorised implementation.
"""

from __future__ import annotations

import itertools
import math

import pytest
import torch

from m2d2m.processes.discrete_diffusion import TransitionSchedule, categorical
from m2d2m.processes.discrete_diffusion_loss import TimestepSampler, diffusion_loss

K = 6
T = 5
ETA = 3.0  # large, so that the asymmetry of the dynamic β-block is pronounced


@pytest.fixture(scope="module")
def codebook() -> torch.Tensor:
    return torch.randn(K, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)


# ---------------------------------------------------------------------------------------------
# Reference construction with loops


def ref_scalars(schedule: str) -> tuple[list[float], list[float]]:
    """Per-step α_t, γ_t (index t = 1..T; index 0 unused) from the linear cumulative schedules."""
    a_end, g_end = {"linear": (0.000009, 0.9), "absorbing": (0.000009, 0.99999)}[schedule]
    a_bar = [1.0] + [0.99999 + (t - 1) / (T - 1) * (a_end - 0.99999) for t in range(1, T + 1)]
    g_bar = [0.0] + [0.000009 + (t - 1) / (T - 1) * (g_end - 0.000009) for t in range(1, T + 1)]
    alpha = [1.0] + [a_bar[t] / a_bar[t - 1] for t in range(1, T + 1)]
    gamma = [0.0] + [1 - (1 - g_bar[t]) / (1 - g_bar[t - 1]) for t in range(1, T + 1)]
    return alpha, gamma


def ref_distance(codebook: torch.Tensor, distance: str) -> list[list[float]]:
    """d[n][m] by loops: ranks by sorting, raw distances scaled by (K − 1)/max."""
    codes = codebook.tolist()

    def raw(n: int, m: int) -> float:
        if n == m:
            return 0.0
        if distance.startswith("l2"):
            return math.sqrt(sum((a - b) ** 2 for a, b in zip(codes[n], codes[m])))
        dot = sum(a * b for a, b in zip(codes[n], codes[m]))
        norm = math.sqrt(sum(a * a for a in codes[n])) * math.sqrt(sum(b * b for b in codes[m]))
        return 1 - dot / norm

    if distance.endswith("_rank"):
        table = [[0.0] * K for _ in range(K)]
        for n in range(K):
            for rank, m in enumerate(sorted(range(K), key=lambda m: (raw(n, m), m != n, m))):
                table[n][m] = float(rank)
        return table
    largest = max(raw(n, m) for n in range(K) for m in range(K))
    return [[raw(n, m) * (K - 1) / largest for m in range(K)] for n in range(K)]


def ref_step(codebook: torch.Tensor, kind: str, distance: str, schedule: str, eta: float) -> list[list[list[float]]]:
    """Q_t[i][j] for t = 0..T (index 0 the identity), by loops."""
    alpha, gamma = ref_scalars(schedule)
    d = ref_distance(codebook, distance)
    mats = [[[float(i == j) for j in range(K + 1)] for i in range(K + 1)]]
    for t in range(1, T + 1):
        q = [[0.0] * (K + 1) for _ in range(K + 1)]
        mass = 1 - alpha[t] - gamma[t]
        for j in range(K):  # source code
            if kind == "uniform":
                share = [1 / K] * K
            else:
                ex = [math.exp(eta * (t / T) * (d[j][m] / K)) for m in range(K)]
                share = [e / sum(ex) for e in ex]
            for i in range(K):
                q[i][j] = mass * share[i] + (alpha[t] if i == j else 0.0)
            q[K][j] = gamma[t]
        q[K][K] = 1.0
        mats.append(q)
    return mats


def matmul(a: list[list[float]], b: list[list[float]]) -> list[list[float]]:
    return [[sum(a[i][k] * b[k][j] for k in range(len(b))) for j in range(len(b[0]))] for i in range(len(a))]


def ref_cumulative(steps: list[list[list[float]]]) -> list[list[list[float]]]:
    cum = [steps[0]]
    for t in range(1, T + 1):
        cum.append(matmul(steps[t], cum[-1]))
    return cum


def path_marginals(steps: list[list[list[float]]], z0: int) -> list[list[float]]:
    """marg[t][i] = q(z_t = i | z0) by summing the probability of every path z0 → z_1 → … → z_T."""
    marg = [[0.0] * (K + 1) for _ in range(T + 1)]
    marg[0][z0] = 1.0
    for t in range(1, T + 1):
        for path in itertools.product(range(K + 1), repeat=t):
            p, prev = 1.0, z0
            for s, state in enumerate(path, start=1):
                p *= steps[s][state][prev]
                prev = state
            marg[t][path[-1]] += p
    return marg


def close(a: torch.Tensor, b: list, tol: float = 1e-6) -> bool:
    return torch.allclose(a.cpu().double(), torch.tensor(b, dtype=torch.float64), atol=tol, rtol=0)


# ---------------------------------------------------------------------------------------------
# Matrices


@pytest.mark.parametrize("schedule", ["linear", "absorbing"])
@pytest.mark.parametrize(
    "kind,distance",
    [
        ("uniform", "l2_rank"),
        ("dynamic", "l2_rank"),
        ("dynamic", "l2"),
        ("dynamic", "cosine"),
        ("dynamic", "cosine_rank"),
    ],
)
def test_step_and_cumulative_matrices(codebook, kind, distance, schedule):
    sched = TransitionSchedule.build(codebook, steps=T, kind=kind, eta=ETA, distance=distance, schedule=schedule)
    steps = ref_step(codebook, kind, distance, schedule, ETA)
    cum = ref_cumulative(steps)
    for t in range(1, T + 1):
        q = sched.step_matrix(t)
        assert q.dtype == torch.float64 and q.shape == (K + 1, K + 1)
        assert close(q, steps[t])
        assert (q.sum(dim=0) - 1).abs().max() < 1e-9
    for t in range(0, T + 1):
        assert close(sched.cumulative_matrix(t), cum[t])
        assert (sched.cumulative_matrix(t).sum(dim=0) - 1).abs().max() < 1e-9
    assert torch.equal(sched.cumulative_matrix(0), torch.eye(K + 1, dtype=torch.float64))


def test_dynamic_block_is_asymmetric_and_far_codes_gain_mass(codebook):
    sched = TransitionSchedule.build(codebook, steps=T, eta=ETA)
    block = sched.step_matrix(T)[:K, :K] - torch.diag(sched.alpha[T].expand(K))
    assert not torch.allclose(block, block.T)
    ranks = sched.distances
    for n in range(K):  # paper: higher probability for greater distances as t grows
        near, far = int(torch.argmin(ranks[n] + 100 * (ranks[n] == 0))), int(torch.argmax(ranks[n]))
        assert block[far, n] > block[near, n]
    assert torch.equal(torch.diagonal(ranks), torch.zeros(K, dtype=torch.float64))


@pytest.mark.parametrize("distance", ["l2_rank", "l2", "cosine", "cosine_rank"])
def test_dynamic_with_zero_eta_is_uniform(codebook, distance):
    dynamic = TransitionSchedule.build(codebook, steps=T, eta=0.0, distance=distance)
    uniform = TransitionSchedule.build(codebook, steps=T, kind="uniform")
    for t in range(1, T + 1):
        assert torch.allclose(dynamic.step_matrix(t), uniform.step_matrix(t), atol=1e-15, rtol=0)
        assert torch.allclose(dynamic.cumulative_matrix(t), uniform.cumulative_matrix(t), atol=1e-12, rtol=0)


def test_mask_is_absorbing_and_end_of_schedule(codebook):
    linear = TransitionSchedule.build(codebook, steps=T, eta=ETA)
    absorbing = TransitionSchedule.build(codebook, steps=T, eta=ETA, schedule="absorbing")
    e_mask = torch.zeros(K + 1, dtype=torch.float64)
    e_mask[K] = 1.0
    for sched in (linear, absorbing):
        for t in range(1, T + 1):
            assert torch.equal(sched.step_matrix(t)[:, K], e_mask)
            assert torch.equal(sched.cumulative_matrix(t)[:, K], e_mask)
    assert torch.allclose(absorbing.cumulative_matrix(T)[K, :K], torch.full((K,), 0.99999, dtype=torch.float64))
    assert torch.allclose(linear.cumulative_matrix(T)[K, :K], torch.full((K,), 0.9, dtype=torch.float64))
    # codes that survive unmasked (mass 1 − γ̄_T = 0.1) are almost all replaced ones, since ᾱ_T ≈ 1e-5
    block = linear.cumulative_matrix(T)[:K, :K]
    assert torch.allclose(block.sum(0), torch.full((K,), 0.1, dtype=torch.float64))
    assert torch.all(block.sum(0) - torch.diagonal(block) > 0.08)


def test_with_eta_equals_fresh_build(codebook):
    base = TransitionSchedule.build(codebook, steps=T, eta=0.5, distance="cosine")
    again = base.with_eta(1.7)
    fresh = TransitionSchedule.build(codebook, steps=T, eta=1.7, distance="cosine")
    assert again.config == fresh.config
    for t in range(0, T + 1):
        assert torch.equal(again.cumulative_matrix(t), fresh.cumulative_matrix(t))
    assert base.config.eta == 0.5
    with pytest.raises(ValueError):
        TransitionSchedule.build(codebook, steps=T, kind="uniform").with_eta(1.0)


def test_to_moves_cache(codebook):
    sched = TransitionSchedule.build(codebook, steps=T).to("cpu")
    assert sched.device.type == "cpu" and sched.step_matrix(1).device.type == "cpu"


# ---------------------------------------------------------------------------------------------
# Marginals, posteriors, sampling


@pytest.fixture(scope="module")
def dynamic(codebook) -> TransitionSchedule:
    return TransitionSchedule.build(codebook, steps=T, eta=ETA, distance="l2_rank")


@pytest.fixture(scope="module")
def marginals(codebook) -> list[list[list[float]]]:
    """marginals[z0][t][i] = q(z_t = i | z0) by path enumeration."""
    steps = ref_step(codebook, "dynamic", "l2_rank", "linear", ETA)
    return [path_marginals(steps, z0) for z0 in range(K)]


def test_marginals_match_path_enumeration(dynamic, marginals):
    for z0 in range(K):
        for t in range(T + 1):
            assert close(dynamic.cumulative_matrix(t)[:, z0], marginals[z0][t])


def ref_posterior(codebook, marginals, z_t: int, z0: int, t: int) -> list[float]:
    """q(z_{t−1} | z_t, z0) by Bayes' rule from the enumerated joint q(z_{t−1}, z_t | z0)."""
    steps = ref_step(codebook, "dynamic", "l2_rank", "linear", ETA)
    joint = [marginals[z0][t - 1][j] * steps[t][z_t][j] for j in range(K + 1)]
    total = sum(joint)
    return [p / total for p in joint]


def test_true_posterior_by_bayes(codebook, dynamic, marginals):
    for t in range(1, T + 1):
        for z0 in range(K):
            for z_t in range(K + 1):
                onehot = torch.zeros(K, dtype=torch.float64)
                onehot[z0] = 1.0
                got = dynamic.posterior_probs(torch.tensor(z_t), onehot, t)
                assert close(got, ref_posterior(codebook, marginals, z_t, z0, t))


def test_posterior_probs_mixture_batched_over_positions_and_t(codebook, dynamic, marginals):
    gen = torch.Generator().manual_seed(1)
    z_t = torch.randint(0, K + 1, (3, 4), generator=gen)
    z_t[0, 0] = K
    t = torch.randint(1, T + 1, (3, 4), generator=gen)
    x0 = torch.softmax(torch.randn(3, 4, K, generator=gen, dtype=torch.float64), dim=-1)
    got = dynamic.posterior_probs(z_t, x0, t)
    assert got.shape == (3, 4, K + 1)
    for b in range(3):
        for n in range(4):
            expected = [0.0] * (K + 1)
            for z0 in range(K):
                post = ref_posterior(codebook, marginals, int(z_t[b, n]), z0, int(t[b, n]))
                expected = [e + float(x0[b, n, z0]) * p for e, p in zip(expected, post)]
            assert close(got[b, n], expected)
            assert abs(float(got[b, n].sum()) - 1) < 1e-9
    # a per-sample t broadcast over positions gives the same as t spelled out per position
    per_sample = torch.tensor([[2], [5], [1]])
    assert torch.allclose(
        dynamic.posterior_probs(z_t, x0, per_sample), dynamic.posterior_probs(z_t, x0, per_sample.expand(3, 4))
    )


def test_true_posterior_is_the_mixture_at_a_one_hot_x0(dynamic):
    """The loss's target by gathers alone equals the mixture's batched product at a one-hot x0 bit
    for bit (one nonzero term), for t per sample, per position and one int."""
    gen = torch.Generator().manual_seed(11)
    z0 = torch.randint(0, K, (3, 4), generator=gen)
    onehot = torch.nn.functional.one_hot(z0, K).double()
    for t in (torch.tensor([[1], [3], [5]]), torch.randint(1, T + 1, (3, 4), generator=gen), 4):
        z_t = dynamic.q_sample(z0, t, generator=gen)
        assert torch.equal(dynamic.true_posterior(z_t, z0, t), dynamic.posterior_probs(z_t, onehot, t))


def test_unchecked_routes_equal_the_checked_ones_which_refuse_bad_inputs(dynamic):
    """``validate=False`` (the training step's and the sampler's route) only skips the range
    checks, which read the tensors on the host."""
    gen = torch.Generator().manual_seed(12)
    z_t = torch.randint(0, K + 1, (3, 4), generator=gen)
    x0 = torch.softmax(torch.randn(3, 4, K, generator=gen, dtype=torch.float64), dim=-1)
    t = torch.tensor([[2], [5], [1]])
    assert torch.equal(dynamic.posterior_probs(z_t, x0, t, validate=False), dynamic.posterior_probs(z_t, x0, t))
    z0 = z_t.clamp_max(K - 1)
    first, again = (dynamic.q_sample(z0, t, torch.Generator().manual_seed(1), validate=v) for v in (True, False))
    assert torch.equal(first, again)
    with pytest.raises(ValueError, match="t must lie in 1..5"):
        dynamic.posterior_probs(z_t, x0, torch.tensor([[0], [5], [1]]))
    with pytest.raises(ValueError, match="t must lie in 1..5"):
        dynamic.posterior_probs(z_t, x0, 6)
    with pytest.raises(ValueError, match="z_t values must lie in 0..6"):
        dynamic.posterior_probs(z_t + 1, x0, t)
    with pytest.raises(ValueError, match="z0 values must lie in 0..5"):
        dynamic.q_sample(z_t, 2)


def span_by_paths(steps: list[list[list[float]]], t: int, s: int) -> list[list[float]]:
    """q(z_t = i | z_s = j) by summing every path j → z_{s+1} → … → z_t = i of one-step moves."""
    span = [[0.0] * (K + 1) for _ in range(K + 1)]
    for j in range(K + 1):
        for path in itertools.product(range(K + 1), repeat=t - s):
            p, prev = 1.0, j
            for r, state in enumerate(path, start=s + 1):
                p *= steps[r][state][prev]
                prev = state
            span[path[-1]][j] += p
    return span


@pytest.mark.parametrize("t,s", [(5, 2), (4, 0), (3, 1), (5, 4)])
def test_skip_posterior_matches_brute_force_paths(codebook, dynamic, marginals, t, s):
    """q(z_s | z_t, z0) over a jump of Δ = t − s steps, by Bayes' rule on the path sums of one-step
    matrices (q(z_s | z0) from the enumerated marginals), for every z_t and z0; and the mixture
    under predicted x0 probabilities."""
    steps = ref_step(codebook, "dynamic", "l2_rank", "linear", ETA)
    span = span_by_paths(steps, t, s)
    assert close(dynamic.span_matrix(t, s), span)
    x0 = torch.softmax(torch.randn(K, generator=torch.Generator().manual_seed(t), dtype=torch.float64), dim=0)
    for z_t in range(K + 1):
        mixture = [0.0] * (K + 1)
        for z0 in range(K):
            joint = [marginals[z0][s][j] * span[z_t][j] for j in range(K + 1)]
            total = sum(joint)
            truth = [p / total for p in joint] if total > 0 else [0.0] * (K + 1)
            onehot = torch.zeros(K, dtype=torch.float64)
            onehot[z0] = 1.0
            if total > 0:
                assert close(dynamic.posterior_probs(torch.tensor(z_t), onehot, t, s), truth)
            mixture = [m + float(x0[z0]) * p for m, p in zip(mixture, truth)]
        assert close(dynamic.posterior_probs(torch.tensor(z_t), x0, t, s), mixture)


def test_one_step_jumps_are_the_one_step_posterior(dynamic):
    gen = torch.Generator().manual_seed(8)
    z_t = torch.randint(0, K + 1, (7,), generator=gen)
    x0 = torch.softmax(torch.randn(7, K, generator=gen, dtype=torch.float64), dim=-1)
    for t in range(1, T + 1):
        assert torch.equal(dynamic.posterior_probs(z_t, x0, t, t - 1), dynamic.posterior_probs(z_t, x0, t))
        assert torch.equal(dynamic.span_matrix(t, t - 1), dynamic.step_matrix(t))
    with pytest.raises(ValueError, match="0 <= s < t"):
        dynamic.span_matrix(3, 3)


@pytest.mark.parametrize("t,s", [(5, 4), (4, 1), (2, 0), (1, 0)])
def test_step_draws_from_the_brute_force_posterior(codebook, dynamic, marginals, t, s):
    """step(z_t, x0, t, s, u) is the inverse-CDF draw with u of Σ_k q(z_s | z_t, z0 = k)·x0[k]
    (eq. 4; q by Bayes' rule on path sums) for every state z_t; at s = 0 no position keeps the
    mask: one with no posterior mass (here an all-zero x0 row) takes its most probable code."""
    span = span_by_paths(ref_step(codebook, "dynamic", "l2_rank", "linear", ETA), t, s)
    gen = torch.Generator().manual_seed(10 * t + s)
    z_t = torch.arange(K + 1)
    x0 = torch.softmax(3.0 * torch.randn(K + 1, K, generator=gen, dtype=torch.float64), dim=-1)
    x0[0] = 0.0
    uniforms = torch.rand(K + 1, generator=gen, dtype=torch.float64)
    z_s = dynamic.step(z_t, x0, t, s, uniforms)
    for n in range(K + 1):
        mixture = [0.0] * (K + 1)
        for z0 in range(K):
            joint = [marginals[z0][s][j] * span[n][j] for j in range(K + 1)]
            if sum(joint) > 0:
                mixture = [m + float(x0[n, z0]) * p / sum(joint) for m, p in zip(mixture, joint)]
        threshold = float(uniforms[n]) * sum(mixture)
        drawn = min(sum(1 for c in itertools.accumulate(mixture) if c <= threshold), K)
        if s == 0 and drawn == K:
            drawn = int(x0[n].argmax())
        assert int(z_s[n]) == drawn, n
    assert s > 0 or int(z_s.max()) < K


def test_categorical_follows_probabilities_and_skips_zeros():
    probs = torch.tensor([0.0, 0.2, 0.0, 0.8], dtype=torch.float64).expand(200_000, 4)
    draws = categorical(probs, torch.rand(200_000, generator=torch.Generator().manual_seed(0), dtype=torch.float64))
    counts = torch.bincount(draws, minlength=4).double() / 200_000
    assert counts[0] == 0 and counts[2] == 0
    assert abs(counts[1] - 0.2) < 0.005
    edges = categorical(probs[:3], torch.tensor([0.0, 0.2, 0.999999], dtype=torch.float64))
    assert edges.tolist() == [1, 3, 3]


def test_q_sample_frequencies_match_marginals(dynamic):
    z0 = torch.tensor([0, 3])
    draws = 20000
    gen = torch.Generator().manual_seed(2)
    samples = dynamic.q_sample(z0.repeat(draws, 1), 4, generator=gen)
    for column, code in enumerate(z0.tolist()):
        freq = torch.bincount(samples[:, column], minlength=K + 1).double() / draws
        assert torch.allclose(freq, dynamic.cumulative_matrix(4)[:, code], atol=0.015, rtol=0)
    assert torch.equal(dynamic.q_sample(z0, 0), z0)
    mixed = dynamic.q_sample(torch.zeros(2, 3, dtype=torch.long), torch.tensor([[1], [T]]), generator=gen)
    assert mixed.shape == (2, 3) and int(mixed.max()) <= K


def test_sample_prior(dynamic):
    z = dynamic.sample_prior((20000,), generator=torch.Generator().manual_seed(3))
    assert abs(float((z == K).double().mean()) - 0.9) < 0.01


# ---------------------------------------------------------------------------------------------
# Loss


def test_loss_matches_brute_force(codebook, dynamic, marginals):
    gen = torch.Generator().manual_seed(4)
    batch, length = 3, 4
    logits = torch.randn(batch, length, K, generator=gen, dtype=torch.float64, requires_grad=True)
    z0 = torch.randint(0, K, (batch, length), generator=gen)
    t = torch.tensor([1, 3, 5])
    z_t = torch.stack([dynamic.q_sample(z0[b], int(t[b]), generator=gen) for b in range(batch)])
    valid = torch.ones(batch, length, dtype=torch.bool)
    valid[2, 3] = False
    z_t[2, 3] = K + 5  # padding may hold any value
    out = diffusion_loss(dynamic, logits, z0, z_t, t, valid=valid, aux_weight=0.3)

    probs = torch.softmax(logits.detach(), dim=-1)
    vlb_pos, nll_pos = [[0.0] * length for _ in range(batch)], [[0.0] * length for _ in range(batch)]
    for b in range(batch):
        for n in range(length):
            if not valid[b, n]:
                continue
            tb, zt, code = int(t[b]), int(z_t[b, n]), int(z0[b, n])
            nll_pos[b][n] = -math.log(float(probs[b, n, code]))
            if tb == 1:
                vlb_pos[b][n] = nll_pos[b][n]
                continue
            truth = ref_posterior(codebook, marginals, zt, code, tb)
            model = [0.0] * (K + 1)
            for k in range(K):
                post = ref_posterior(codebook, marginals, zt, k, tb)
                model = [m + float(probs[b, n, k]) * p for m, p in zip(model, post)]
            vlb_pos[b][n] = sum(q * math.log(q / m) for q, m in zip(truth, model) if q > 0)
    counts = [sum(valid[b].tolist()) for b in range(batch)]
    vlb = [sum(v for v, ok in zip(vlb_pos[b], valid[b].tolist()) if ok) / counts[b] for b in range(batch)]
    aux = [sum(v for v, ok in zip(nll_pos[b], valid[b].tolist()) if ok) / counts[b] for b in range(batch)]
    total = sum((vlb[b] + 0.3 * aux[b]) * counts[b] for b in range(batch)) / sum(counts)
    assert close(out.vlb, vlb) and close(out.aux, aux)
    assert abs(float(out.loss.detach()) - total) < 1e-6
    out.loss.backward()
    assert torch.isfinite(logits.grad).all() and logits.grad[2, 3].abs().max() == 0


def test_loss_takes_t_per_sample_or_per_position_alike(dynamic):
    """A (B,) t goes through one batched product over the samples' matrices, a t per position
    through one product per position: the same loss and gradient."""
    gen = torch.Generator().manual_seed(13)
    z0 = torch.randint(0, K, (3, 4), generator=gen)
    t = torch.tensor([1, 3, 5])
    z_t = dynamic.q_sample(z0, t[:, None], generator=gen)
    losses = []
    for form in (t, t[:, None].expand(3, 4)):
        logits = torch.randn(3, 4, K, generator=torch.Generator().manual_seed(0), requires_grad=True)
        out = diffusion_loss(dynamic, logits, z0, z_t, form, validate=False)
        out.loss.backward()
        losses.append((out.loss.detach(), out.vlb, logits.grad))
    assert all(torch.allclose(a, b, rtol=1e-12, atol=0) for a, b in zip(*losses))


def test_loss_importance_weight_and_perfect_prediction(dynamic):
    z0 = torch.tensor([[1, 2, 3], [4, 5, 0]])
    z_t = dynamic.q_sample(z0, 3, generator=torch.Generator().manual_seed(5))
    logits = torch.full((2, 3, K), -60.0)
    logits.scatter_(-1, z0.unsqueeze(-1), 60.0)
    out = diffusion_loss(dynamic, logits, z0, z_t, torch.tensor([3, 3]))
    assert out.loss.dtype == torch.float32
    assert float(out.vlb.abs().max()) < 1e-6  # a perfect x0 prediction has zero KL
    random_logits = torch.randn(2, 3, K, generator=torch.Generator().manual_seed(6))
    plain = diffusion_loss(dynamic, random_logits, z0, z_t, 3)
    weighted = diffusion_loss(dynamic, random_logits, z0, z_t, 3, pt=torch.full((2,), 0.5 / T))
    assert torch.allclose(weighted.loss, 2 * plain.loss)


def test_importance_weights_keep_the_loss_unbiased(dynamic):
    """Drawing t from a learned, non-uniform p(t) and weighting each loss by 1/(T·p(t)) has the
    expectation of uniform sampling: exactly over the distribution, and empirically over draws."""
    gen = torch.Generator().manual_seed(9)
    z0 = torch.randint(0, K, (1, 5), generator=gen)
    logits = torch.randn(1, 5, K, generator=gen)
    z_t = {t: dynamic.q_sample(z0, t, generator=gen) for t in range(1, T + 1)}
    plain = {t: float(diffusion_loss(dynamic, logits, z0, z_t[t], t).loss) for t in range(1, T + 1)}
    sampler = TimestepSampler(steps=T, mode="importance", warmup=0)
    sampler.update(torch.arange(1, T + 1), torch.tensor([plain[t] * t for t in range(1, T + 1)]))
    probs = sampler.probs()
    assert float(probs.max() / probs.min()) > 2  # far from uniform
    weighted = {
        t: float(diffusion_loss(dynamic, logits, z0, z_t[t], t, pt=probs[t - 1 : t]).loss) for t in range(1, T + 1)
    }
    uniform_mean = sum(plain.values()) / T
    assert abs(sum(float(probs[t - 1]) * weighted[t] for t in range(1, T + 1)) - uniform_mean) < 1e-6
    draws, pt = sampler.sample(40000, generator=gen)
    estimate = sum(weighted[int(t)] * float(probs[int(t) - 1]) / float(p) for t, p in zip(draws, pt)) / len(draws)
    assert abs(estimate - uniform_mean) < 0.03 * uniform_mean


def test_timestep_sampler():
    gen = torch.Generator().manual_seed(7)
    sampler = TimestepSampler(steps=T, mode="importance", warmup=2)
    t, pt = sampler.sample(1000, generator=gen)
    assert int(t.min()) == 1 and int(t.max()) == T and torch.allclose(pt, torch.full_like(pt, 1 / T))
    for _ in range(3):
        ts = torch.arange(1, T + 1)
        sampler.update(ts, ts.double())  # loss of t is t, so sqrt(EMA of loss²) grows with t
    probs = sampler.probs()
    weights = torch.arange(1, T + 1, dtype=torch.float32) * math.sqrt(1 - 0.9**3) + 1e-4
    weights[0] = weights[1]
    assert torch.allclose(probs, weights / weights.sum())
    t, pt = sampler.sample(5, generator=gen)
    assert torch.allclose(pt, probs[t - 1])
    assert torch.allclose(TimestepSampler(steps=T).probs(), torch.full((T,), 1 / T))
