"""M2D2M's generator: action sentences and lengths in frames → tokens by the discrete-diffusion
sampler (Two-Phase Sampling or a baseline, :mod:`m2d2m.generators.m2d2m.sampling`) → motion by the
VQ-VAE decoder, from one self-contained checkpoint (:mod:`m2d2m.generators.m2d2m.checkpoint`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import torch

from m2d2m.generators.m2d2m.checkpoint import M2D2MCheckpoint, load_m2d2m
from m2d2m.generators.m2d2m.options import SAMPLING, M2D2MOptions
from m2d2m.generators.m2d2m.sampling import TokenRequest, TokenSampler, switch_step
from m2d2m.generators.protocol import Keep
from m2d2m.generators.token_model import TokenModelGenerator
from m2d2m.motion.clip import Motion
from m2d2m.motion.representation.features import features_to_joints, joints_to_features
from m2d2m.motion.transforms.joining import slerp_join


class M2D2MGenerator(TokenModelGenerator):
    """A loaded M2D2M checkpoint behind the generator protocol."""

    model = "m2d2m"
    sampling = SAMPLING

    def __init__(self, checkpoint: M2D2MCheckpoint, source: Path) -> None:
        self.checkpoint = checkpoint
        self.source = source
        self.codec, self.lengths, self.extra = checkpoint.codec, checkpoint.lengths, checkpoint.extra
        self.sampler = TokenSampler(checkpoint.denoiser, checkpoint.text_encoder, checkpoint.schedule)

    @classmethod
    def load(cls, path: str | Path, device: str | torch.device = "cpu") -> M2D2MGenerator:
        return cls(load_m2d2m(path, device), Path(path))

    @property
    def device(self) -> torch.device:
        return self.sampler.device

    @property
    def model_defaults(self) -> dict[str, Any]:
        """The steps, truncation and guidance its config's ``sampling`` section chose."""
        return dict(self.checkpoint.sampling)

    def check_options(self, options: M2D2MOptions) -> None:
        options.check(self.checkpoint.schedule.steps)

    def describe(self, options: M2D2MOptions) -> str:
        steps = self.checkpoint.schedule.steps
        eta = self.checkpoint.schedule.config.eta if options.eta is None else options.eta
        phases = f"T_s = {switch_step(options.ts, steps)} of T = {steps}, " if options.method == "tps" else ""
        truncation = f", r = {options.truncation:g}" if options.truncation < 1.0 else ""
        taken = f", {options.steps} of {steps} steps" if options.steps not in (None, steps) else ""
        return f"{phases}η = {eta:g}, s = {options.guidance:g}{truncation}{taken}"

    # ----------------------------------------------------------------------------- the call
    def generate(
        self,
        actions: Sequence[Sequence[str]],
        frames: Sequence[Sequence[int]],
        options: M2D2MOptions,
        seeds: Sequence[int],
        keep: Sequence[Keep | None] | None = None,
        progress: Callable[[float], None] | None = None,
    ) -> list[Motion]:
        """Sample every sequence in one batch of the sampler and decode each (see the protocol)."""
        keep = [None] * len(actions) if keep is None else keep
        lengths = self.tokens_of(frames)
        requests = [
            TokenRequest([[a] for a in sequence], tokens, int(seed), self.given_tokens(kept, sum(tokens)))
            for sequence, tokens, seed, kept in zip(actions, lengths, seeds, keep)
        ]
        steps = self.checkpoint.schedule.steps
        tokens = self.sampler.sample(
            requests, options, None if progress is None else lambda s: progress((steps - s) / steps)
        )
        settings = {**asdict(options), "model": self.model, "checkpoint": str(self.source)}
        return [
            self.decode(pieces, list(sequence), options, {**settings, "seed": int(seed)})
            for pieces, sequence, seed in zip(tokens, actions, seeds)
        ]

    def decode(
        self, pieces: list[torch.Tensor], actions: list[str], options: M2D2MOptions, settings: dict[str, Any]
    ) -> Motion:
        """Tokens per action → one Motion: decoded together, or (``slerp``) one by one and joined."""
        if options.method != "slerp":
            return self.codec.motion(pieces, actions, settings)
        skeleton = self.skeleton
        joints, ranges = slerp_join(
            [features_to_joints(self.codec.decode(p), skeleton) for p in pieces],
            options.slerp * self.frame_step,
            skeleton,
        )
        features = joints_to_features(np.concatenate([joints, joints[-1:]]), skeleton)
        return Motion(
            features,
            np.asarray(joints, dtype=np.float32),
            self.fps,
            skeleton.name,
            list(actions),
            ranges,
            settings,
            torch.cat(pieces).cpu().numpy(),
        )
