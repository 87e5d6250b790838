"""Transition matrices of M2D2M's discrete diffusion (paper §3 and §4.2; schedule and posterior after
microsoft/VQ-Diffusion, ``diffusion_transformer.py``).

Tokens are the K codes of the frozen VQ codebook plus a mask token at index K. One forward step keeps
a code (α_t), masks it (γ_t) or replaces it, the replace mass 1 − α_t − γ_t being spread evenly over
the K codes (``uniform``: VQ-Diffusion's β_t) or by codebook distance (``dynamic``: M2D2M's β(t, d)).
A distance-shaped β-block is not symmetric, so unlike VQ-Diffusion nothing here relies on symmetry:
Q_t and Q̄_t are dense (K+1)×(K+1) matrices and the posterior takes explicit rows and matrix
products. They are built in float64; the reverse step a sampler draws with stays in float64, and a
training loss may ask for float32 copies (``dtype``), the precision VQ-Diffusion trains in, so that
no float64 runs on a GPU's training step (docs/training.md, "Mixed precision").

Sign convention (paper Eq. 7 and the sentence after it: "progressively assigns higher probabilities
to greater distances between tokens as the diffusion step t advances"): β(t, d) ∝ exp(+η·(t/T)·(d/K)),
so a larger η puts the replace mass on FAR codes, the more so the larger t; at t → 0 or η = 0 it is
uniform, i.e. VQ-Diffusion.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from m2d2m.networks.config import ConfigError

KINDS = ("uniform", "dynamic")
DISTANCES = ("l2_rank", "l2", "cosine", "cosine_rank")
# schedule name -> (ᾱ_T, γ̄_T); both start at ᾱ_1 = 0.99999, γ̄_1 = 0.000009.
SCHEDULES: dict[str, tuple[float, float]] = {
    "linear": (0.000009, 0.9),  # ours: cumulative replace mass grows to 0.1 (docs/training.md)
    "absorbing": (0.000009, 0.99999),  # VQ-Diffusion's released endpoints: in effect pure masking
}


@dataclass(frozen=True)
class ScheduleConfig:
    """Everything that determines a schedule, flat so it can be logged as run parameters."""

    steps: int = 100
    kind: str = "dynamic"
    eta: float = 0.5
    distance: str = "l2_rank"
    schedule: str = "linear"
    alpha_bar_start: float = 0.99999
    alpha_bar_end: float = 0.000009
    gamma_bar_start: float = 0.000009
    gamma_bar_end: float = 0.9

    def __post_init__(self) -> None:
        if not isinstance(self.steps, int) or self.steps < 1:
            raise ConfigError(f"steps must be a positive integer, got {self.steps!r}")
        if self.kind not in KINDS:
            raise ConfigError(f"kind must be one of {KINDS}, got {self.kind!r}")
        if self.distance not in DISTANCES:
            raise ConfigError(f"distance must be one of {DISTANCES}, got {self.distance!r}")
        if self.schedule not in SCHEDULES:
            raise ConfigError(f"schedule must be one of {tuple(SCHEDULES)}, got {self.schedule!r}")
        if not 0.0 <= self.alpha_bar_end <= self.alpha_bar_start <= 1.0:
            raise ConfigError("need 0 <= alpha_bar_end <= alpha_bar_start <= 1")
        if not 0.0 <= self.gamma_bar_start <= self.gamma_bar_end < 1.0:
            raise ConfigError("need 0 <= gamma_bar_start <= gamma_bar_end < 1")
        if self.alpha_bar_start + self.gamma_bar_start > 1.0 or self.alpha_bar_end + self.gamma_bar_end > 1.0:
            raise ConfigError("alpha_bar + gamma_bar must not exceed 1 at either end")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def scalar_schedule(config: ScheduleConfig) -> dict[str, Tensor]:
    """ᾱ_t, γ̄_t (linear in t) and the per-step α_t, γ_t, replace mass; float64, index t = 0..T.

    Index 0 is the identity (ᾱ_0 = 1, γ̄_0 = 0, α_0 = 1), as in VQ-Diffusion, so that t − 1 = 0 needs
    no special case.
    """
    steps = config.steps
    frac = torch.arange(steps, dtype=torch.float64) / max(steps - 1, 1)
    alpha_bar = torch.cat(
        [
            torch.ones(1, dtype=torch.float64),
            config.alpha_bar_start + frac * (config.alpha_bar_end - config.alpha_bar_start),
        ]
    )
    gamma_bar = torch.cat(
        [
            torch.zeros(1, dtype=torch.float64),
            config.gamma_bar_start + frac * (config.gamma_bar_end - config.gamma_bar_start),
        ]
    )
    alpha = torch.ones_like(alpha_bar)
    gamma = torch.zeros_like(gamma_bar)
    alpha[1:] = alpha_bar[1:] / alpha_bar[:-1]
    gamma[1:] = 1.0 - (1.0 - gamma_bar[1:]) / (1.0 - gamma_bar[:-1])
    replace_mass = 1.0 - alpha - gamma
    if (replace_mass < -1e-12).any():
        bad = int(torch.nonzero(replace_mass < -1e-12)[0])
        raise ValueError(
            f"the schedule gives a negative replace mass {float(replace_mass[bad]):.3g} "
            f"at step {bad}; choose other endpoints"
        )
    return {
        "alpha_bar": alpha_bar,
        "gamma_bar": gamma_bar,
        "alpha": alpha,
        "gamma": gamma,
        "replace": replace_mass.clamp_min(0.0),
    }


def code_distances(codebook: Tensor, distance: str = "l2_rank") -> Tensor:
    """d[n, m]: how far target code m lies from source code n, on the scale of a rank, float64 (K, K).

    ``*_rank``: the rank of m among all codes sorted by their distance to n (0 = n itself, ties broken
    by index), so each row is a permutation of 0..K−1. ``l2`` / ``cosine``: the raw distance (L2, or
    1 − cosine similarity) scaled by (K − 1)/max over all pairs, so that d/K in Eq. 7 spans [0, 1)
    like a rank and η means roughly the same thing for every distance, while the geometry (how much
    nearer one code is than another, and across sources) is kept. The diagonal is exactly 0.
    """
    if distance not in DISTANCES:
        raise ValueError(f"distance must be one of {DISTANCES}, got {distance!r}")
    codes = codebook.detach().to(torch.float64)
    num_codes = codes.shape[0]
    if distance.startswith("l2"):
        raw = torch.cdist(codes, codes, compute_mode="donot_use_mm_for_euclid_dist")
    else:
        unit = F.normalize(codes, dim=1)
        raw = (1.0 - unit @ unit.T).clamp(0.0, 2.0)
    eye = torch.eye(num_codes, dtype=torch.bool, device=codes.device)
    raw = raw.masked_fill(eye, 0.0)
    if distance.endswith("_rank"):
        # -1 on the diagonal: a duplicate code must not outrank the code itself.
        order = torch.argsort(raw.masked_fill(eye, -1.0), dim=1, stable=True)
        ranks = torch.empty_like(raw)
        positions = torch.arange(num_codes, dtype=torch.float64, device=codes.device)
        ranks.scatter_(1, order, positions.expand(num_codes, -1).contiguous())
        return ranks
    largest = raw.max()
    if largest <= 0:
        return torch.zeros_like(raw)
    return raw * ((num_codes - 1) / largest)


def replace_block(replace_mass: Tensor, num_codes: int, distances: Tensor | None, eta: float) -> Tensor:
    """B_t[m, n] = β(t, d(n, m)) for t = 1..T, float64 (T, K, K); ``distances=None`` means uniform.

    The softmax runs over the target codes m of each source n, so every column of B_t sums to the
    step's replace mass and Q_t stays column-stochastic.
    """
    mass = replace_mass[1:]
    steps = mass.shape[0]
    if distances is None:
        return (mass / num_codes)[:, None, None].expand(steps, num_codes, num_codes)
    t = torch.arange(1, steps + 1, dtype=torch.float64, device=distances.device)
    scale = eta * (t / steps) / num_codes
    weights = torch.softmax(scale[:, None, None] * distances, dim=2)  # (t, source n, target m)
    return mass[:, None, None] * weights.transpose(1, 2)


def transition_matrices(scalars: dict[str, Tensor], block: Tensor) -> tuple[Tensor, Tensor]:
    """Q_t and Q̄_t = Q_t ⋯ Q_1 stacked over t = 0..T (index 0 the identity), float64 (T+1, K+1, K+1).

    Q_t = [[α_t I + B_t, 0], [γ_t 1ᵀ, 1]]: the mask is absorbing and every code reaches it with γ_t.
    """
    steps, num_codes = block.shape[0], block.shape[1]
    device = block.device
    step = torch.zeros(steps + 1, num_codes + 1, num_codes + 1, dtype=torch.float64, device=device)
    step[0] = torch.eye(num_codes + 1, dtype=torch.float64, device=device)
    step[1:, :num_codes, :num_codes] = block
    step[1:, :num_codes, :num_codes].diagonal(dim1=1, dim2=2).add_(scalars["alpha"][1:, None])
    step[1:, num_codes, :num_codes] = scalars["gamma"][1:, None]
    step[1:, num_codes, num_codes] = 1.0
    cumulative = torch.empty_like(step)
    cumulative[0] = step[0]
    for t in range(1, steps + 1):
        torch.matmul(step[t], cumulative[t - 1], out=cumulative[t])
    return step, cumulative


class TransitionSchedule:
    """The forward process q of M2D2M: cached Q_t, Q̄_t, sampling of z_t, the posterior p(z_{t−1} | z_t)
    and the reverse step a sampler takes with it (:meth:`step`).

    Build with :meth:`build`; matrices live on the codebook's device (``.to`` moves them) and are
    indexed ``Q[i, j] = q(z_t = i | z_{t−1} = j)``.
    """

    def __init__(
        self,
        config: ScheduleConfig,
        num_codes: int,
        scalars: dict[str, Tensor],
        distances: Tensor | None,
        step: Tensor,
        cumulative: Tensor,
    ) -> None:
        self.config = config
        self.num_codes = num_codes
        self.mask_index = num_codes
        self._scalars = scalars
        self._distances = distances
        self._step = step
        self._cumulative = cumulative
        self._spans: dict[tuple[int, int], Tensor] = {}
        self._cast: dict[torch.dtype, tuple[Tensor, Tensor]] = {}

    @classmethod
    def build(
        cls,
        codebook: Tensor,
        steps: int = 100,
        kind: str = "dynamic",
        eta: float = 0.5,
        distance: str = "l2_rank",
        schedule: str = "linear",
        alpha_bar_end: float | None = None,
        gamma_bar_end: float | None = None,
        alpha_bar_start: float = 0.99999,
        gamma_bar_start: float = 0.000009,
    ) -> TransitionSchedule:
        """Build from the frozen VQ codebook (K, code_dim); unset endpoints take the schedule's defaults."""
        if schedule not in SCHEDULES:
            raise ValueError(f"schedule must be one of {tuple(SCHEDULES)}, got {schedule!r}")
        if codebook.dim() != 2 or codebook.shape[0] < 1:
            raise ValueError(f"codebook must have shape (K, code_dim), got {tuple(codebook.shape)}")
        default_alpha_end, default_gamma_end = SCHEDULES[schedule]
        config = ScheduleConfig(
            steps=steps,
            kind=kind,
            eta=float(eta),
            distance=distance,
            schedule=schedule,
            alpha_bar_start=alpha_bar_start,
            alpha_bar_end=default_alpha_end if alpha_bar_end is None else alpha_bar_end,
            gamma_bar_start=gamma_bar_start,
            gamma_bar_end=default_gamma_end if gamma_bar_end is None else gamma_bar_end,
        )
        device = codebook.device
        scalars = {name: value.to(device) for name, value in scalar_schedule(config).items()}
        distances = code_distances(codebook, distance) if kind == "dynamic" else None
        return cls._assemble(config, codebook.shape[0], scalars, distances)

    @classmethod
    def from_config(cls, codebook: Tensor, diffusion: dict[str, Any]) -> TransitionSchedule:
        """The schedule a run's ``diffusion`` section (or a saved :class:`ScheduleConfig`) builds
        from its codebook, in float64; the section's keys that are not the schedule's (loss
        weights, timestep sampling) are the training's, and ignored here."""
        options = {f.name: diffusion[f.name] for f in fields(ScheduleConfig) if f.name in diffusion}
        options["steps"] = int(options.get("steps", 100))
        return cls.build(codebook.detach().double(), **options)

    @classmethod
    def _assemble(
        cls, config: ScheduleConfig, num_codes: int, scalars: dict[str, Tensor], distances: Tensor | None
    ) -> TransitionSchedule:
        block = replace_block(scalars["replace"], num_codes, distances, config.eta)
        step, cumulative = transition_matrices(scalars, block)
        return cls(config, num_codes, scalars, distances, step, cumulative)

    def with_eta(self, eta: float) -> TransitionSchedule:
        """The same schedule at another η (e.g. η = 0.25 for multi-action sampling), reusing the distances."""
        if self.config.kind != "dynamic":
            raise ValueError("with_eta needs a 'dynamic' schedule; a 'uniform' one has no η")
        return self._assemble(replace(self.config, eta=float(eta)), self.num_codes, self._scalars, self._distances)

    def to(self, device: torch.device | str) -> TransitionSchedule:
        """Move the cached matrices (in place, like ``nn.Module.to``) and return self."""
        self._scalars = {name: value.to(device) for name, value in self._scalars.items()}
        if self._distances is not None:
            self._distances = self._distances.to(device)
        self._step = self._step.to(device)
        self._cumulative = self._cumulative.to(device)
        self._spans = {pair: span.to(device) for pair, span in self._spans.items()}
        self._cast = {}
        return self

    def _matrices(self, dtype: torch.dtype) -> tuple[Tensor, Tensor]:
        """Q_t and Q̄_t stacked over t in ``dtype``: the float64 originals, or copies cast once and
        kept until the next :meth:`to`. Each entry is cast on its own, so a float32 copy holds the
        float64 value to float32's relative rounding; no 1 − x is taken in the lower precision."""
        if dtype == torch.float64:
            return self._step, self._cumulative
        if dtype not in self._cast:
            self._cast[dtype] = (self._step.to(dtype), self._cumulative.to(dtype))
        return self._cast[dtype]

    @property
    def device(self) -> torch.device:
        return self._step.device

    @property
    def steps(self) -> int:
        return self.config.steps

    @property
    def alpha_bar(self) -> Tensor:
        """ᾱ_t for t = 0..T (float64)."""
        return self._scalars["alpha_bar"]

    @property
    def gamma_bar(self) -> Tensor:
        """γ̄_t for t = 0..T (float64): the probability that a code is masked by step t."""
        return self._scalars["gamma_bar"]

    @property
    def alpha(self) -> Tensor:
        """Per-step keep probability α_t for t = 0..T (float64)."""
        return self._scalars["alpha"]

    @property
    def gamma(self) -> Tensor:
        """Per-step mask probability γ_t for t = 0..T (float64)."""
        return self._scalars["gamma"]

    @property
    def replace_mass(self) -> Tensor:
        """Per-step replace mass 1 − α_t − γ_t for t = 0..T (float64), what β spreads over the codes."""
        return self._scalars["replace"]

    @property
    def distances(self) -> Tensor | None:
        """d[n, m] of the dynamic kind (see :func:`code_distances`); None for uniform."""
        return self._distances

    def step_matrix(self, t: int) -> Tensor:
        """Q_t, float64 (K+1, K+1), t = 1..T."""
        if not 1 <= t <= self.steps:
            raise ValueError(f"t must lie in 1..{self.steps}, got {t}")
        return self._step[t]

    def cumulative_matrix(self, t: int) -> Tensor:
        """Q̄_t = Q_t ⋯ Q_1, float64 (K+1, K+1), t = 0..T (the identity at 0)."""
        if not 0 <= t <= self.steps:
            raise ValueError(f"t must lie in 0..{self.steps}, got {t}")
        return self._cumulative[t]

    def span_matrix(self, t: int, s: int) -> Tensor:
        """Q_{t|s} = Q_t ⋯ Q_{s+1}, i.e. q(z_t | z_s), float64 (K+1, K+1) for 0 <= s < t <= T; the
        jump a sampler that skips from t to s takes. Products are cached per (t, s)."""
        if not 0 <= s < t <= self.steps:
            raise ValueError(f"need 0 <= s < t <= {self.steps}, got t = {t}, s = {s}")
        if s == t - 1:
            return self._step[t]
        if (t, s) not in self._spans:
            span = self._step[s + 1]
            for r in range(s + 2, t + 1):
                span = self._step[r] @ span
            self._spans[t, s] = span
        return self._spans[t, s]

    def _timesteps(self, t: int | Tensor, shape: torch.Size, low: int, validate: bool) -> Tensor:
        """t broadcast to ``shape`` as a long tensor on the schedule's device; with ``validate``,
        checked to lie in low..T (reading its range on the host: a device sync)."""
        tt = torch.as_tensor(t, device=self.device).long()
        if validate and tt.numel() and (int(tt.min()) < low or int(tt.max()) > self.steps):
            raise ValueError(f"t must lie in {low}..{self.steps}")
        return torch.broadcast_to(tt, shape)

    def _codes(self, z: Tensor, upper: int, name: str, validate: bool) -> Tensor:
        """``z`` as long codes on the schedule's device; with ``validate``, checked to lie in 0..upper
        (reading its range on the host: a device sync)."""
        z = z.to(self.device).long()
        if validate and z.numel() and (int(z.min()) < 0 or int(z.max()) > upper):
            raise ValueError(f"{name} values must lie in 0..{upper}")
        return z

    def q_sample(
        self,
        z0: Tensor,
        t: int | Tensor,
        generator: torch.Generator | None = None,
        validate: bool = True,
        dtype: torch.dtype = torch.float64,
    ) -> Tensor:
        """Draw z_t ~ q(z_t | z0) = Q̄_t[:, z0]; t (1..T, or 0 for z0 itself) broadcasts with z0.

        ``generator`` must live on the schedule's device. ``validate=False`` skips the range checks
        of z0 and t, which make the host wait for the device: for a training step, whose codes come
        from the VQ-VAE and whose t from :class:`~m2d2m.processes.discrete_diffusion_loss.TimestepSampler`.
        ``dtype`` is that of the probabilities and the uniforms the draw takes (float32 for a training step).
        """
        z0 = self._codes(z0, self.num_codes - 1, "z0", validate)
        tt = self._timesteps(t, z0.shape, low=0, validate=validate)
        cumulative = self._matrices(dtype)[1]
        probs = cumulative[tt.reshape(-1), :, z0.reshape(-1)]  # (N, K+1): column z0 of Q̄_t
        u = torch.rand(probs.shape[0], generator=generator, dtype=dtype, device=self.device)
        return categorical(probs, u).reshape(z0.shape)

    def sample_prior(self, shape: tuple[int, ...], generator: torch.Generator | None = None) -> Tensor:
        """z_T for sampling: the mask with probability γ̄_T, otherwise a uniformly random code."""
        u = torch.rand(shape, generator=generator, dtype=torch.float64, device=self.device)
        codes = torch.randint(self.num_codes, shape, generator=generator, device=self.device)
        return torch.where(u < self.gamma_bar[-1], torch.full_like(codes, self.mask_index), codes)

    def posterior_probs(
        self,
        z_t: Tensor,
        x0_probs: Tensor,
        t: int | Tensor,
        s: int | None = None,
        validate: bool = True,
        dtype: torch.dtype = torch.float64,
    ) -> Tensor:
        """p(z_s | z_t) = Σ_k q(z_s | z_t, z0 = k)·x0_probs[k] in ``dtype`` (..., K+1): the reverse step
        from t (1..T) to s = t − 1 by default, or to an earlier ``s`` (0 <= s < t; ``t`` one int then):
        the step-skipping sampler's jump, exact for any Δ = t − s.

        With Bayes' rule q(z_s = j | z_t = i, k) = Q_{t|s}[i, j]·Q̄_s[j, k] / Q̄_t[i, k] (Q_{t|t−1} = Q_t),
        the mixture is Q_{t|s}[i, :] ⊙ (Q̄_s · (x0_probs / Q̄_t[i, :])): two row gathers and one matrix
        product. Codes k that cannot produce z_t (Q̄_t[i, k] = 0) get no weight. Differentiable in
        x0_probs.

        ``t`` is one int (a sampler's step: one product), or a tensor that broadcasts with z_t: t per
        sample (a training batch, shape (B, 1, …)) gathers each sample's Q̄_{t−1} and takes one batched
        product (``torch.bmm``), with no grouping by value that would make the host read t. A t that
        varies along every dimension takes one product per position. ``validate=False`` skips the
        range checks of z_t and t, which read them on the host (a device sync): for callers whose
        inputs are valid by construction. ``dtype`` is the precision of the whole computation:
        float64 by default (a sampler's), float32 for a training loss (:meth:`_matrices`).
        """
        num_codes = self.num_codes
        z = self._codes(z_t, num_codes, "z_t", validate)
        if tuple(x0_probs.shape) != (*z.shape, num_codes):
            raise ValueError(f"x0_probs must have shape {(*z.shape, num_codes)}, got {tuple(x0_probs.shape)}")
        probs = x0_probs.to(device=self.device, dtype=dtype)
        step, cumulative = self._matrices(dtype)
        if isinstance(t, int):
            if not 1 <= t <= self.steps:
                raise ValueError(f"t must lie in 1..{self.steps}, got {t}")
            s = t - 1 if s is None else s
            rows = self.span_matrix(t, s)[z].to(dtype)  # (..., K+1): q(z_t | z_s = j)
            weights = _x0_ratios(probs, cumulative[t][z, :num_codes]).reshape(-1, num_codes)
            return rows * (weights @ cumulative[s, :, :num_codes].T).reshape(rows.shape)
        if s is not None:
            raise ValueError("a skip to s needs one t for every position")
        t_group, z_group = self._groups(t, z, validate)
        rows = step[t_group[:, None], z_group]  # (G, M, K+1): q(z_t | z_{t−1} = j)
        reach = cumulative[t_group[:, None], z_group, :num_codes]  # (G, M, K): q(z_t | z0 = k)
        weights = _x0_ratios(probs.reshape(*z_group.shape, num_codes), reach)
        earlier = cumulative[t_group - 1, :, :num_codes]  # (G, K+1, K): Q̄_{t−1}
        return (rows * torch.bmm(weights, earlier.transpose(1, 2))).reshape(*z.shape, num_codes + 1)

    def step(self, z_t: Tensor, x0_probs: Tensor, t: int, s: int, uniforms: Tensor) -> Tensor:
        """z_s drawn for z_t: the reverse jump p_θ(z_s | z_t) = Σ_k q(z_s | z_t, z0 = k)·p_θ(z0 = k | z_t)
        of M2D2M (Chi et al., 2024), eq. 4 (:meth:`posterior_probs`, exact for any jump s < t), drawn
        by :func:`categorical` with one uniform per position. No mask survives the last jump (s = 0):
        a position that draws it takes its most probable code.

        ``x0_probs`` (..., K) is the denoiser's p_θ(z0 | z_t, y), after guidance and truncation. The
        tokens are not range-checked, which would read them on the host every step: a sampler's
        are valid by construction."""
        probs = self.posterior_probs(z_t, x0_probs, t, s, validate=False)
        z_s = categorical(probs, uniforms)
        if s == 0:
            z_s = torch.where(z_s == self.mask_index, x0_probs.argmax(dim=-1), z_s)
        return z_s

    def true_posterior(
        self, z_t: Tensor, z0: Tensor, t: int | Tensor, validate: bool = True, dtype: torch.dtype = torch.float64
    ) -> Tensor:
        """q(z_{t−1} | z_t, z0) for known codes z0 in ``dtype`` (..., K+1): :meth:`posterior_probs` at a
        one-hot x0, Q_t[z_t, j]·Q̄_{t−1}[j, z0] / Q̄_t[z_t, z0], by gathers alone (the target of the
        training loss's KL, paper Eq. 3). Zero where z0 cannot produce z_t. ``t`` broadcasts with z_t."""
        z = self._codes(z_t, self.num_codes, "z_t", validate)
        codes = self._codes(z0, self.num_codes - 1, "z0", validate)
        if codes.shape != z.shape:
            raise ValueError(f"z0 must have the shape of z_t {tuple(z.shape)}, got {tuple(codes.shape)}")
        tt = self._timesteps(t, z.shape, low=1, validate=validate)
        step, cumulative = self._matrices(dtype)
        weight = _x0_ratios(1.0, cumulative[tt, z, codes])  # 1 / q(z_t | z0)
        earlier = cumulative[tt - 1, :, codes]  # (..., K+1): q(z_{t−1} = j | z0), indices' dims first
        return step[tt, z] * (weight[..., None] * earlier)

    def _groups(self, t: Tensor, z: Tensor, validate: bool) -> tuple[Tensor, Tensor]:
        """t per group of positions that share it, (G,), and the codes as (G, M): the groups are the
        leading dimensions of z along which t varies (t broadcasts with z as NumPy's rules say)."""
        tt = torch.as_tensor(t, device=self.device).long()
        if tt.dim() > z.dim():
            raise ValueError(f"t of shape {tuple(tt.shape)} does not broadcast with z_t of shape {tuple(z.shape)}")
        shape = (1,) * (z.dim() - tt.dim()) + tuple(tt.shape)
        # 0 when t is one number; max(..., default=0) would break torch.compile's graph here (dynamo)
        lead = max([0, *(d + 1 for d, n in enumerate(shape) if n != 1)])
        self._timesteps(tt, tt.shape, low=1, validate=validate)
        t_group = torch.broadcast_to(tt.reshape(shape[:lead]), z.shape[:lead]).reshape(-1)
        return t_group, z.reshape(t_group.shape[0], math.prod(z.shape[lead:]))


def categorical(probs: Tensor, uniforms: Tensor) -> Tensor:
    """Inverse-CDF draw over the last dimension with given uniforms in [0, 1), so that a caller
    decides whose random stream each draw takes.

    Counting the states whose CDF stays at or below u·total never picks a zero-probability state;
    a row with no mass at all gets the last state (the mask), which a sampler treats as undecided.
    """
    cdf = probs.cumsum(dim=-1)
    chosen = (cdf <= uniforms.unsqueeze(-1).to(cdf.dtype) * cdf[..., -1:]).sum(dim=-1)
    return chosen.clamp_max(probs.shape[-1] - 1)


def _x0_ratios(probs: Tensor | float, reach: Tensor) -> Tensor:
    """x0_probs[k] / Q̄_t[z_t, k], each z0 = k's weight in the posterior mixture; zero where k
    cannot produce z_t."""
    feasible = reach > 0
    return torch.where(feasible, probs / torch.where(feasible, reach, 1.0), 0.0)
