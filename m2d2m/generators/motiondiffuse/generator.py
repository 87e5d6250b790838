"""MotionDiffuse's generator (Zhang et al. 2022): action sentences and lengths in frames → motion
features by the Gaussian reverse process (:mod:`m2d2m.processes.gaussian_diffusion`) and the
controlled sampler (:mod:`m2d2m.generators.motiondiffuse.sampling`), from one model file
(:mod:`m2d2m.generators.motiondiffuse.checkpoint`). It works on the features directly: no codec,
so no reconstruction row in the evaluation tables.

Multi-action methods:

- ``time-varied`` (§3.5, eq. 11; MotionDiffuse's own): one interval per action, reaching
  ``overlap`` frames into each neighbour (ours: the paper allows overlapping intervals but gives no
  width), every interval's noise estimated under its own sentence and combined at every step, with
  the correction λ2 pulling the overlapping estimates together.
- ``independent``: the same with no overlap and so no correction: every action denoised alone.

Body-part control (§3.5, eq. 10) is :meth:`MotionDiffuseGenerator.generate_parts`: one sentence
per body part, the parts' estimates combined with their feature masks and the correction λ1.
Editing (``keep``) replaces the kept frames and dimensions at every step, so in-betweening and
upper-body editing both work.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from m2d2m.generators.motiondiffuse.checkpoint import MotionDiffuseCheckpoint, load_motiondiffuse
from m2d2m.generators.motiondiffuse.options import SAMPLING, MotionDiffuseOptions
from m2d2m.generators.motiondiffuse.sampling import FeatureRequest, Step, Term, sample
from m2d2m.generators.protocol import Keep, MotionGenerator
from m2d2m.motion.clip import Motion
from m2d2m.motion.representation.body_parts import PARTS, part_mask
from m2d2m.motion.representation.features import features_to_joints
from m2d2m.motion.representation.skeleton import Skeleton
from m2d2m.processes.gaussian_diffusion import GaussianDiffusion, prediction_of
from m2d2m.text import TextEncoder


class MotionDiffuseGenerator(MotionGenerator):
    """A loaded MotionDiffuse model file behind the generator protocol."""

    model = "motiondiffuse"
    sampling = SAMPLING
    edits = ("inbetween", "upper")  # any frames and dimensions can be kept (replacement inpainting)
    part_control = True

    def __init__(self, checkpoint: MotionDiffuseCheckpoint, source: Path) -> None:
        self.checkpoint = checkpoint
        self.source = source
        self.process = checkpoint.process

    @classmethod
    def load(cls, path: str | Path, device: str | torch.device = "cpu") -> MotionDiffuseGenerator:
        return cls(load_motiondiffuse(path, device), Path(path))

    # -------------------------------------------------------------------------- what it is
    @property
    def skeleton(self) -> Skeleton:
        return self.checkpoint.skeleton

    @property
    def feature_dim(self) -> int:
        return self.checkpoint.network.config.feature_dim

    @property
    def device(self) -> torch.device:
        return self.checkpoint.network.positions.device

    @property
    def data_dir(self) -> Path | None:
        data_dir = self.checkpoint.extra.get("data_dir")
        return Path(data_dir) if data_dir else None

    def typical_frames(self, verb: str | None) -> int:
        return min(self.checkpoint.lengths.typical(verb), self.longest_frames)

    @property
    def longest_frames(self) -> int:
        return min(self.checkpoint.lengths.longest, self.checkpoint.network.config.max_frames)

    @property
    def known_verbs(self) -> tuple[str, ...]:
        return tuple(self.checkpoint.lengths.per_verb)

    @property
    def text_encoder(self) -> TextEncoder:
        return self.checkpoint.text_encoder

    # --------------------------------------------------------------------------- its options
    def check_options(self, options: MotionDiffuseOptions) -> None:
        if options.steps is not None and not 1 <= options.steps <= self.process.num_steps:
            raise ValueError(f"steps must lie in 1..{self.process.num_steps} (the trained T), got {options.steps}")

    def describe(self, options: MotionDiffuseOptions) -> str:
        if options.sampler == "ddim":
            sampler = f"DDIM, η = {options.ddim_eta:g}"
        else:
            sampler = f"ancestral, Σ = {'β_t' if options.variance == 'beta' else 'β̃_t'}"
        joined = (
            f", intervals overlapping by {options.overlap} frames, λ2 = {options.lambda_time:g}"
            if options.method == "time-varied"
            else ""
        )
        return f"{self._steps(options)} of T = {self.process.num_steps} steps ({sampler}){joined}"

    def _steps(self, options: MotionDiffuseOptions) -> int:
        return self.process.num_steps if options.steps is None else options.steps

    def _sampling(self, options: MotionDiffuseOptions) -> tuple[GaussianDiffusion, Step]:
        steps = self._steps(options)
        process = self.process if steps == self.process.num_steps else self.process.respaced(steps)
        if options.sampler == "ddim":
            return process, lambda x, t, eps, noise: process.ddim_sample(x, t, eps, noise, options.ddim_eta)
        return process, lambda x, t, eps, noise: process.p_sample(x, t, eps, noise, options.variance)

    # ----------------------------------------------------------------------------- the calls
    def generate(
        self,
        actions: Sequence[Sequence[str]],
        frames: Sequence[Sequence[int]],
        options: MotionDiffuseOptions,
        seeds: Sequence[int],
        keep: Sequence[Keep | None] | None = None,
        progress: Callable[[float], None] | None = None,
    ) -> list[Motion]:
        """Every sequence's intervals denoised together, one noise estimate per interval and step."""
        keep = [None] * len(actions) if keep is None else keep
        overlap = options.overlap if options.method == "time-varied" else 0
        requests, ranges = [], []
        for sequence, lengths, seed, kept in zip(actions, frames, seeds, keep):
            bounds = np.cumsum([0, *(self.round_frames(n) for n in lengths)]).tolist()
            total = bounds[-1]
            spans = list(zip(bounds[:-1], bounds[1:]))
            terms = tuple(
                Term(sentence, *self._interval(start, end, total, overlap))
                for sentence, (start, end) in zip(sequence, spans)
            )
            requests.append(FeatureRequest(total, terms, int(seed), *self._kept(kept, total)))
            ranges.append(spans)
        normalized = self._sample(requests, options, options.lambda_time, progress)
        settings = {**asdict(options), "model": self.model, "checkpoint": str(self.source)}
        return [
            self._motion(x, list(sequence), spans, {**settings, "seed": int(seed)})
            for x, sequence, spans, seed in zip(normalized, actions, ranges, seeds)
        ]

    def generate_parts(
        self,
        parts: Sequence[Mapping[str, str]],
        frames: Sequence[int],
        options: MotionDiffuseOptions,
        seeds: Sequence[int],
        progress: Callable[[float], None] | None = None,
    ) -> list[Motion]:
        """Body-part control (eq. 10): each request names a sentence for every body part, all over
        its ``frames``; the parts' estimates are combined with their feature masks."""
        requests = []
        for texts, length, seed in zip(parts, frames, seeds):
            missing = [part for part in PARTS if part not in texts]
            unknown = sorted(set(texts) - set(PARTS))
            if unknown or missing:
                raise ValueError(
                    f"give one sentence for each body part ({', '.join(PARTS)}): "
                    + (f"unknown {', '.join(unknown)}" if unknown else f"missing {', '.join(missing)}")
                )
            total = self.round_frames(length)
            terms = tuple(Term(texts[part], 0, total, part_mask(self.skeleton, part)) for part in PARTS)
            requests.append(FeatureRequest(total, terms, int(seed)))
        normalized = self._sample(requests, options, options.lambda_part, progress)
        settings = {**asdict(options), "model": self.model, "checkpoint": str(self.source), "method": "body parts"}
        return [
            self._motion(
                x,
                [" | ".join(f"{part}: {texts[part]}" for part in PARTS)],
                [(0, len(x))],
                {**settings, "parts": dict(texts), "seed": int(seed)},
            )
            for x, texts, seed in zip(normalized, parts, seeds)
        ]

    def _interval(self, start: int, end: int, total: int, overlap: int) -> tuple[int, int]:
        """An action's frames [start, end) reaching ``overlap`` frames into each neighbour, as far
        as the sequence and the network's longest pass allow."""
        spare = max(0, self.checkpoint.network.config.max_frames - (end - start))
        before = min(overlap, start, spare // 2)
        after = min(overlap, total - end, spare - before)
        return start - before, end + after

    def _kept(self, keep: Keep | None, frames: int) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """A Keep as normalised features and a (frames, D) mask of the entries to keep."""
        if keep is None:
            return None, None
        if len(keep.features) != frames:
            raise ValueError(f"the kept motion holds {len(keep.features)} frames but the request asks for {frames}")
        features = self.checkpoint.normalizer.normalize(np.asarray(keep.features, dtype=np.float32))
        return torch.as_tensor(features), torch.as_tensor(keep.entries)

    def _sample(
        self,
        requests: list[FeatureRequest],
        options: MotionDiffuseOptions,
        correction: float,
        progress: Callable[[float], None] | None,
    ) -> list[torch.Tensor]:
        network, text_encoder = self.checkpoint.network, self.checkpoint.text_encoder
        with torch.no_grad():
            words, mask = text_encoder.encode([term.sentence for request in requests for term in request.terms])
            text = network.encode_text(words.to(self.device), mask.to(self.device))
        process, step = self._sampling(options)
        return sample(
            network, text, requests, process, step, correction, progress, prediction_of(self.checkpoint.diffusion)
        )

    def _motion(
        self, normalized: torch.Tensor, actions: list[str], ranges: list[tuple[int, int]], settings: dict
    ) -> Motion:
        features = self.checkpoint.normalizer.denormalize(normalized.cpu().numpy())
        joints = features_to_joints(features, self.skeleton)
        return Motion(
            features,
            np.asarray(joints, dtype=np.float32),
            self.fps,
            self.skeleton.name,
            actions,
            [(int(a), int(b)) for a, b in ranges],
            settings,
        )
