"""The motion VQ-VAE of T2M-GPT (Zhang et al. 2023; Mael-zys/T2M-GPT, ``models/vqvae.py``,
``models/encdec.py``, ``models/quantize_cnn.py``), re-implemented device-agnostically.

Features ``(B, T, D)`` are encoded by a strided 1-D convolution stack into one latent per
``2**down_t`` frames, each latent is replaced by its nearest code in an EMA codebook with dead-code
reset, and a mirror-image decoder with nearest-neighbour upsampling maps the codes back to frames.
The codebook is also what the denoiser builds its distance-aware transitions from.

A tokenizer may cover one body part (``VQConfig.part``, MMM's part tokenizers: Pinyoanuntapong et
al., CVPR 2024, §3.3): it reads the whole body's features, encodes only its part's dimensions
(:mod:`m2d2m.motion.representation.body_parts`) and decodes those alone.

Differences from the reference code, each on purpose: no hard-coded CUDA; any ``T`` (padded at the
end by repeating the last frame, the reconstruction cropped back); ``decode`` works for any batch
size; the quantizer computes in float32 even under autocast; dead codes are selected with
``torch.where`` so a long-dead code whose EMA count underflowed to 0 cannot turn into NaN; under
``torch.distributed`` the codebook statistics are all-reduced so every replica keeps the same
codebook; a training step reads nothing back on the host (the code histogram is an ``index_add``,
not ``bincount``, whose output size the host must learn; the reset is a ``torch.where``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
import torch.nn.functional as F
from torch import nn

from m2d2m.model_files import PLAIN, ModelFileKind, Network, Normalization
from m2d2m.motion.representation.body_parts import FULL, PARTS, part_dims, skeleton_of_width
from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.motion.representation.smoothing import gaussian_kernel
from m2d2m.networks.config import ConfigError, NetworkConfig

_ACTIVATIONS: dict[str, type[nn.Module]] = {"relu": nn.ReLU, "silu": nn.SiLU, "gelu": nn.GELU}


@dataclass(frozen=True)
class VQConfig(NetworkConfig):
    """Architecture of the VQ-VAE; the defaults are T2M-GPT's published ones (HumanML3D, 263-d)."""

    feature_dim: int = 263
    width: int = 512
    depth: int = 3
    dilation_growth: int = 3
    down_t: int = 2
    code_dim: int = 512
    codebook_size: int = 512
    ema_decay: float = 0.99
    # dead-code reset: every step, dead = EMA count below 1 (T2M-GPT), or every N steps, dead =
    # unused by the last N batches (MMM resets every 20; see :class:`EMACodebook`)
    reset_every: int = 1
    activation: str = "relu"
    # σ (frames) of a fixed Gaussian low-pass on the decoder's output, trained through; 0 is
    # T2M-GPT's decoder. Not in T2M-GPT: see :class:`TemporalLowPass` and docs/training.md.
    output_smoothing: float = 0.0
    # the body part it tokenizes: full, or upper / lower (MMM's part tokenizers); ``feature_dim``
    # stays the whole body's, which it reads
    part: str = FULL

    def __post_init__(self) -> None:
        self.require_positive(
            "feature_dim", "width", "depth", "dilation_growth", "code_dim", "codebook_size", "reset_every"
        )
        if not isinstance(self.down_t, int) or self.down_t < 0:
            raise ConfigError(f"VQConfig.down_t must be a non-negative integer, got {self.down_t!r}")
        self.require_fraction("ema_decay", open_low=True)
        if not isinstance(self.output_smoothing, (int, float)) or not 0 <= self.output_smoothing <= 8:
            raise ConfigError(
                f"VQConfig.output_smoothing must be a number of frames in [0, 8], got {self.output_smoothing!r}"
            )
        self.require_choice("activation", sorted(_ACTIVATIONS))
        self.require_choice("part", (FULL, *PARTS))
        if self.part != FULL:
            try:
                skeleton_of_width(self.feature_dim)
            except ValueError as error:
                raise ConfigError(f"VQConfig.part {self.part!r}: {error}") from error

    @property
    def dims(self) -> np.ndarray:
        """The feature dimensions it encodes and decodes: its part's, or all of them."""
        if self.part == FULL:
            return np.arange(self.feature_dim)
        return part_dims(skeleton_of_width(self.feature_dim), self.part)


# --------------------------------------------------------------------------------------------------
# Quantizer


@dataclass
class Quantized:
    """What the quantizer returns. ``quantized`` has the input's shape and dtype and carries the
    straight-through gradient; ``perplexity`` and ``active_codes`` describe this batch's code
    histogram (summed over ranks in distributed training)."""

    quantized: torch.Tensor
    indices: torch.Tensor
    commit_loss: torch.Tensor
    perplexity: torch.Tensor
    active_codes: torch.Tensor


def _distributed() -> bool:
    return dist.is_available() and dist.is_initialized()


class EMACodebook(nn.Module):
    """Nearest-neighbour codebook updated by exponential moving averages, with dead-code reset
    (T2M-GPT's ``QuantizeEMAReset``).

    The codebook and its EMA statistics are buffers, not parameters: the optimiser never sees
    them and the only loss term is the commitment loss. A code whose EMA count falls below 1 is
    dead; its codebook row is replaced by an encoder output of the current batch. As in the
    reference, its EMA statistics are not reset: it stays dead (and is re-drawn every step) until
    its count climbs back to 1, i.e. until it averages more than one vector per batch, so batches
    need several encoder outputs per code.

    With ``reset_every`` = N > 1 (MMM's tokenizer, N = 20: Pinyoanuntapong et al., CVPR 2024,
    supplement §C) codes are reset only every N steps, and a code is dead when none of the last N
    batches used it: a large codebook (8192) then keeps rarely used codes instead of re-drawing
    them every step. Its usage counter exists only then, so T2M-GPT-style model files keep their
    buffers.

    Whether the codebook is initialised is a buffer (it travels with checkpoints); the quantizer
    reads it on the host once, at its first training call after construction or a state dict
    load, and remembers it, rather than at every step.
    """

    def __init__(self, codebook_size: int, code_dim: int, decay: float = 0.99, reset_every: int = 1) -> None:
        super().__init__()
        self.codebook_size = codebook_size
        self.code_dim = code_dim
        self.decay = decay
        self.reset_every = reset_every
        self.register_buffer("codebook", torch.zeros(codebook_size, code_dim))
        self.register_buffer("code_sum", torch.zeros(codebook_size, code_dim))
        self.register_buffer("code_count", torch.zeros(codebook_size))
        self.register_buffer("initialised", torch.tensor(False))
        if reset_every > 1:
            self.register_buffer("recent_usage", torch.zeros(codebook_size))
            self.register_buffer("updates", torch.tensor(0))
        self._known_initialised = False  # the buffer read True since construction or the last load
        self.register_load_state_dict_post_hook(_forget_initialised)

    def _sample(self, vectors: torch.Tensor) -> torch.Tensor:
        """``codebook_size`` rows drawn from ``vectors`` without replacement; when there are
        fewer vectors than codes they are tiled and jittered (std 0.01/√D) so copies differ."""
        n = vectors.shape[0]
        if n < self.codebook_size:
            vectors = vectors.repeat(math.ceil(self.codebook_size / n), 1)
            vectors = vectors + torch.randn_like(vectors) * (0.01 / math.sqrt(self.code_dim))
        order = torch.randperm(vectors.shape[0], device=vectors.device)[: self.codebook_size]
        sample = vectors[order].contiguous()
        if _distributed():
            dist.broadcast(sample, src=0)
        return sample

    @torch.no_grad()
    def initialise(self, vectors: torch.Tensor) -> None:
        """Fill the codebook from data (N, code_dim) so no code starts far from the encoder's
        outputs; EMA sums start at the codes with a count of one."""
        sample = self._sample(vectors.detach().float())
        self.codebook.copy_(sample)
        self.code_sum.copy_(sample)
        self.code_count.fill_(1.0)
        self.initialised.fill_(True)
        self._known_initialised = True

    def nearest(self, vectors: torch.Tensor) -> torch.Tensor:
        """Index of the nearest code (squared L2) for each row of ``vectors`` (N, code_dim)."""
        with torch.autocast(device_type=vectors.device.type, enabled=False):
            codebook = self.codebook.float()
            # ‖x‖² is the same for every code, so it is left out of the argmin.
            distance = codebook.pow(2).sum(1) - 2.0 * vectors.float() @ codebook.t()
            return distance.argmin(1)

    @torch.no_grad()
    def _update(self, vectors: torch.Tensor, indices: torch.Tensor, counts: torch.Tensor) -> None:
        sums = torch.zeros_like(self.code_sum, dtype=torch.float32).index_add_(0, indices, vectors)
        if _distributed():
            dist.all_reduce(sums)
        mu = self.decay
        self.code_sum.mul_(mu).add_(sums, alpha=1.0 - mu)
        self.code_count.mul_(mu).add_(counts, alpha=1.0 - mu)
        mean = self.code_sum / self.code_count.unsqueeze(1).clamp_min(1e-12)
        # drawn every step, dead codes or not, so every rank takes part in its broadcast
        self.codebook.copy_(torch.where(self._dead(counts).unsqueeze(1), self._sample(vectors), mean))

    def _dead(self, counts: torch.Tensor) -> torch.Tensor:
        """(K,) bool: the codes to re-draw after this step's update; with ``reset_every`` N, those
        unused since the last reset at every N-th update and none in between (decided on the
        device)."""
        if self.reset_every == 1:
            return self.code_count < 1.0
        self.recent_usage.add_(counts)
        self.updates.add_(1)
        due = self.updates % self.reset_every == 0
        dead = due & (self.recent_usage == 0)
        self.recent_usage.masked_fill_(due, 0.0)
        return dead

    def forward(self, x: torch.Tensor) -> Quantized:
        """Quantize ``x`` (..., code_dim). In training mode the first call initialises the
        codebook from ``x`` and every call updates it; in eval mode the buffers are untouched."""
        shape, dtype = x.shape, x.dtype
        with torch.autocast(device_type=x.device.type, enabled=False):
            flat = x.reshape(-1, self.code_dim).float()
            if self.training and not self._known_initialised:
                if not bool(self.initialised):  # once per construction or load: see the class
                    self.initialise(flat)
                self._known_initialised = True
            indices = self.nearest(flat)
            counts = torch.zeros(self.codebook_size, device=flat.device).index_add_(
                0, indices, torch.ones_like(indices, dtype=torch.float32)
            )
            if self.training:
                if _distributed():
                    dist.all_reduce(counts)
                self._update(flat.detach(), indices, counts)
            codes = F.embedding(indices, self.codebook.float())
            commit_loss = F.mse_loss(flat, codes.detach())
            # Straight-through: the value is exactly the code, the gradient is the identity to x.
            quantized = codes.detach() + (flat - flat.detach())
            probs = counts / counts.sum()
            perplexity = torch.exp(-torch.special.xlogy(probs, probs).sum())
        return Quantized(
            quantized=quantized.reshape(shape).to(dtype),
            indices=indices.reshape(shape[:-1]),
            commit_loss=commit_loss,
            perplexity=perplexity,
            active_codes=(counts > 0).sum(),
        )


def _forget_initialised(quantizer: EMACodebook, incompatible_keys: object) -> None:
    """After a state dict load the ``initialised`` buffer may say otherwise: read it again."""
    quantizer._known_initialised = False


# --------------------------------------------------------------------------------------------------
# Encoder and decoder


class ResBlock(nn.Module):
    """Pre-activation residual block: act → dilated conv k3 → act → conv k1, plus the input."""

    def __init__(self, width: int, dilation: int, activation: str) -> None:
        super().__init__()
        self.body = nn.Sequential(
            _ACTIVATIONS[activation](),
            nn.Conv1d(width, width, 3, padding=dilation, dilation=dilation),
            _ACTIVATIONS[activation](),
            nn.Conv1d(width, width, 1),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.body(x)


def resnet1d(width: int, depth: int, growth: int, activation: str) -> nn.Sequential:
    """``depth`` residual blocks with dilations growth**i in reverse order (9, 3, 1), as T2M-GPT
    runs them in both encoder and decoder."""
    dilations = [growth**i for i in range(depth)][::-1]
    return nn.Sequential(*(ResBlock(width, d, activation) for d in dilations))


def _encoder(c: VQConfig) -> nn.Sequential:
    layers: list[nn.Module] = [nn.Conv1d(len(c.dims), c.width, 3, padding=1), _ACTIVATIONS[c.activation]()]
    for _ in range(c.down_t):
        layers += [
            nn.Conv1d(c.width, c.width, 4, stride=2, padding=1),
            resnet1d(c.width, c.depth, c.dilation_growth, c.activation),
        ]
    layers.append(nn.Conv1d(c.width, c.code_dim, 3, padding=1))
    return nn.Sequential(*layers)


def _decoder(c: VQConfig) -> nn.Sequential:
    layers: list[nn.Module] = [nn.Conv1d(c.code_dim, c.width, 3, padding=1), _ACTIVATIONS[c.activation]()]
    for _ in range(c.down_t):
        layers += [
            resnet1d(c.width, c.depth, c.dilation_growth, c.activation),
            nn.Upsample(scale_factor=2, mode="nearest"),
            nn.Conv1d(c.width, c.width, 3, padding=1),
        ]
    layers += [
        nn.Conv1d(c.width, c.width, 3, padding=1),
        _ACTIVATIONS[c.activation](),
        nn.Conv1d(c.width, len(c.dims), 3, padding=1),
        TemporalLowPass(c.output_smoothing),
    ]
    return nn.Sequential(*layers)


class TemporalLowPass(nn.Module):
    """A fixed Gaussian filter of σ frames along time, each channel alone, edges replicated (the
    same filter as :func:`m2d2m.motion.representation.smoothing.gaussian_smooth`); identity for σ = 0.

    Why: a decoder can leave broadband sub-millimetre jitter in every joint, which the
    transition metrics (the M2D2M paper's Jerk, eq. 10; FlowMDM's PJ/AUJ) weigh far above anything
    visible. Off in every shipped config: on the calibrated corpus T2M-GPT's decoder is already as
    smooth as the data (docs/training.md, "Smooth decoding"). As the decoder's last layer it is
    trained through, so the reconstruction loss sees the output that is used."""

    def __init__(self, sigma: float) -> None:
        super().__init__()
        self.sigma = float(sigma)
        kernel = gaussian_kernel(self.sigma) if self.sigma > 0 else np.ones(1)
        self.register_buffer("kernel", torch.tensor(kernel, dtype=torch.float32).view(1, 1, -1), persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, C, T) → (B, C, T)."""
        if self.sigma == 0:
            return x
        radius = self.kernel.shape[-1] // 2
        batch, channels, frames = x.shape
        padded = F.pad(x.reshape(batch * channels, 1, frames), (radius, radius), mode="replicate")
        return F.conv1d(padded, self.kernel.to(x.dtype)).reshape(batch, channels, frames)


# --------------------------------------------------------------------------------------------------
# The model


@dataclass
class VQOutput:
    """Result of :meth:`MotionVQVAE.forward`: the reconstruction (B, T, D_part) of the model's
    dimensions (:attr:`VQConfig.dims`) in normalised feature space, the commitment loss, the
    tokens (B, ceil(T / frames_per_token)) and codebook usage."""

    reconstruction: torch.Tensor
    commit_loss: torch.Tensor
    tokens: torch.Tensor
    perplexity: torch.Tensor
    active_codes: torch.Tensor


class MotionVQVAE(nn.Module):
    """Encoder → EMA codebook → decoder on normalised motion features (B, T, D); a part's model
    reads the same (B, T, D) and writes its part's dimensions (B, T, D_part)."""

    def __init__(self, config: VQConfig | None = None) -> None:
        super().__init__()
        self.config = config or VQConfig()
        self.register_buffer("dims", torch.as_tensor(self.config.dims), persistent=False)
        self.encoder = _encoder(self.config)
        self.quantizer = EMACodebook(
            self.config.codebook_size, self.config.code_dim, self.config.ema_decay, self.config.reset_every
        )
        self.decoder = _decoder(self.config)

    @property
    def frames_per_token(self) -> int:
        return 2**self.config.down_t

    @property
    def codebook(self) -> torch.Tensor:
        """The (K, code_dim) code vectors (a buffer, so never part of a gradient)."""
        return self.quantizer.codebook

    def select(self, x: torch.Tensor) -> torch.Tensor:
        """The dimensions of full features (..., D) that this model encodes and reconstructs."""
        return x if self.config.part == FULL else x[..., self.dims]

    def _latents(self, x: torch.Tensor) -> torch.Tensor:
        """Encoder outputs (B, L, code_dim); ``x`` is padded at the end to a whole number of
        tokens by repeating its last frame, which keeps the padding on the motion's manifold."""
        if x.ndim != 3 or x.shape[-1] != self.config.feature_dim or x.shape[1] < 1:
            raise ValueError(f"expected features (B, T >= 1, {self.config.feature_dim}), got {tuple(x.shape)}")
        x = self.select(x)
        missing = -x.shape[1] % self.frames_per_token
        if missing:
            x = torch.cat([x, x[:, -1:].expand(-1, missing, -1)], dim=1)
        return self.encoder(x.transpose(1, 2)).transpose(1, 2)

    def _decode_latents(self, latents: torch.Tensor) -> torch.Tensor:
        return self.decoder(latents.transpose(1, 2)).transpose(1, 2)

    def forward(self, x: torch.Tensor) -> VQOutput:
        frames = x.shape[1]
        quantized = self.quantizer(self._latents(x))
        return VQOutput(
            reconstruction=self._decode_latents(quantized.quantized)[:, :frames],
            commit_loss=quantized.commit_loss,
            tokens=quantized.indices,
            perplexity=quantized.perplexity,
            active_codes=quantized.active_codes,
        )

    @torch.no_grad()
    def encode(self, x: torch.Tensor) -> torch.Tensor:
        """Token indices (B, ceil(T / frames_per_token)), long; never updates the codebook."""
        latents = self._latents(x)
        return self.quantizer.nearest(latents.reshape(-1, self.config.code_dim)).reshape(latents.shape[:2])

    def decode(self, tokens: torch.Tensor) -> torch.Tensor:
        """Features (B, frames_per_token · L, D_part) for token indices (B, L): its part's dimensions."""
        if tokens.ndim != 2:
            raise ValueError(f"expected tokens (B, L), got {tuple(tokens.shape)}")
        return self._decode_latents(F.embedding(tokens.long(), self.codebook))


# --------------------------------------------------------------------------------------------------
# Model files


# the hand-over from VQ training to tokenizing and the token models: the network, the normalisation
# of its features and its skeleton's name, in one self-contained file (whose payload the token
# models' files embed whole)
VQ_FORMAT = ModelFileKind(
    "m2d2m-vq/1",
    "a VQ-VAE model file",
    {"model": Network.of(MotionVQVAE, VQConfig), "normalizer": Normalization(), "skeleton": PLAIN, "extra": PLAIN},
    inline=frozenset({"model", "normalizer"}),
)


def load_vq(path: str | Path, map_location: str | torch.device = "cpu") -> tuple[MotionVQVAE, Normalizer, dict]:
    """Read a VQ model file: the model (eval mode, on ``map_location``), its normaliser, and
    ``{"skeleton", "part", "extra"}`` (``part``: the body part it tokenizes); ValueError when the
    file is not one."""
    payload = VQ_FORMAT.read(path, map_location)
    try:
        return vq_from_payload(payload, map_location)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from error


def vq_from_payload(payload: dict, map_location: str | torch.device = "cpu") -> tuple[MotionVQVAE, Normalizer, dict]:
    """The model, normaliser and ``{"skeleton", "part", "extra"}`` of a VQ file's contents — also
    used when a model file carries its VQ-VAE inside it."""
    try:
        parts = VQ_FORMAT.restore(payload, map_location)
    except (KeyError, TypeError, ValueError, AttributeError, RuntimeError) as error:
        # a file with the format tag whose contents do not fit the model (missing keys, other
        # shapes): the caller gets a ValueError naming what is wrong, like any unreadable file
        raise ValueError(
            f"not a usable VQ-VAE ({type(error).__name__}: {' '.join(str(error).split())[:200]})"
        ) from error
    model = parts["model"]
    return (
        model,
        parts["normalizer"],
        {"skeleton": parts["skeleton"], "part": model.config.part, "extra": parts["extra"]},
    )
