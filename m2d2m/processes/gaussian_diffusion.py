"""Gaussian DDPM of MotionDiffuse (Zhang et al. 2022, §3.3, eqs. 1-5), after Ho et al. 2020.

Forward process (Ho et al. 2020, eq. 2 and 4; MotionDiffuse eq. 1 and 3): q(x_t | x_{t-1}) =
N(sqrt(α_t) x_{t-1}, β_t I), hence q(x_t | x_0) = N(sqrt(ᾱ_t) x_0, (1 - ᾱ_t) I) with ᾱ_t = prod_{s<=t} α_s.
The network predicts the noise ε (MotionDiffuse eq. 4; Ho et al. eq. 14); the reverse mean is the
posterior mean q(x_{t-1} | x_t, x_0) (Ho et al. eq. 6-7) taken at the x_0 implied by ε, which is the
same as MotionDiffuse eq. 5 / Ho et al. eq. 11: 1/sqrt(α_t) (x_t - β_t / sqrt(1 - ᾱ_t) ε). The reverse
variance is fixed: β_t as in MotionDiffuse §3.3 (after eq. 4), or β̃_t, the posterior variance
(Ho et al. eq. 7; "fixed small" in the public DDPM code).

Schedule: linear β from 1e-4 to 0.02 over T = 1000 steps (Ho et al. §4), both ends scaled by 1000/T
so that a shorter chain spans the same noise range (Nichol & Dhariwal 2021, the "linear" schedule of
improved-diffusion); or ``cosine``, Nichol & Dhariwal's eq. 17, which destroys the signal more
slowly at first and keeps fewer steps at pure noise (an option of ours for MotionDiffuse).

What the network predicts: the noise ε (the paper, ``epsilon``), or x_0 itself (``x0``, as MDM,
Tevet et al. 2023, does; ours as an option). Sampling needs ε; :meth:`GaussianDiffusion.predict_eps`
turns a predicted x_0 into the ε it implies, so every sampler works with either.

Fewer sampling steps (Nichol & Dhariwal 2021 §4, respacing): keep a subsequence s_0 < ... < s_{K-1}
of the steps, leave ᾱ at those steps unchanged and set β'_i = 1 - ᾱ_{s_i} / ᾱ_{s_{i-1}}; the network
is still told the original index s_i. Deterministic sampling follows DDIM (Song et al. 2021, eq. 12,
with σ from eq. 16 scaled by η).

Indices are 0-based: index t is the paper's step t + 1, so ᾱ at index t is prod_{s<=t} α_s and the
"previous" ᾱ at index 0 is 1 (x_{-1} stands for the clean x_0). The schedule is kept in float64
numpy arrays, and each array a step indexes is converted to the input tensor's dtype and device
once and kept there: a training or sampling step then copies nothing from the host (on a GPU, a
copy from the host makes the host wait for the device's queue).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import Tensor

from m2d2m.networks.config import ConfigError

# Σ_θ = β_t (the paper, §3.3 after eq. 4) or β̃_t (the public code's FIXED_SMALL)
VARIANCES = ("beta", "posterior")
SCHEDULES = ("linear", "cosine")
PREDICTIONS = ("epsilon", "x0")


def linear_betas(steps: int = 1000, start: float = 1e-4, end: float = 0.02) -> np.ndarray:
    """β_0..β_{steps-1}, linear from ``start`` to ``end`` after scaling both by 1000/steps, float64."""
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise ConfigError(f"diffusion steps must be a positive integer, got {steps!r}")
    if not 0.0 < start <= end:
        raise ConfigError(f"need 0 < beta start <= beta end, got start={start!r}, end={end!r}")
    scale = 1000.0 / steps
    if scale * end >= 1.0:
        raise ConfigError(f"{steps} steps scale beta end {end!r} to {scale * end:.4g}, which must stay below 1")
    return np.linspace(scale * start, scale * end, steps, dtype=np.float64)


def cosine_betas(steps: int = 1000, offset: float = 0.008, max_beta: float = 0.999) -> np.ndarray:
    """β_0..β_{steps-1} of Nichol & Dhariwal 2021 eq. 17: ᾱ(t) = f(t)/f(0), f(t) = cos²(π/2·(t/T + s)/(1 + s)),
    β_t = 1 − ᾱ(t)/ᾱ(t − 1) clipped at ``max_beta`` (their §3.2), float64."""
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise ConfigError(f"diffusion steps must be a positive integer, got {steps!r}")
    grid = np.arange(steps + 1, dtype=np.float64) / steps
    cumulative = np.cos((grid + offset) / (1.0 + offset) * np.pi / 2.0) ** 2
    return np.clip(1.0 - cumulative[1:] / cumulative[:-1], 0.0, max_beta)


DIFFUSION_KEYS = ("steps", "beta_start", "beta_end", "schedule", "prediction")  # a run's diffusion section


def prediction_of(diffusion: dict[str, Any]) -> str:
    """What the network of a ``diffusion`` section predicts: ``epsilon`` (the paper's) or ``x0``."""
    return diffusion.get("prediction", "epsilon")


class GaussianDiffusion:
    """The fixed schedule and the closed forms built from it; no network, no state besides arrays."""

    def __init__(self, betas: np.ndarray, timesteps: Sequence[int] | None = None) -> None:
        betas = np.asarray(betas, dtype=np.float64)
        if betas.ndim != 1 or betas.size == 0:
            raise ConfigError(f"betas must be a non-empty 1-D array, got shape {betas.shape}")
        if not np.all((betas > 0.0) & (betas < 1.0)):
            raise ConfigError("every beta must lie in (0, 1)")
        if timesteps is None:
            steps = np.arange(betas.size, dtype=np.int64)
        else:
            steps = np.asarray(timesteps)
            if steps.ndim != 1 or steps.size != betas.size or not np.issubdtype(steps.dtype, np.integer):
                raise ConfigError(f"timesteps must be {betas.size} integers, one per beta, got shape {steps.shape}")
            steps = steps.astype(np.int64)
            if steps[0] < 0 or np.any(np.diff(steps) <= 0):
                raise ConfigError("timesteps must be non-negative and strictly increasing")
        self.betas = betas
        self.timesteps = steps
        self.alphas = 1.0 - betas
        self.alphas_cumprod = np.cumprod(self.alphas)
        self.alphas_cumprod_prev = np.concatenate([[1.0], self.alphas_cumprod[:-1]])
        self.posterior_variance = betas * (1.0 - self.alphas_cumprod_prev) / (1.0 - self.alphas_cumprod)
        # the arrays a step indexes, by name (float64), and their copies on devices (see _table)
        self._arrays = {
            "betas": betas,
            "timesteps": steps,
            "posterior_variance": self.posterior_variance,
            "sqrt_alphas_cumprod": np.sqrt(self.alphas_cumprod),
            "sqrt_one_minus_alphas_cumprod": np.sqrt(1.0 - self.alphas_cumprod),
            "one_minus_alphas_cumprod": 1.0 - self.alphas_cumprod,
            "sqrt_recip_alphas_cumprod": np.sqrt(1.0 / self.alphas_cumprod),
            "sqrt_recipm1_alphas_cumprod": np.sqrt(1.0 / self.alphas_cumprod - 1.0),
            "sqrt_alphas_cumprod_prev": np.sqrt(self.alphas_cumprod_prev),
            # Ho et al. eq. 7: μ̃_t = coef_x0 · x_0 + coef_xt · x_t
            "posterior_coef_x0": betas * np.sqrt(self.alphas_cumprod_prev) / (1.0 - self.alphas_cumprod),
            "posterior_coef_xt": (1.0 - self.alphas_cumprod_prev) * np.sqrt(self.alphas) / (1.0 - self.alphas_cumprod),
        }
        self._tables: dict[tuple[str, torch.dtype, torch.device], Tensor] = {}

    @classmethod
    def from_config(cls, diffusion: dict[str, Any]) -> GaussianDiffusion:
        """The process of a run's ``diffusion`` section: T and the schedule (MotionDiffuse's linear
        β from 1e-4 to 0.02 over 1000 steps, or ``cosine``); its ``prediction`` (ε, the paper's, or
        x0) is checked here and read by :func:`prediction_of`. ValueError for anything else."""
        unknown = sorted(set(diffusion) - set(DIFFUSION_KEYS))
        if unknown:
            raise ValueError(f"unknown diffusion keys: {', '.join(unknown)}")
        schedule = diffusion.get("schedule", "linear")
        if schedule not in SCHEDULES or prediction_of(diffusion) not in PREDICTIONS:
            raise ValueError(
                f"diffusion.schedule must be one of {', '.join(SCHEDULES)} and diffusion.prediction "
                f"one of {', '.join(PREDICTIONS)}, got {schedule!r} and {prediction_of(diffusion)!r}"
            )
        steps = int(diffusion.get("steps", 1000))
        if schedule == "cosine":
            return cls(cosine_betas(steps))
        return cls.linear(steps, float(diffusion.get("beta_start", 1e-4)), float(diffusion.get("beta_end", 0.02)))

    @classmethod
    def linear(cls, steps: int = 1000, start: float = 1e-4, end: float = 0.02) -> GaussianDiffusion:
        """The MotionDiffuse / DDPM process with :func:`linear_betas`."""
        return cls(linear_betas(steps, start, end))

    @property
    def num_steps(self) -> int:
        return int(self.betas.size)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(num_steps={self.num_steps}, timesteps={self.timesteps[0]}..{self.timesteps[-1]})"

    def _table(self, name: str, dtype: torch.dtype, device: torch.device) -> Tensor:
        """The schedule array ``name`` as a tensor of ``dtype`` on ``device``, converted from its
        float64 values once and kept."""
        key = (name, dtype, device)
        if key not in self._tables:
            self._tables[key] = torch.as_tensor(self._arrays[name], dtype=dtype, device=device)
        return self._tables[key]

    def _at(self, name: str, t: Tensor, like: Tensor) -> Tensor:
        """The schedule array ``name`` at t in ``like``'s dtype and device, shaped (B, 1, ...) to
        broadcast over a batch like ``like``."""
        if t.dim() != 1 or t.shape[0] != like.shape[0]:
            raise ValueError(
                f"t must have shape ({like.shape[0]},) to match a batch of shape {tuple(like.shape)}, "
                f"got {tuple(t.shape)}"
            )
        table = self._table(name, like.dtype, like.device)
        return table[t.to(like.device).long()].reshape(-1, *([1] * (like.dim() - 1)))

    def network_steps(self, t: Tensor) -> Tensor:
        """The original-schedule index each step stands for, the one the network was trained with."""
        return self._table("timesteps", torch.long, t.device)[t.long()]

    def q_sample(self, x0: Tensor, t: Tensor, noise: Tensor) -> Tensor:
        """x_t ~ q(x_t | x_0) by reparameterisation (MotionDiffuse eq. 3, Ho et al. eq. 4)."""
        return self._at("sqrt_alphas_cumprod", t, x0) * x0 + self._at("sqrt_one_minus_alphas_cumprod", t, x0) * noise

    def q_mean_variance(self, x0: Tensor, t: Tensor) -> tuple[Tensor, Tensor]:
        """Mean sqrt(ᾱ_t) x_0 and variance 1 - ᾱ_t (shaped to broadcast) of q(x_t | x_0)."""
        return self._at("sqrt_alphas_cumprod", t, x0) * x0, self._at("one_minus_alphas_cumprod", t, x0)

    def q_posterior(self, x0: Tensor, xt: Tensor, t: Tensor) -> tuple[Tensor, Tensor]:
        """Mean and variance β̃_t of q(x_{t-1} | x_t, x_0) (Ho et al. eq. 6-7); at t = 0 it is x_0 exactly."""
        mean = self._at("posterior_coef_x0", t, x0) * x0 + self._at("posterior_coef_xt", t, xt) * xt
        return mean, self._at("posterior_variance", t, xt)

    def predict_eps(self, xt: Tensor, t: Tensor, x0: Tensor) -> Tensor:
        """The ε for which x_t = q_sample(x_0, t, ε): eq. 3 solved for ε (a predicted x_0's noise)."""
        return (self._at("sqrt_recip_alphas_cumprod", t, xt) * xt - x0) / self._at("sqrt_recipm1_alphas_cumprod", t, xt)

    def predict_x0(self, xt: Tensor, t: Tensor, eps: Tensor) -> Tensor:
        """The x_0 for which x_t = q_sample(x_0, t, eps): eq. 3 solved for x_0."""
        return self._at("sqrt_recip_alphas_cumprod", t, xt) * xt - self._at("sqrt_recipm1_alphas_cumprod", t, xt) * eps

    def _variance(self, variance: str) -> str:
        """The name of the array of Σ_θ's choice."""
        if variance == "beta":
            return "betas"
        if variance == "posterior":
            return "posterior_variance"
        raise ConfigError(f"variance must be one of {VARIANCES}, got {variance!r}")

    def p_mean_variance(self, xt: Tensor, t: Tensor, eps: Tensor, variance: str = "beta") -> tuple[Tensor, Tensor]:
        """Mean and fixed variance of p_θ(x_{t-1} | x_t) given the predicted noise (MotionDiffuse eq. 5)."""
        table = self._variance(variance)
        mean, _ = self.q_posterior(self.predict_x0(xt, t, eps), xt, t)
        return mean, self._at(table, t, xt)

    def p_sample(self, xt: Tensor, t: Tensor, eps: Tensor, noise: Tensor, variance: str = "beta") -> Tensor:
        """One ancestral step x_t -> x_{t-1} (Ho et al. Algorithm 2); the last step (t = 0) adds no noise."""
        mean, var = self.p_mean_variance(xt, t, eps, variance)
        keep = (t != 0).to(device=xt.device, dtype=xt.dtype).reshape(var.shape)
        return mean + keep * var.sqrt() * noise

    def ddim_sample(self, xt: Tensor, t: Tensor, eps: Tensor, noise: Tensor, eta: float = 0.0) -> Tensor:
        """One DDIM step to this process's previous step (Song et al. 2021, eq. 12; σ of eq. 16 times η).

        η = 0 is deterministic; η = 1 is the ancestral step with variance β̃_t. No noise at t = 0.
        """
        if not 0.0 <= eta <= 1.0:
            raise ConfigError(f"DDIM eta must lie in [0, 1], got {eta!r}")
        sigma, direction = f"ddim_sigma@{eta!r}", f"ddim_direction@{eta!r}"
        if sigma not in self._arrays:
            prev = self.alphas_cumprod_prev
            values = eta * np.sqrt((1.0 - prev) / (1.0 - self.alphas_cumprod) * (1.0 - self.alphas_cumprod / prev))
            self._arrays[sigma] = values
            self._arrays[direction] = np.sqrt(np.clip(1.0 - prev - values**2, 0.0, None))
        keep = (t != 0).to(device=xt.device, dtype=xt.dtype).reshape(-1, *([1] * (xt.dim() - 1)))
        return (
            self._at("sqrt_alphas_cumprod_prev", t, xt) * self.predict_x0(xt, t, eps)
            + self._at(direction, t, xt) * eps
            + keep * self._at(sigma, t, xt) * noise
        )

    def respaced(self, steps: int) -> GaussianDiffusion:
        """A process of ``steps`` of these steps, evenly spaced from the first to the last index.

        ᾱ at the kept steps is unchanged and β'_i = 1 - ᾱ_{s_i} / ᾱ_{s_{i-1}} (Nichol & Dhariwal 2021
        §4). A single step keeps the last index, the one pure noise starts from. Indices are rounded
        half up, which keeps them distinct whenever steps <= num_steps.
        """
        if isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= self.num_steps:
            raise ConfigError(f"respaced steps must be an integer in [1, {self.num_steps}], got {steps!r}")
        if steps == self.num_steps:
            return GaussianDiffusion(self.betas.copy(), self.timesteps.copy())
        if steps == 1:
            keep = np.array([self.num_steps - 1])
        else:
            keep = np.floor(np.linspace(0.0, self.num_steps - 1, steps) + 0.5).astype(np.int64)
        kept = self.alphas_cumprod[keep]
        betas = 1.0 - kept / np.concatenate([[1.0], kept[:-1]])
        return GaussianDiffusion(betas, self.timesteps[keep])
