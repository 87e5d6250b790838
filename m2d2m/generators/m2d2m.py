"""M2D2M's generator: action sentences and lengths in frames → tokens by the discrete-diffusion
sampler (Two-Phase Sampling or a baseline, :mod:`m2d2m.generators.m2d2m_sampling`) → motion by the
VQ-VAE decoder, from one self-contained checkpoint (:mod:`m2d2m.generators.m2d2m_checkpoint`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch

from m2d2m.generators.m2d2m_checkpoint import Checkpoint, load_checkpoint
from m2d2m.generators.m2d2m_sampling import (FREE, METHODS, MULTI_ACTION, SINGLE_ACTION, Request, SamplingOptions,
                                             TokenSampler, switch_step)
from m2d2m.generators.protocol import MULTI, SINGLE, Keep, MotionGenerator
from m2d2m.motion.clip import Motion
from m2d2m.motion.joining import slerp_join
from m2d2m.motion.normalization import Normalizer
from m2d2m.motion.representation import features_to_joints, joints_to_features
from m2d2m.motion.skeleton import Skeleton
from m2d2m.networks.vqvae import MotionVQVAE


def decode_tokens(vq: MotionVQVAE, normalizer: Normalizer, tokens: torch.Tensor) -> np.ndarray:
    """Un-normalised features (F, D) of one token sequence, decoded on the VQ-VAE's device."""
    device = next(vq.parameters()).device
    with torch.no_grad():
        return normalizer.denormalize(vq.decode(tokens[None].to(device))[0].cpu().numpy())


class M2D2MGenerator(MotionGenerator):
    """A loaded M2D2M checkpoint behind the generator protocol."""

    model = "m2d2m"
    methods = METHODS
    options_type = SamplingOptions
    presets = {MULTI: MULTI_ACTION, SINGLE: SINGLE_ACTION}

    def __init__(self, checkpoint: Checkpoint, source: Path) -> None:
        self.checkpoint = checkpoint
        self.source = source
        self.sampler = TokenSampler(checkpoint.denoiser, checkpoint.text_encoder, checkpoint.schedule)

    @classmethod
    def load(cls, path: str | Path, device: str | torch.device = "cpu") -> "M2D2MGenerator":
        return cls(load_checkpoint(path, device), Path(path))

    # -------------------------------------------------------------------------- what it is
    @property
    def skeleton(self) -> Skeleton:
        return self.checkpoint.skeleton

    @property
    def feature_dim(self) -> int:
        return int(self.checkpoint.normalizer.mean.shape[-1])

    @property
    def device(self) -> torch.device:
        return self.sampler.device

    @property
    def data_dir(self) -> Path | None:
        data_dir = self.checkpoint.extra.get("data_dir")
        return Path(data_dir) if data_dir else None

    @property
    def frame_step(self) -> int:
        return self.checkpoint.frames_per_token

    def typical_frames(self, verb: str | None) -> int:
        return self.checkpoint.lengths.tokens_for(verb) * self.frame_step

    @property
    def longest_frames(self) -> int:
        return self.checkpoint.lengths.longest * self.frame_step

    def check_options(self, options: SamplingOptions) -> None:
        options.check(self.checkpoint.schedule.steps)

    def describe(self, options: SamplingOptions) -> str:
        steps = self.checkpoint.schedule.steps
        eta = self.checkpoint.schedule.config.eta if options.eta is None else options.eta
        phases = f"T_s = {switch_step(options.ts, steps)} of T = {steps}, " if options.method == "tps" else ""
        return f"{phases}η = {eta:g}, s = {options.guidance:g}"

    # ----------------------------------------------------------------------------- the call
    def generate(self, actions: Sequence[Sequence[str]], frames: Sequence[Sequence[int]], options: SamplingOptions,
                 seeds: Sequence[int], keep: Sequence[Keep | None] | None = None,
                 progress: Callable[[float], None] | None = None) -> list[Motion]:
        """Sample every sequence in one batch of the sampler and decode each (see the protocol)."""
        keep = [None] * len(actions) if keep is None else keep
        lengths = [[self.round_frames(n) // self.frame_step for n in sequence] for sequence in frames]
        requests = [Request([[a] for a in sequence], tokens, int(seed), self._given(kept, sum(tokens)))
                    for sequence, tokens, seed, kept in zip(actions, lengths, seeds, keep)]
        steps = self.checkpoint.schedule.steps
        tokens = self.sampler.sample(requests, options,
                                     None if progress is None else lambda t: progress((steps - t + 1) / steps))
        settings = {**asdict(options), "model": self.model, "checkpoint": str(self.source)}
        return [self.decode(pieces, list(sequence), options, {**settings, "seed": int(seed)})
                for pieces, sequence, seed in zip(tokens, actions, seeds)]

    def _given(self, keep: Keep | None, tokens: int) -> torch.Tensor | None:
        """The sampler's fixed tokens for a :class:`Keep`: the VQ-VAE's tokens of the kept features
        wherever a token holds a kept frame, :data:`FREE` elsewhere."""
        if keep is None:
            return None
        encoded = self.encode(keep.features)
        if len(encoded) != tokens:
            raise ValueError(f"the kept motion holds {len(encoded)} tokens but the request asks for {tokens}")
        held = np.zeros(tokens, dtype=bool)
        units = np.flatnonzero(keep.frames) // self.frame_step
        held[units[units < tokens]] = True
        return torch.where(torch.as_tensor(held), encoded, torch.full_like(encoded, FREE))

    def encode(self, features: np.ndarray) -> torch.Tensor:
        """The VQ-VAE's tokens (on the CPU) of un-normalised features (F, D): one per 4 frames."""
        normalizer = self.checkpoint.normalizer
        with torch.no_grad():
            normalized = torch.as_tensor(normalizer.normalize(features), dtype=torch.float32, device=self.device)
            return self.checkpoint.vq.encode(normalized[None])[0].cpu()

    def reconstruct(self, segments: Sequence[Sequence[np.ndarray]]) -> list[Motion]:
        """Each sequence's segments encoded by the VQ-VAE, their tokens concatenated and decoded
        together: the ceiling of any sampler over these tokens (paper Table 3's "VQ-VAE" row)."""
        options = self.options(MULTI, method="independent")
        return [self.decode([self.encode(clip) for clip in clips], [f"segment {i + 1}" for i in range(len(clips))],
                            options, {"model": self.model, "method": "vq reconstruction",
                                      "checkpoint": str(self.source)})
                for clips in segments]

    def decode(self, pieces: list[torch.Tensor], actions: list[str], options: SamplingOptions,
               settings: dict[str, Any]) -> Motion:
        """Tokens per action → one Motion: decoded together, or (``slerp``) one by one and joined."""
        skeleton, per_token = self.skeleton, self.frame_step
        vq, normalizer = self.checkpoint.vq, self.checkpoint.normalizer
        if options.method == "slerp":
            decoded = [decode_tokens(vq, normalizer, p) for p in pieces]
            joints, ranges = slerp_join([features_to_joints(f, skeleton) for f in decoded],
                                        options.slerp * per_token, skeleton)
            features = joints_to_features(np.concatenate([joints, joints[-1:]]), skeleton)
        else:
            features = decode_tokens(vq, normalizer, torch.cat(pieces))
            joints = features_to_joints(features, skeleton)
            ends = np.cumsum([len(p) * per_token for p in pieces])
            ranges = [(int(end - len(p) * per_token), int(end)) for p, end in zip(pieces, ends)]
        return Motion(features, np.asarray(joints, dtype=np.float32), self.fps, skeleton.name, list(actions),
                      ranges, settings, torch.cat(pieces).cpu().numpy())
