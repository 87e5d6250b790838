"""MMM's sampling knobs and presets (:mod:`m2d2m.generators.options`): confidence-based parallel
decoding (Pinyoanuntapong et al., CVPR 2024, §3.2, supplement §H) for the text-to-motion model,
and the upper-body editor's ``lower_mask`` (supplement §I.2)."""

from __future__ import annotations

from dataclasses import dataclass

from m2d2m.generators.options import MULTI, SINGLE, Sampling, check_knobs, knob

# the decoding schedules of m2d2m.processes.masking (tests/test_mmm_decoding.py keeps the two equal)
SCHEDULES = ("cosine", "linear", "square")
METHODS = ("transition", "independent")
# Our default, inside the training corruption (configs/mmm-body: masking.lower_most = 0.3): some
# lower tokens masked, as the supplement's Fig. 14 (bottom) recommends without giving a number.
DEFAULT_LOWER_MASK = 0.25


@dataclass(frozen=True)
class DecodingOptions:
    """Knobs of parallel decoding; the defaults are the paper's (10 iterations for the longest
    motion, cosine schedule, temperature 1, no filtering)."""

    iterations: int = knob(
        10,
        "decoding iterations for the longest motion, fewer for shorter ones (T of T_dyn)",
        label="Decoding iterations",
        minimum=1,
        maximum=1000,  # the paper's 10; one a token at most decides anything, and a billion would never end
    )
    schedule: str = knob(
        "cosine",
        "how many tokens stay masked after each iteration",
        label="Unmasking schedule",
        choices=SCHEDULES,
    )
    temperature: float = knob(
        1.0,
        "softmax temperature of each draw: higher is more varied",
        label="Temperature",
        above=0,
        maximum=100,  # the logits divided by it: far above 1, every code alike
    )
    top_k: int | None = knob(
        None, "draw among the k most probable codes (default: all)", label="Keep the k likeliest codes", minimum=1
    )
    top_p: float | None = knob(
        None,
        "draw among the fewest codes holding this much of the probability (default: all)",
        label="Keep likeliest codes",
        above=0,
        maximum=1,
    )

    def check(self) -> None:
        """Raise ValueError naming the first setting its knobs refuse."""
        check_knobs(self)


@dataclass(frozen=True)
class MMMOptions(DecodingOptions):
    """MMM's decoding knobs and how the actions of a sequence are joined."""

    method: str = knob(
        "transition",
        "how the actions are joined: transition tokens decoded between neighbours "
        "(transition) or each alone (independent)",
        choices=METHODS,
    )
    transition: int = knob(
        2,
        "[MASK] tokens decoded between neighbouring actions; 2 tokens = 8 frames",
        label="Transition tokens",
        methods=("transition",),
        minimum=1,
    )


@dataclass(frozen=True)
class BodyOptions(DecodingOptions):
    """MMM's decoding knobs and ``lower_mask``, the fraction of the kept lower-body tokens hidden
    from the transformer (supplement §I.2)."""

    method: str = knob("independent", "each action's upper body decoded alone", choices=("independent",))
    lower_mask: float = knob(
        DEFAULT_LOWER_MASK,
        "fraction of the kept lower-body tokens hidden from the transformer: 0 follows the kept motion, 1 ignores it",
        label="Hidden lower body",
        minimum=0,
        maximum=1,
    )


SAMPLING = Sampling(
    "mmm",
    MMMOptions,
    {MULTI: MMMOptions(), SINGLE: MMMOptions(method="independent")},
    {"transition": "Transition tokens between actions (MMM)", "independent": "Each action alone"},
)
BODY_SAMPLING = Sampling(
    "mmm-body",
    BodyOptions,
    {MULTI: BodyOptions(), SINGLE: BodyOptions()},
    {"independent": "Each action's upper body alone"},
)
