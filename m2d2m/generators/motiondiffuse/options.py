"""MotionDiffuse's sampling knobs and presets (:mod:`m2d2m.generators.options`): the reverse
process (Zhang et al. 2022, §3.3), respacing (Nichol & Dhariwal 2021, §4), DDIM (Song et al.
2021), and the corrections of time-varied and body-part control (§3.5, eqs. 10–11)."""

from __future__ import annotations

from dataclasses import dataclass

from m2d2m.generators.options import MULTI, SINGLE, Sampling, knob

METHODS = ("time-varied", "independent")
SAMPLERS = ("ddpm", "ddim")
# the ancestral variances of m2d2m.processes.gaussian_diffusion (tests/test_motiondiffuse.py keeps the two equal)
VARIANCES = ("beta", "posterior")


@dataclass(frozen=True)
class MotionDiffuseOptions:
    """Knobs of MotionDiffuse's sampling; the defaults are the paper's (all 1000 steps, ancestral,
    Σ = β_t; λ1 = λ2 = 0.01, §4.3). ``steps`` below the trained T respaces the process."""

    method: str = knob(
        "time-varied",
        "how the actions are joined: one interval each, overlapping and corrected "
        "(time-varied, eq. 11), or each alone (independent)",
        choices=METHODS,
    )
    steps: int | None = knob(
        None,
        "reverse steps, respaced: fewer is faster (default: every step of the trained T)",
        label="Denoising steps",
        minimum=1,
    )
    sampler: str = knob("ddpm", "ancestral steps (ddpm) or DDIM (ddim)", label="Sampler", choices=SAMPLERS)
    variance: str = knob(
        "beta",
        "the ancestral steps' Σ: β_t (the paper) or the posterior's β̃_t (the public code)",
        label="Ancestral noise",
        choices=VARIANCES,
    )
    ddim_eta: float = knob(
        0.0, "DDIM's η: 0 deterministic, 1 as noisy as ancestral", label="DDIM noise", minimum=0, maximum=1
    )
    overlap: int = knob(
        10,
        "frames each action's interval reaches into its neighbours (ours)",
        label="Overlap frames",
        methods=("time-varied",),
        minimum=0,
    )
    lambda_time: float = knob(
        0.01,
        "how strongly overlapping intervals are pulled together, λ2 of eq. 11",
        label="Overlap correction",
        methods=("time-varied",),
        minimum=0,
        maximum=10,  # λ of eq. 10–11, 0.01 in the paper: a pull a thousand times as strong is no motion's
    )
    # body-part control only (`m2d2m generate --part`): no multi-action method reads it
    lambda_part: float = knob(
        0.01,
        "how strongly the body parts' estimates are pulled together, λ1 of eq. 10",
        label="Body-part correction",
        methods=(),
        minimum=0,
        maximum=10,  # λ of eq. 10–11, 0.01 in the paper: a pull a thousand times as strong is no motion's
    )


SAMPLING = Sampling(
    "motiondiffuse",
    MotionDiffuseOptions,
    {MULTI: MotionDiffuseOptions(), SINGLE: MotionDiffuseOptions(method="independent")},
    {"time-varied": "Overlapping actions (time-varied)", "independent": "Each action alone"},
)
