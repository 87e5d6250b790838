"""Independent checks of the Gaussian DDPM (m2d2m/processes/gaussian_diffusion.py).

Reference values are rebuilt here from the definitions (MotionDiffuse §3.3, Ho et al. 2020) with plain
Python loops and scalar algebra, or checked in distribution by sampling, never by calling the
module's own helpers.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from m2d2m.networks.config import ConfigError
from m2d2m.processes.gaussian_diffusion import VARIANCES, GaussianDiffusion, cosine_betas, linear_betas

T = 1000


@pytest.fixture(scope="module")
def process() -> GaussianDiffusion:
    return GaussianDiffusion.linear()


def ref_betas(steps: int, start: float = 1e-4, end: float = 0.02) -> list[float]:
    """β_i = (1000/steps)·(start + i·(end − start)/(steps − 1)), straight from the definition."""
    scale = 1000.0 / steps
    return [scale * (start + i * (end - start) / (steps - 1)) for i in range(steps)]


def ref_alpha_bar(betas: list[float], t: int) -> float:
    """ᾱ at index t = prod_{s<=t} (1 − β_s); at t = −1 (the clean data) it is 1."""
    product = 1.0
    for s in range(t + 1):
        product *= 1.0 - betas[s]
    return product


def full(value: int, n: int) -> torch.Tensor:
    return torch.full((n,), value, dtype=torch.long)


# ---------------------------------------------------------------------------------------------
# Schedule


def test_linear_betas_endpoints_and_scaling() -> None:
    betas = linear_betas()
    assert betas.dtype == np.float64 and betas.shape == (T,)
    assert betas[0] == pytest.approx(1e-4, rel=1e-12) and betas[-1] == pytest.approx(0.02, rel=1e-12)
    assert np.allclose(betas, ref_betas(T), rtol=1e-12, atol=0.0)
    short = linear_betas(100)
    assert short[0] == pytest.approx(1e-3, rel=1e-12) and short[-1] == pytest.approx(0.2, rel=1e-12)
    assert np.allclose(short, ref_betas(100), rtol=1e-12, atol=0.0)
    assert np.array_equal(GaussianDiffusion.linear(100).betas, short)


def test_schedule_arrays_against_loops(process: GaussianDiffusion) -> None:
    betas = ref_betas(T)
    assert process.num_steps == T
    for t in (0, 1, 10, 500, 999):
        a_bar, a_bar_prev = ref_alpha_bar(betas, t), ref_alpha_bar(betas, t - 1)
        assert process.alphas_cumprod[t] == pytest.approx(a_bar, rel=1e-10)
        assert process.alphas_cumprod_prev[t] == pytest.approx(a_bar_prev, rel=1e-10)
        assert process.posterior_variance[t] == pytest.approx(
            betas[t] * (1 - a_bar_prev) / (1 - a_bar), rel=1e-10, abs=1e-300
        )
    assert process.alphas_cumprod_prev[0] == 1.0 and process.posterior_variance[0] == 0.0
    assert np.array_equal(process.timesteps, np.arange(T))


@pytest.mark.parametrize(
    ("betas", "timesteps"),
    [
        (np.array([]), None),
        (np.full((2, 3), 0.1), None),
        (np.array([0.1, 0.0]), None),
        (np.array([0.1, 1.0]), None),
        (np.array([0.1, -0.2]), None),
        (np.array([0.1, np.nan]), None),
        (np.array([0.1, 0.2]), [0]),
        (np.array([0.1, 0.2]), [5, 5]),
        (np.array([0.1, 0.2]), [7, 3]),
        (np.array([0.1, 0.2]), [-1, 3]),
        (np.array([0.1, 0.2]), [0.0, 1.5]),
    ],
)
def test_bad_schedules_raise(betas: np.ndarray, timesteps: list | None) -> None:
    with pytest.raises(ConfigError):
        GaussianDiffusion(betas, timesteps)


@pytest.mark.parametrize(
    "kwargs", [{"steps": 0}, {"steps": -3}, {"steps": 2.0}, {"steps": 10}, {"start": 0.0}, {"start": 0.03, "end": 0.02}]
)
def test_bad_linear_settings_raise(kwargs: dict) -> None:
    with pytest.raises(ConfigError):
        linear_betas(**kwargs)


# ---------------------------------------------------------------------------------------------
# Forward process


def test_q_mean_variance_closed_form(process: GaussianDiffusion) -> None:
    betas = ref_betas(T)
    steps = [0, 3, 250, 999]
    x0 = torch.randn(len(steps), 5, 7, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    mean, var = process.q_mean_variance(x0, torch.tensor(steps))
    assert mean.shape == x0.shape
    for row, t in enumerate(steps):
        a_bar = ref_alpha_bar(betas, t)
        torch.testing.assert_close(mean[row], math.sqrt(a_bar) * x0[row], rtol=1e-10, atol=1e-12)
        torch.testing.assert_close(
            var[row].expand(5, 7), torch.full((5, 7), 1 - a_bar, dtype=torch.float64), rtol=1e-10, atol=1e-14
        )


def test_q_sample_matches_q_in_distribution(process: GaussianDiffusion) -> None:
    n = 200_000
    gen = torch.Generator().manual_seed(2)
    x0 = torch.full((n,), 0.8, dtype=torch.float64)
    for t in (0, 100, 999):
        xt = process.q_sample(x0, full(t, n), torch.randn(n, dtype=torch.float64, generator=gen))
        a_bar = ref_alpha_bar(ref_betas(T), t)
        se = math.sqrt((1 - a_bar) / n)
        assert abs(xt.mean().item() - math.sqrt(a_bar) * 0.8) < 5 * se
        assert xt.var().item() == pytest.approx(1 - a_bar, rel=5 * math.sqrt(2 / n))


def test_q_sample_broadcasts_per_sample_t(process: GaussianDiffusion) -> None:
    x0 = torch.ones(2, 3, 4)
    noise = torch.zeros(2, 3, 4)
    xt = process.q_sample(x0, torch.tensor([0, 999]), noise)
    assert xt.dtype == torch.float32 and xt.shape == (2, 3, 4)
    assert torch.allclose(xt[0], torch.full((3, 4), math.sqrt(1 - 1e-4)))
    assert torch.allclose(xt[1], torch.full((3, 4), math.sqrt(ref_alpha_bar(ref_betas(T), 999))))


@pytest.mark.parametrize(("steps", "checks"), [(T, (0, 49, 300)), (100, (0, 50, 99))])
def test_step_by_step_chain_matches_q(steps: int, checks: tuple[int, ...]) -> None:
    """x_t built by composing q(x_s | x_{s-1}) = N(sqrt(1 − β_s) x_{s-1}, β_s) has q(x_t | x_0)'s law."""
    n = 200_000
    process = GaussianDiffusion.linear(steps)
    betas = ref_betas(steps)
    gen = torch.Generator().manual_seed(3)
    x0 = -1.3
    x = torch.full((n,), x0, dtype=torch.float64)
    for s in range(max(checks) + 1):
        x = math.sqrt(1 - betas[s]) * x + math.sqrt(betas[s]) * torch.randn(n, dtype=torch.float64, generator=gen)
        if s in checks:
            mean, var = process.q_mean_variance(torch.tensor([x0], dtype=torch.float64), torch.tensor([s]))
            se = math.sqrt(var.item() / n)
            assert abs(x.mean().item() - mean.item()) < 5 * se
            assert x.var().item() == pytest.approx(var.item(), rel=5 * math.sqrt(2 / n))


# ---------------------------------------------------------------------------------------------
# Posterior and reverse step


def test_posterior_by_bayes_rule(process: GaussianDiffusion) -> None:
    """q(x_{t-1} | x_t, x_0) ∝ N(x_{t-1}; sqrt(ᾱ_{t-1}) x_0, 1 − ᾱ_{t-1}) · N(x_t; sqrt(α_t) x_{t-1}, β_t),
    multiplied out on scalars: precisions add, means are precision-weighted."""
    betas = ref_betas(T)
    steps = [1, 2, 40, 500, 999]
    gen = torch.Generator().manual_seed(4)
    x0 = torch.randn(len(steps), 3, dtype=torch.float64, generator=gen)
    xt = torch.randn(len(steps), 3, dtype=torch.float64, generator=gen)
    mean, var = process.q_posterior(x0, xt, torch.tensor(steps))
    for row, t in enumerate(steps):
        a_bar_prev, alpha, beta = ref_alpha_bar(betas, t - 1), 1 - betas[t], betas[t]
        precision = 1 / (1 - a_bar_prev) + alpha / beta
        assert var[row].item() == pytest.approx(1 / precision, rel=1e-9)
        for col in range(3):
            ref = (
                math.sqrt(a_bar_prev) * x0[row, col].item() / (1 - a_bar_prev)
                + math.sqrt(alpha) * xt[row, col].item() / beta
            ) / precision
            assert mean[row, col].item() == pytest.approx(ref, rel=1e-9, abs=1e-12)


def test_posterior_at_first_step_is_x0(process: GaussianDiffusion) -> None:
    x0, xt = torch.randn(4, 2, dtype=torch.float64), torch.randn(4, 2, dtype=torch.float64)
    mean, var = process.q_posterior(x0, xt, full(0, 4))
    torch.testing.assert_close(mean, x0, rtol=1e-12, atol=1e-12)  # 1 − ᾱ_0 vs β_0 rounding
    assert torch.all(var == 0)


def test_predict_x0_and_eq5_mean(process: GaussianDiffusion) -> None:
    betas = ref_betas(T)
    steps = [0, 1, 17, 400, 998, 999]
    gen = torch.Generator().manual_seed(5)
    x0 = torch.randn(len(steps), 4, 3, dtype=torch.float64, generator=gen)
    eps = torch.randn(len(steps), 4, 3, dtype=torch.float64, generator=gen)
    t = torch.tensor(steps)
    xt = process.q_sample(x0, t, eps)
    torch.testing.assert_close(process.predict_x0(xt, t, eps), x0, rtol=0, atol=1e-6)
    for variance in VARIANCES:
        mean, var = process.p_mean_variance(xt, t, eps, variance)
        for row, step in enumerate(steps):
            a_bar, alpha, beta = ref_alpha_bar(betas, step), 1 - betas[step], betas[step]
            eq5 = (xt[row] - beta / math.sqrt(1 - a_bar) * eps[row]) / math.sqrt(alpha)
            torch.testing.assert_close(mean[row], eq5, rtol=1e-9, atol=1e-9)
            expected_var = beta if variance == "beta" else process.posterior_variance[step]
            assert var[row].item() == pytest.approx(expected_var, rel=1e-12)
    with pytest.raises(ConfigError):
        process.p_mean_variance(xt, t, eps, "learned")


def test_p_sample_noise(process: GaussianDiffusion) -> None:
    betas = ref_betas(T)
    n = 100_000
    gen = torch.Generator().manual_seed(6)
    xt = torch.full((n,), 0.3, dtype=torch.float64)
    eps = torch.full((n,), -0.2, dtype=torch.float64)
    noise = torch.randn(n, dtype=torch.float64, generator=gen)
    for variance in VARIANCES:
        first = process.p_sample(xt, full(0, n), eps, noise, variance)
        mean0, _ = process.p_mean_variance(xt, full(0, n), eps, variance)
        assert torch.equal(first, mean0)
        for step in (1, 500, 999):
            sample = process.p_sample(xt, full(step, n), eps, noise, variance)
            mean, _ = process.p_mean_variance(xt, full(step, n), eps, variance)
            a_bar, a_bar_prev = ref_alpha_bar(betas, step), ref_alpha_bar(betas, step - 1)
            var = betas[step] if variance == "beta" else betas[step] * (1 - a_bar_prev) / (1 - a_bar)
            torch.testing.assert_close(sample - mean, math.sqrt(var) * noise, rtol=1e-9, atol=1e-12)
            assert sample.var().item() == pytest.approx(var, rel=5 * math.sqrt(2 / n))
    mixed = process.p_sample(xt[:2], torch.tensor([0, 5]), eps[:2], torch.ones(2, dtype=torch.float64))
    mixed_mean, _ = process.p_mean_variance(xt[:2], torch.tensor([0, 5]), eps[:2])
    assert mixed[0] == mixed_mean[0] and mixed[1] == pytest.approx(mixed_mean[1].item() + math.sqrt(betas[5]))


# ---------------------------------------------------------------------------------------------
# DDIM


def test_ddim_eta0_is_deterministic_and_exact(process: GaussianDiffusion) -> None:
    betas = ref_betas(T)
    steps = [0, 1, 250, 999]
    gen = torch.Generator().manual_seed(7)
    x0 = torch.randn(len(steps), 6, dtype=torch.float64, generator=gen)
    eps = torch.randn(len(steps), 6, dtype=torch.float64, generator=gen)
    t = torch.tensor(steps)
    xt = process.q_sample(x0, t, eps)
    one = process.ddim_sample(xt, t, eps, torch.randn(len(steps), 6, dtype=torch.float64, generator=gen))
    two = process.ddim_sample(xt, t, eps, torch.randn(len(steps), 6, dtype=torch.float64, generator=gen))
    assert torch.equal(one, two)
    for row, step in enumerate(steps):
        a_bar_prev = ref_alpha_bar(betas, step - 1)
        expected = math.sqrt(a_bar_prev) * x0[row] + math.sqrt(1 - a_bar_prev) * eps[row]
        torch.testing.assert_close(one[row], expected, rtol=0, atol=1e-9)


def test_ddim_eta1_is_the_ancestral_step_with_posterior_variance(process: GaussianDiffusion) -> None:
    gen = torch.Generator().manual_seed(8)
    t = torch.tensor([0, 3, 600, 999])
    xt, eps, noise = (torch.randn(4, 5, dtype=torch.float64, generator=gen) for _ in range(3))
    torch.testing.assert_close(
        process.ddim_sample(xt, t, eps, noise, eta=1.0),
        process.p_sample(xt, t, eps, noise, "posterior"),
        rtol=1e-9,
        atol=1e-9,
    )
    for eta in (-0.1, 1.5):
        with pytest.raises(ConfigError):
            process.ddim_sample(xt, t, eps, noise, eta=eta)


# ---------------------------------------------------------------------------------------------
# Respacing


def test_respaced_keeps_alpha_bar(process: GaussianDiffusion) -> None:
    short = process.respaced(50)
    assert short.num_steps == 50
    assert short.timesteps[0] == 0 and short.timesteps[-1] == T - 1
    assert np.all(np.diff(short.timesteps) > 0)
    assert np.allclose(short.alphas_cumprod, process.alphas_cumprod[short.timesteps], rtol=1e-12, atol=0)
    assert np.allclose(short.alphas_cumprod_prev[1:], process.alphas_cumprod[short.timesteps[:-1]], rtol=1e-12)
    assert torch.equal(short.network_steps(torch.tensor([0, 1, 49])), torch.tensor([0, short.timesteps[1], T - 1]))
    # β'_i = 1 − ᾱ_{s_i}/ᾱ_{s_{i-1}} with ᾱ from the loops
    betas = ref_betas(T)
    for i in (1, 25, 49):
        ratio = ref_alpha_bar(betas, int(short.timesteps[i])) / ref_alpha_bar(betas, int(short.timesteps[i - 1]))
        assert short.betas[i] == pytest.approx(1 - ratio, rel=1e-9)
    twice = short.respaced(10)
    assert set(twice.timesteps) <= set(short.timesteps)
    assert np.allclose(twice.alphas_cumprod, process.alphas_cumprod[twice.timesteps], rtol=1e-12, atol=0)


def test_respaced_edge_counts(process: GaussianDiffusion) -> None:
    same = process.respaced(T)
    assert np.array_equal(same.betas, process.betas) and np.array_equal(same.timesteps, process.timesteps)
    assert np.array_equal(same.alphas_cumprod, process.alphas_cumprod)
    one = process.respaced(1)
    assert one.num_steps == 1 and one.timesteps.tolist() == [T - 1]
    assert one.alphas_cumprod[0] == pytest.approx(process.alphas_cumprod[-1], rel=1e-12)
    for steps in range(1, 40):  # every count yields distinct increasing indices, ends included
        kept = GaussianDiffusion.linear(37).respaced(min(steps, 37)).timesteps
        assert len(kept) == min(steps, 37) and np.all(np.diff(kept) > 0) and kept[-1] == 36
    for bad in (0, -1, T + 1, 2.5, True):
        with pytest.raises(ConfigError):
            process.respaced(bad)


# ---------------------------------------------------------------------------------------------
# Toy recovery with an oracle noise predictor

MEAN, STD, SAMPLES = 1.5, 0.5, 20_000


def oracle_eps(process: GaussianDiffusion, xt: torch.Tensor, network_t: torch.Tensor) -> torch.Tensor:
    """E[ε | x_t] for data N(MEAN, STD²), where x_t ~ N(sqrt(ᾱ) MEAN, ᾱ STD² + 1 − ᾱ).

    ᾱ is taken at the ORIGINAL index the sampler reports, as a trained network would see it."""
    a_bar = torch.as_tensor(process.alphas_cumprod, dtype=torch.float64)[network_t]
    return (1 - a_bar).sqrt() * (xt - a_bar.sqrt() * MEAN) / (a_bar * STD**2 + 1 - a_bar)


def sample(process: GaussianDiffusion, sampler: GaussianDiffusion, method: str, seed: int) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    x = torch.randn(SAMPLES, dtype=torch.float64, generator=gen)
    for i in reversed(range(sampler.num_steps)):
        t = full(i, SAMPLES)
        eps = oracle_eps(process, x, sampler.network_steps(t))
        noise = torch.randn(SAMPLES, dtype=torch.float64, generator=gen)
        x = sampler.p_sample(x, t, eps, noise) if method == "ancestral" else sampler.ddim_sample(x, t, eps, noise)
    return x


# Exact (linear-Gaussian) end points of these chains, for the tolerances: 1000-step ancestral gives
# N(1.49998, 0.5008²); 50-step ancestral std 0.518; 50-step DDIM mean 1.4955, std 0.472 — the coarse
# chains' own discretisation bias, on top of the sampling error (≈ 0.0035 on the mean, 0.0025 on the std).
@pytest.mark.parametrize(
    ("steps", "method", "std_tol"),
    [
        (T, "ancestral", 0.015),
        (50, "ancestral", 0.04),
        (50, "ddim", 0.045),
    ],
)
def test_oracle_sampling_recovers_data(process: GaussianDiffusion, steps: int, method: str, std_tol: float) -> None:
    x = sample(process, process.respaced(steps), method, seed=steps)
    assert torch.isfinite(x).all()
    assert x.mean().item() == pytest.approx(MEAN, abs=0.02)
    assert x.std().item() == pytest.approx(STD, abs=std_tol)


# ---------------------------------------------------------------------------------------------
# Options of ours: the cosine schedule, x_0-prediction


def test_cosine_betas_follow_nichol_and_dhariwal_eq_17() -> None:
    betas = cosine_betas(100)
    s = 0.008
    f = [math.cos((t / 100 + s) / (1 + s) * math.pi / 2) ** 2 for t in range(101)]
    for t in (0, 1, 50, 98):  # ᾱ(t) = f(t)/f(0) as the product of (1 − β)
        assert ref_alpha_bar(list(betas), t) == pytest.approx(f[t + 1] / f[0], rel=1e-9)
    assert betas[-1] == pytest.approx(0.999)  # clipped at the end, where f reaches 0
    assert np.all(np.diff(betas) > 0) and betas[0] > 0
    with pytest.raises(ConfigError):
        cosine_betas(0)


def test_predict_eps_inverts_q_sample(process: GaussianDiffusion) -> None:
    gen = torch.Generator().manual_seed(6)
    x0 = torch.randn(3, 5, 2, dtype=torch.float64, generator=gen)
    eps = torch.randn(3, 5, 2, dtype=torch.float64, generator=gen)
    t = torch.tensor([0, 300, 999])
    xt = process.q_sample(x0, t, eps)
    torch.testing.assert_close(process.predict_eps(xt, t, x0), eps, rtol=0, atol=1e-6)


def test_an_oracle_x0_predictor_samples_what_the_oracle_eps_predictor_does(process: GaussianDiffusion) -> None:
    """A network that predicts x_0 is sampled through the ε its x_0 implies: the oracle E[x_0 | x_t]
    fed through predict_eps gives E[ε | x_t], step for step."""
    sampler = process.respaced(50)
    gen = torch.Generator().manual_seed(7)
    x = torch.randn(1000, dtype=torch.float64, generator=gen)
    for i in reversed(range(sampler.num_steps)):
        t = full(i, 1000)
        network_t = sampler.network_steps(t)
        eps = oracle_eps(process, x, network_t)
        a_bar = torch.as_tensor(process.alphas_cumprod, dtype=torch.float64)[network_t]
        x0 = (x - (1 - a_bar).sqrt() * eps) / a_bar.sqrt()  # E[x_0 | x_t], by the same eq. 3
        torch.testing.assert_close(sampler.predict_eps(x, t, x0), eps, rtol=1e-6, atol=1e-6)
        x = sampler.ddim_sample(x, t, eps, torch.zeros_like(x))
