"""The condition a training step sees: a fraction ``text_drop`` of its captions replaced by the
empty sentence, the null condition that editing without text and classifier-free guidance ask
for (docs/training.md, "text_drop")."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def drop_captions(captions: Sequence[str], fraction: float, rng: np.random.Generator | None = None) -> list[str]:
    """``captions`` with each replaced by "" with probability ``fraction``, drawn from ``rng``, or
    from NumPy's global generator (which Lightning's ``seed_everything`` seeds) when None.

    Drawn on the host, with no tensor: the captions are host strings, so which ones to drop is a
    host decision, and a tensor drawn for it would have to be read back (on a GPU, a generator on
    the device makes the host wait for every queued kernel)."""
    draws = (np.random if rng is None else rng).random(len(captions))
    return ["" if draw < fraction else caption for caption, draw in zip(captions, draws)]
