"""MMM's upper-body editing (Pinyoanuntapong et al., CVPR 2024, §3.3 and supplement §I.2): keep a
motion's lower body, generate its upper body from new text.

The kept motion is encoded by both part tokenizers (:class:`~m2d2m.generators.token_model.BodyCodec`).
Its lower-body tokens condition the body transformer (:mod:`m2d2m.networks.mmm_body_transformer`),
except a fraction ``lower_mask`` of them, chosen at random with the sequence's seed and replaced by
[MASK] — the user's knob of supplement §I.2: with none masked the upper body follows the lower
body's original motion closely and the new text weakly; with all masked the two halves are
unrelated; in between they agree and both show. The [MASK] tokens of the lower body stay as they
are through every iteration (§3.3); the upper-body tokens are decoded by MMM's confidence-based
parallel decoding (:mod:`m2d2m.generators.mmm.decoding`). The motion returned has every lower-body
token of the kept motion, masked or not, unchanged; only the upper body is new.

Each action of a sequence is one decoding row with its own sentence and its stretch of the lower
body (method ``independent``); every frame's lower body must be kept.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from m2d2m.generators.mmm.checkpoint import load_body_mmm
from m2d2m.generators.mmm.generator import MMMGenerator, Row, seed_of
from m2d2m.generators.mmm.options import BODY_SAMPLING, BodyOptions
from m2d2m.generators.protocol import Keep
from m2d2m.generators.token_model import FREE
from m2d2m.motion.clip import Motion
from m2d2m.motion.representation.body_parts import LOWER, part_mask
from m2d2m.networks.mmm_body_transformer import body_canvas
from m2d2m.processes.masking import random_positions


def masked_lower(lower: torch.Tensor, fraction: float, mask_id: int, seed: int) -> torch.Tensor:
    """``lower`` (L,) with round(``fraction``·L) positions, drawn with ``seed``, set to ``mask_id``."""
    generator = torch.Generator().manual_seed(int(seed))
    length = torch.tensor([len(lower)])
    count = torch.round(torch.tensor([fraction * len(lower)])).long()
    hidden = random_positions(length, len(lower), count, generator)[0]
    return torch.where(hidden, torch.full_like(lower, mask_id), lower)


class BodyMMMGenerator(MMMGenerator):
    """A loaded upper-body editor behind the generator protocol: every sequence comes with a
    :class:`Keep` of its lower body (:func:`~m2d2m.generators.protocol.keep_part`)."""

    model = "mmm-body"
    sampling = BODY_SAMPLING
    needs_keep = (
        "give the motion whose lower body to keep on every frame "
        "(m2d2m generate --model mmm-body --edit SOURCE --keep-body lower)"
    )
    edits = ("upper",)
    edit_method = None  # independent is its one method, its default

    @classmethod
    def load(cls, path: str | Path, device: str | torch.device = "cpu") -> BodyMMMGenerator:
        return cls(load_body_mmm(path, device), Path(path))

    def describe(self, options: BodyOptions) -> str:
        return (
            f"upper body by {options.iterations} iterations ({options.schedule}), temperature "
            f"{options.temperature:g}, {options.lower_mask:.0%} of the lower-body tokens masked"
        )

    def _kept_pairs(self, keep: Keep | None, tokens: int) -> torch.Tensor:
        """The kept motion's token pairs (L, 2), or ValueError when ``keep`` is not its whole lower body."""
        if (
            keep is None
            or keep.dims is None
            or not np.array_equal(keep.dims, part_mask(self.skeleton, LOWER))
            or not keep.frames.all()
        ):
            raise ValueError(
                f"mmm-body generates the upper body of a motion whose lower body it keeps: {self.needs_keep}"
            )
        encoded = self.codec.encode(keep.features)
        if len(encoded) != tokens:
            raise ValueError(f"the kept motion holds {len(encoded)} tokens but the request asks for {tokens}")
        return encoded

    def generate(
        self,
        actions: Sequence[Sequence[str]],
        frames: Sequence[Sequence[int]],
        options: BodyOptions,
        seeds: Sequence[int],
        keep: Sequence[Keep | None] | None = None,
        progress: Callable[[float], None] | None = None,
    ) -> list[Motion]:
        """Every action's upper body decoded in one batch, given its stretch of the kept lower body."""
        keep = [None] * len(actions) if keep is None else keep
        config = self.checkpoint.transformer.config
        rows, kept, lowers = [], [], []
        for sequence, tokens, seed, held in zip(actions, self.tokens_of(frames), seeds, keep):
            pairs = self._kept_pairs(held, sum(tokens))
            kept.append(pairs[:, 1].split(tokens))
            for j, (sentence, lower) in enumerate(zip(sequence, kept[-1])):
                rows.append(Row(sentence, torch.full((len(lower),), FREE), seed_of(seed, 0, j)))
                lowers.append(masked_lower(lower, options.lower_mask, config.lower_mask_id, seed_of(seed, 2, j)))
        width = max(len(lower) for lower in lowers)
        condition = torch.full((len(lowers), width), config.lower_pad_id, dtype=torch.long)
        for index, lower in enumerate(lowers):
            condition[index, : len(lower)] = lower
        condition = condition.to(self.device, non_blocking=True)  # laid out on the host, copied once

        def frame(upper: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
            return body_canvas(upper, condition, lengths, config)

        decoded = iter(self._decode(rows, options, frame))
        if progress is not None:
            progress(1.0)
        settings = {**asdict(options), "model": self.model, "checkpoint": str(self.source)}
        return [
            self.codec.motion(
                [torch.stack([next(decoded), lower], dim=-1) for lower in lower_pieces],
                list(sequence),
                {**settings, "seed": int(seed)},
            )
            for sequence, lower_pieces, seed in zip(actions, kept, seeds)
        ]
