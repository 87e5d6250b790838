"""What every generator over VQ-VAE motion tokens shares (M2D2M, MMM): the codec that turns
features into tokens and back (a pair of body-part codecs for MMM's upper-body editing), and the
protocol's properties that follow from it and the corpus's length prior (:class:`TokenModelGenerator`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from m2d2m.generators.protocol import Keep, MotionGenerator
from m2d2m.model_files import LengthPrior, Part
from m2d2m.motion.clip import Motion
from m2d2m.motion.representation.body_parts import FULL, LOWER, UPPER, merge
from m2d2m.motion.representation.features import features_to_joints
from m2d2m.motion.representation.normalization import Normalizer
from m2d2m.motion.representation.skeleton import SKELETONS, Skeleton
from m2d2m.networks.vqvae import VQ_FORMAT, MotionVQVAE, vq_from_payload
from m2d2m.precision import full_precision
from m2d2m.text import TextEncoder

FREE = -1  # a token position a generator fills (the samplers' and decoders' convention)


@dataclass
class TokenCodec:
    """The VQ-VAE a token model decodes with, its normalisation and skeleton. A body part's
    tokenizer (``vq.config.part``) encodes whole-body features and decodes its part's dimensions
    (:attr:`dims`); only a whole-body codec makes a :class:`Motion`."""

    vq: MotionVQVAE
    normalizer: Normalizer
    skeleton: Skeleton

    @classmethod
    def from_payload(cls, payload: dict[str, Any], device: str | torch.device = "cpu") -> TokenCodec:
        """From a VQ model file's payload embedded in a model's file, on ``device``, in eval mode."""
        vq, normalizer, meta = vq_from_payload(payload, device)
        return cls(vq, normalizer, SKELETONS[meta["skeleton"]])

    @property
    def frames_per_token(self) -> int:
        return self.vq.frames_per_token

    @property
    def device(self) -> torch.device:
        return next(self.vq.parameters()).device

    @property
    def part(self) -> str:
        return self.vq.config.part

    @property
    def dims(self) -> np.ndarray:
        """The feature dimensions :meth:`decode` returns."""
        return self.vq.config.dims

    def encode(self, features: np.ndarray) -> torch.Tensor:
        """Tokens (on the CPU) of un-normalised features (F, D): one per ``frames_per_token`` frames."""
        with torch.no_grad(), full_precision(self.device):
            normalized = torch.as_tensor(self.normalizer.normalize(features), dtype=torch.float32, device=self.device)
            return self.vq.encode(normalized[None])[0].cpu()

    def decode(self, tokens: torch.Tensor) -> np.ndarray:
        """Un-normalised features (F, D) of one token sequence; a part's (F, D_part). In float32
        even inside a bf16 sampler: the decoder runs once, and its root velocities are integrated
        over the whole clip, where bf16's three digits would drift."""
        with torch.no_grad(), full_precision(self.device):
            decoded = self.vq.decode(tokens[None].to(self.device))[0].cpu().numpy()
        return self.normalizer.denormalize(decoded, None if self.part == FULL else self.dims)

    def motion(
        self,
        pieces: list[torch.Tensor],
        actions: list[str],
        settings: dict[str, Any],
        gaps: Sequence[torch.Tensor] = (),
    ) -> Motion:
        """One Motion from each action's tokens, decoded together in order, with ``gaps[j]`` (tokens
        that belong to no action: a transition) between actions j and j + 1."""
        if self.part != FULL:
            raise ValueError(f"a {self.part}-body tokenizer alone cannot make a whole motion")
        stream, ranges, start = [], [], 0
        per_token = self.frames_per_token
        for j, piece in enumerate(pieces):
            ranges.append((start * per_token, (start + len(piece)) * per_token))
            stream.append(piece)
            start += len(piece)
            if j < len(gaps):
                stream.append(gaps[j])
                start += len(gaps[j])
        tokens = torch.cat(stream)
        features = self.decode(tokens)
        joints = features_to_joints(features, self.skeleton)
        skeleton = self.skeleton
        return Motion(
            features,
            np.asarray(joints, dtype=np.float32),
            skeleton.fps,
            skeleton.name,
            list(actions),
            ranges,
            settings,
            tokens.cpu().numpy(),
        )


class EmbeddedVQ(Part):
    """A VQ-VAE model file carried whole inside a token model's file (the codec that decodes its
    tokens): saved from the VQ file's path, loaded as a :class:`TokenCodec`."""

    def dump(self, value: str | Path) -> dict[str, Any]:
        return VQ_FORMAT.read(value)

    def load(self, stored: dict[str, Any], device: str | torch.device) -> TokenCodec:
        return TokenCodec.from_payload(stored, device)


@dataclass
class BodyCodec(TokenCodec):
    """Two part tokenizers as one codec (MMM's upper-body editing, Pinyoanuntapong et al., CVPR
    2024, §3.3): a token is the pair (upper code, lower code), (L, 2); decoding decodes each half
    with its own VQ-VAE and merges the parts into whole-body features. ``vq`` is the upper body's."""

    lower: TokenCodec

    @classmethod
    def pair(cls, upper: TokenCodec, lower: TokenCodec) -> BodyCodec:
        """The codec of ``upper`` and ``lower`` tokenizers, or ValueError when they do not pair up."""
        if (upper.part, lower.part) != (UPPER, LOWER):
            raise ValueError(f"need an upper- and a lower-body tokenizer, got {upper.part} and {lower.part}")
        if upper.skeleton is not lower.skeleton or upper.frames_per_token != lower.frames_per_token:
            raise ValueError("the upper- and lower-body tokenizers differ in skeleton or frames per token")
        if not (
            np.array_equal(upper.normalizer.mean, lower.normalizer.mean)
            and np.array_equal(upper.normalizer.std, lower.normalizer.std)
            and upper.normalizer.feat_bias == lower.normalizer.feat_bias
        ):
            raise ValueError("the upper- and lower-body tokenizers normalise differently (other datasets?)")
        return cls(upper.vq, upper.normalizer, upper.skeleton, lower)

    @property
    def upper(self) -> TokenCodec:
        return TokenCodec(self.vq, self.normalizer, self.skeleton)

    @property
    def part(self) -> str:
        return FULL

    @property
    def dims(self) -> np.ndarray:
        return np.arange(self.skeleton.feature_dim)

    def encode(self, features: np.ndarray) -> torch.Tensor:
        """Token pairs (L, 2) of un-normalised whole-body features (F, D)."""
        return torch.stack([self.upper.encode(features), self.lower.encode(features)], dim=-1)

    def decode(self, tokens: torch.Tensor) -> np.ndarray:
        """Whole-body features (F, D) of token pairs (L, 2)."""
        return merge({UPPER: self.upper.decode(tokens[:, 0]), LOWER: self.lower.decode(tokens[:, 1])}, self.skeleton)


class TokenModelGenerator(MotionGenerator):
    """The protocol's properties for a model over a :class:`TokenCodec`'s tokens; subclasses set
    ``codec``, ``lengths``, ``extra`` and ``source`` and implement sampling."""

    edits = ("inbetween",)  # kept frames become kept tokens (:meth:`given_tokens`)
    checkpoint: Any  # the loaded model file: its networks, text encoder and records
    codec: TokenCodec
    lengths: LengthPrior
    extra: dict[str, Any]

    @property
    def text_encoder(self) -> TextEncoder:
        return self.checkpoint.text_encoder

    @property
    def known_verbs(self) -> tuple[str, ...]:
        return tuple(self.lengths.per_verb)

    @property
    def skeleton(self) -> Skeleton:
        return self.codec.skeleton

    @property
    def feature_dim(self) -> int:
        return int(self.codec.normalizer.mean.shape[-1])

    @property
    def data_dir(self) -> Path | None:
        data_dir = self.extra.get("data_dir")
        return Path(data_dir) if data_dir else None

    @property
    def frame_step(self) -> int:
        return self.codec.frames_per_token

    def typical_frames(self, verb: str | None) -> int:
        return self.lengths.typical(verb) * self.frame_step

    @property
    def longest_frames(self) -> int:
        return self.lengths.longest * self.frame_step

    def tokens_of(self, frames: Sequence[Sequence[int]]) -> list[list[int]]:
        """Each action's length in tokens for lengths asked in frames."""
        return [[self.round_frames(n) // self.frame_step for n in sequence] for sequence in frames]

    def given_tokens(self, keep: Keep | None, tokens: int) -> torch.Tensor | None:
        """The fixed tokens of a :class:`Keep`: the codec's tokens of the kept features wherever a
        token holds a kept frame, :data:`FREE` elsewhere (None without a Keep)."""
        if keep is None:
            return None
        if not keep.whole_frames:
            raise ValueError(
                f"{self.model} keeps whole frames, not a body part alone (upper-body editing is the model mmm-body)"
            )
        encoded = self.codec.encode(keep.features)
        if len(encoded) != tokens:
            raise ValueError(f"the kept motion holds {len(encoded)} tokens but the request asks for {tokens}")
        held = np.zeros(tokens, dtype=bool)
        units = np.flatnonzero(keep.frames) // self.frame_step
        held[units[units < tokens]] = True
        return torch.where(torch.as_tensor(held), encoded, torch.full_like(encoded, FREE))

    def reconstruct(self, segments: Sequence[Sequence[np.ndarray]]) -> list[Motion]:
        """Each sequence's segments encoded, their tokens concatenated and decoded together: the
        ceiling of any sampler over these tokens (the M2D2M paper's Table 3 "VQ-VAE" row)."""
        settings = {"model": self.model, "method": "vq reconstruction", "checkpoint": str(self.source)}
        return [
            self.codec.motion(
                [self.codec.encode(clip) for clip in clips], [f"segment {i + 1}" for i in range(len(clips))], settings
            )
            for clips in segments
        ]
