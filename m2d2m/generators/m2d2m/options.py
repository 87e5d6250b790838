"""M2D2M's sampling knobs and presets (:mod:`m2d2m.generators.options`): the reverse process's
settings (the paper's §4.2–4.3, eq. 9) and how the actions of a sequence are joined."""

from __future__ import annotations

from dataclasses import dataclass

from m2d2m.generators.options import COMPILE, MULTI, SINGLE, Sampling, check_knobs, knob

METHODS = ("tps", "independent", "handshake", "slerp")


@dataclass(frozen=True)
class M2D2MOptions:
    """Knobs of the reverse process. The presets are the paper's settings (§5.1); the bare
    defaults sample with the η the model was trained with."""

    method: str = knob(
        "tps",
        "how the actions are joined: Two-Phase Sampling (tps), each alone (independent), "
        "shared tokens (handshake) or SLERP between them (slerp)",
        choices=METHODS,
    )
    ts: int | None = knob(
        None,
        "the step T_s at which sampling switches from the whole sequence at once to each action alone "
        "(default: 90 % of T)",
        label="Switch to each action alone at step",
        methods=("tps",),
        minimum=0,
    )
    eta: float | None = knob(
        None,
        "how much the noise favours codes far from a token's own in the codebook, the η of the dynamic "
        "transition, eq. 7 (0: any code alike; default: as trained)",
        label="Far-code noise weight",
        minimum=0,
        maximum=100,  # trained with 0.5; from tens on every replacement goes to the farthest code
    )
    guidance: float = knob(
        2.0,
        "how strongly the motion is pushed towards the text, the classifier-free guidance scale s of the "
        "paper's eq. 9 (0: the text-conditioned prediction alone)",
        label="Text guidance",
        minimum=0,
        maximum=20,  # the paper's 2 and 4; from tens on the guided logits pick one code each
    )
    truncation: float = knob(
        1.0,
        "draw only among the most probable codes holding this much of the probability (1: all codes)",
        label="Keep likeliest codes",
        above=0,
        maximum=1,
    )
    steps: int | None = knob(
        None,
        "reverse steps taken, skipping steps with exact posteriors: fewer is faster (default: all T)",
        label="Denoising steps",
        minimum=1,
    )
    handshake: int = knob(
        5,
        "tokens shared between neighbouring actions; 5 tokens = 20 frames",
        label="Shared tokens",
        methods=("handshake",),
        minimum=1,
    )
    slerp: int = knob(
        2,
        "tokens left out before each later action and filled by SLERP; 2 tokens = 8 frames",
        label="Blend length",
        methods=("slerp",),
        minimum=0,
    )
    compile: str = knob(
        "off",
        "run the denoiser through torch.compile at a few padded shapes (CUDA graphs on a GPU): on, off, "
        "or auto (on CUDA only); each shape compiles once per process, so it pays off over many steps",
        label="Compile the denoiser",
        choices=COMPILE,
    )

    def check(self, steps: int) -> None:
        """Raise ValueError naming the first setting a schedule of ``steps`` steps cannot run
        or its knobs refuse."""
        check_knobs(self)
        if self.method == "tps" and self.ts is not None and not 0 <= self.ts <= steps:
            raise ValueError(f"T_s must lie in 0..T = {steps}, got {self.ts}")
        if self.steps is not None and not 1 <= self.steps <= steps:
            raise ValueError(f"steps must lie in 1..T = {steps}, got {self.steps}")


MULTI_ACTION = M2D2MOptions(method="tps", ts=None, eta=0.25, guidance=2.0)
# one action has no joint phase: every method samples it alike, ``independent`` says so
SINGLE_ACTION = M2D2MOptions(method="independent", eta=0.5, guidance=4.0)
# the knobs a model file may set for every preset (its config's ``sampling`` section): how it samples,
# chosen for that model on a validation split, not what the paper's single- and multi-action settings are
MODEL_DEFAULTS = ("steps", "truncation", "guidance")

SAMPLING = Sampling(
    "m2d2m",
    M2D2MOptions,
    {MULTI: MULTI_ACTION, SINGLE: SINGLE_ACTION},
    {
        "tps": "Two-phase sampling (M2D2M)",
        "independent": "Each action alone",
        "handshake": "Shared tokens between actions",
        "slerp": "Blend between actions",
    },
)
