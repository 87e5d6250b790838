"""MMM's generator (Pinyoanuntapong et al., CVPR 2024): action sentences and lengths in frames →
tokens by confidence-based parallel decoding (:mod:`m2d2m.generators.mmm.decoding`) → motion by
the VQ-VAE, from one model file (:mod:`m2d2m.generators.mmm.checkpoint`).

Multi-action methods:

- ``transition`` (MMM's long-sequence generation, §4 and supplement §I.3): every action's tokens
  are generated alone; then, between neighbours, ``transition`` [MASK] tokens (2 = 8 frames) with
  the end of the earlier action before them and the start of the later one after them — half of
  each, as much as fits the transformer — are filled in a single decoding step, conditioned on the
  earlier action's sentence. As with the SLERP baseline, every later action is ``transition``
  tokens shorter, so a sequence is as long as asked and the transition frames belong to no action.
- ``independent``: every action alone, tokens concatenated before decoding.

Editing (``keep``) fixes the kept tokens while the rest is decoded, bit-exact, for one action or
under ``independent``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from m2d2m.generators.mmm.checkpoint import MMMCheckpoint, load_mmm
from m2d2m.generators.mmm.decoding import decode
from m2d2m.generators.mmm.options import SAMPLING, DecodingOptions, MMMOptions
from m2d2m.generators.protocol import Keep
from m2d2m.generators.token_model import FREE, TokenModelGenerator
from m2d2m.motion.clip import Motion
from m2d2m.networks.mmm_transformer import MaskedMotionTransformer, canvas
from m2d2m.text import TextEncoder


@dataclass
class Row:
    """One decoding row: its condition, its tokens (``given``: codes to keep, FREE to fill), a seed."""

    sentence: str
    given: torch.Tensor
    seed: int


def seed_of(seed: int, *role: int) -> int:
    """A row's seed from its sequence's and its role in it, so that no row depends on the batch."""
    return int(np.random.SeedSequence([int(seed), *role]).generate_state(1)[0])


class MMMGenerator(TokenModelGenerator):
    """A loaded MMM model file behind the generator protocol."""

    model = "mmm"
    sampling = SAMPLING
    edit_method = "independent"  # its transition tokens are decoded across actions, which kept tokens cannot be

    def __init__(self, checkpoint: MMMCheckpoint, source: Path) -> None:
        self.checkpoint = checkpoint
        self.source = source
        self.codec, self.lengths, self.extra = checkpoint.codec, checkpoint.lengths, checkpoint.extra

    @classmethod
    def load(cls, path: str | Path, device: str | torch.device = "cpu") -> MMMGenerator:
        return cls(load_mmm(path, device), Path(path))

    @property
    def device(self) -> torch.device:
        return self.checkpoint.transformer.codebook.device

    @property
    def max_tokens(self) -> int:
        return self.checkpoint.transformer.config.max_tokens

    def describe(self, options: MMMOptions) -> str:
        sampling = ", ".join(
            f"{name} {value}"
            for name, value in (("top-k", options.top_k), ("top-p", options.top_p))
            if value is not None
        )
        joined = f", {options.transition} transition tokens" if options.method == "transition" else ""
        return (
            f"{options.iterations} iterations ({options.schedule}), temperature {options.temperature:g}"
            + (f", {sampling}" if sampling else "")
            + joined
        )

    # ----------------------------------------------------------------------------- the call
    def generate(
        self,
        actions: Sequence[Sequence[str]],
        frames: Sequence[Sequence[int]],
        options: MMMOptions,
        seeds: Sequence[int],
        keep: Sequence[Keep | None] | None = None,
        progress: Callable[[float], None] | None = None,
    ) -> list[Motion]:
        """Every action of every sequence decoded in one batch, then (``transition``) every
        transition in a second, one decoding step; each sequence decoded by the VQ-VAE."""
        keep = [None] * len(actions) if keep is None else keep
        joined = options.method == "transition"
        lengths = [
            [n if j == 0 or not joined else max(1, n - options.transition) for j, n in enumerate(tokens)]
            for tokens in self.tokens_of(frames)
        ]
        rows = []
        for sequence, tokens, seed, kept in zip(actions, lengths, seeds, keep):
            if kept is not None and joined and len(sequence) > 1:
                raise ValueError("MMM keeps frames for one action at a time, or with --method independent")
            given = self.given_tokens(kept, sum(tokens))
            pieces = torch.full((sum(tokens),), FREE) if given is None else given
            rows += [
                Row(sentence, piece, seed_of(seed, 0, j))
                for j, (sentence, piece) in enumerate(zip(sequence, pieces.split(tokens)))
            ]
        decoded = iter(self._decode(rows, options))
        pieces = [[next(decoded) for _ in sequence] for sequence in actions]
        if progress is not None:
            progress(0.5 if joined else 1.0)
        gaps: list[list[torch.Tensor]] = [[] for _ in actions]
        if joined:
            gaps = self._transitions(actions, pieces, seeds, options)
            if progress is not None:
                progress(1.0)
        settings = {**asdict(options), "model": self.model, "checkpoint": str(self.source)}
        return [
            self.codec.motion(p, list(sequence), {**settings, "seed": int(seed)}, g)
            for p, g, sequence, seed in zip(pieces, gaps, actions, seeds)
        ]

    def _transitions(
        self,
        actions: Sequence[Sequence[str]],
        pieces: list[list[torch.Tensor]],
        seeds: Sequence[int],
        options: MMMOptions,
    ) -> list[list[torch.Tensor]]:
        """The transition tokens between each pair of neighbours, all in one decoding step."""
        side = (self.max_tokens - options.transition) // 2
        rows, shapes = [], []
        for sequence, tokens, seed in zip(actions, pieces, seeds):
            for j in range(len(sequence) - 1):
                before = tokens[j][-min(side, max(1, len(tokens[j]) // 2)) :]
                after = tokens[j + 1][: min(side, max(1, len(tokens[j + 1]) // 2))]
                given = torch.cat([before, torch.full((options.transition,), FREE), after])
                rows.append(Row(sequence[j], given, seed_of(seed, 1, j)))
                shapes.append(len(before))
        filled = iter(zip(self._decode(rows, replace(options, iterations=1)) if rows else [], shapes))
        return [
            [
                tokens[start : start + options.transition]
                for tokens, start in (next(filled) for _ in range(len(sequence) - 1))
            ]
            for sequence in actions
        ]

    def _decode(self, rows: list[Row], options: DecodingOptions, frame: Frame | None = None) -> list[torch.Tensor]:
        longest = max(len(row.given) for row in rows)
        if longest > self.max_tokens:
            raise ValueError(
                f"MMM generates at most {self.max_tokens} tokens "
                f"({self.max_tokens * self.frame_step} frames) per action; {longest} were asked for"
            )
        return decode_sentences(
            self.checkpoint.transformer, self.checkpoint.text_encoder, rows, self.lengths.longest, options, frame
        )


Frame = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]  # (B, W) tokens, (B,) lengths → network input


def decode_sentences(
    transformer: MaskedMotionTransformer,
    text_encoder: TextEncoder,
    rows: list[Row],
    longest: int,
    options: DecodingOptions,
    frame: Frame | None = None,
) -> list[torch.Tensor]:
    """Each row's tokens, its FREE positions decoded under its sentence in one batch (``longest``
    is the M of T_dyn: the corpus's longest motion in tokens). ``frame`` makes the network's input
    from the tokens being decoded, padded to the longest row, and the rows' lengths; by default
    :func:`~m2d2m.networks.mmm_transformer.canvas` (upper-body editing adds the fixed lower body)."""
    device = transformer.codebook.device
    width = max(len(row.given) for row in rows)
    given = torch.full((len(rows), width), FREE, dtype=torch.long)
    for index, row in enumerate(rows):
        given[index, : len(row.given)] = row.given
    # laid out on the host and copied once, without waiting for the device
    given = given.to(device, non_blocking=True)
    lengths = torch.tensor([len(row.given) for row in rows]).to(device, non_blocking=True)
    valid = torch.arange(width, device=device)[None, :] < lengths[:, None]
    config = transformer.config
    with torch.no_grad():
        words, word_mask, sentence = text_encoder.encode_pooled([row.sentence for row in rows])

        def predict(tokens: torch.Tensor) -> torch.Tensor:
            # [END], then [PAD] past each row
            inputs = canvas(tokens, lengths, config) if frame is None else frame(tokens, lengths)
            return transformer(inputs, sentence, words, word_mask)[:, :-1]

        tokens = decode(predict, given, valid, config.mask_id, longest, options, [row.seed for row in rows]).cpu()
    return [tokens[index, : len(row.given)] for index, row in enumerate(rows)]
