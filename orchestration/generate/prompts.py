"""What a person asks for, checked and planned before sampling: free-text prompts split into
action sentences with the dataset's tagger (as the corpus's captions were split), each action
given a length (the seconds asked for, or the corpus's typical length for its verb) under a cap
on the whole, and the requests of ``--keep-body`` and ``--part`` checked before a model loads.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence

import numpy as np

from m2d2m.generators.protocol import MotionGenerator
from m2d2m.layout import NLP, recorded_path
from m2d2m.motion.representation.body_parts import PARTS
from orchestration.errors import UserError

# A 590-s clip took 293 s and a 182-MB GIF: a minute is several actions, and seconds to make.
DEFAULT_MAX_SECONDS = 60.0


def require_words(prompt: str) -> None:
    """Refuse, in one line, a prompt of punctuation or emoji alone: the model would sample from no words."""
    if not re.search(r"[^\W_]", prompt):
        raise UserError(f"the prompt {prompt!r} has no words; describe an action, e.g. 'a person walks forward'")


class PromptPlanner:
    """Free-text prompts → action sentences and lengths in frames for one generator."""

    def __init__(self, generator: MotionGenerator) -> None:
        self.generator = generator
        self._tagger = None
        self._verbs: dict[str, str | None] = {}  # each action sentence split out so far → its verb

    def split(self, prompt: str) -> tuple[list[str], list[str | None]]:
        """Action sentences and their verbs, split as the corpus's captions were."""
        from pipelines.language import decompose, load_tagger

        require_words(prompt)
        if self._tagger is None:
            data_dir = self.generator.data_dir
            try:
                self._tagger = load_tagger(recorded_path(data_dir, self.generator.source) / NLP if data_dir else None)
            except FileNotFoundError as error:
                raise UserError(f"{error} (or pass --no-split)") from error
        parts = decompose(prompt, tagger=self._tagger)
        verbs: list[str | None] = (
            list(parts.verbs) if len(parts.verbs) == len(parts.actions) else [None] * len(parts.actions)
        )
        self._verbs.update(zip(parts.actions, verbs))
        return list(parts.actions), verbs

    def notices(self, actions: Sequence[str]) -> list[str]:
        """What the model does not know of ``actions``, one sentence each, to say before sampling:
        words its text encoder never read in training (it reads them as unknown), and the verb of
        a split action that it was never shown alone (not a light verb's, "does a cartwheel": its
        action is its object's). Nothing stops: it samples from the rest."""
        from pipelines.language import LIGHT_VERBS, action_verbs

        known = self.generator.known_verbs
        nameable = action_verbs(known)
        listed = ", ".join(nameable[:12]) + (", …" if len(nameable) > 12 else "")
        said = []
        for action in dict.fromkeys(actions):
            unknown = self.generator.unknown_words(action)
            if unknown:
                words = ", ".join(f"'{word}'" for word in unknown)
                were = "it were" if len(unknown) == 1 else "they were"
                said.append(f"{action!r}: the model never read {words} in training; it samples as if {were} not there")
            verb = self._verbs.get(action)
            if known and verb and verb not in known and verb not in LIGHT_VERBS:
                said.append(
                    f"{action!r}: the model was never shown '{verb}' alone; it knows {len(nameable)} actions "
                    f"({listed}; `m2d2m models` lists them)"
                )
        return said

    def plan(
        self, prompts: Sequence[str], seconds: Sequence[float] | None = None, split: bool = True
    ) -> tuple[list[str], list[int]]:
        """The action sentences and their lengths in frames for ``prompts``.

        With ``split`` a prompt with several verbs becomes several actions; a prompt's ``seconds``
        are then shared among its actions in proportion to their typical lengths. Without
        ``seconds`` every action gets the corpus's typical length for its verb.
        """
        prompts = list(prompts)
        if not prompts or any(not p.strip() for p in prompts):
            raise UserError("give at least one non-empty prompt")
        for prompt in prompts:
            require_words(prompt)
        if seconds is not None and len(seconds) not in (1, len(prompts)):
            raise UserError(f"give one duration per prompt ({len(prompts)}) or one for all, not {len(seconds)}")
        step = self.generator.frame_step
        actions: list[str] = []
        frames: list[int] = []
        for index, prompt in enumerate(prompts):
            parts, verbs = self.split(prompt) if split else ([" ".join(prompt.lower().split())], [None])
            typical = [self.generator.typical_frames(verb) // step for verb in verbs]
            if seconds is not None:
                wanted = float(seconds[0] if len(seconds) == 1 else seconds[index])
                check_seconds(self.generator, wanted, repr(prompt), actions=len(parts))
                typical = share(max(len(parts), round(wanted * self.generator.fps / step)), typical)
            actions.extend(parts)
            frames.extend(n * step for n in typical)
        return actions, frames


def seconds_range(generator: MotionGenerator) -> tuple[float, float]:
    """The shortest and longest action the model supports: one step of its granularity, and
    the longest clip it was trained on."""
    return generator.frame_step / generator.fps, generator.longest_frames / generator.fps


def check_seconds(generator: MotionGenerator, seconds: float, what: str, actions: int = 1) -> None:
    """The one refusal of a length no action of this model can have, for every way of asking
    (a prompt's ``--seconds``, an action of the API, an edit's new or re-timed action, a gap, an
    uploaded motion's action): ``what`` names it; a prompt split into ``actions`` may last as
    long as that many. Checked before the seconds become frames, so no length reaches arithmetic
    (a NaN, or 1e308 s, which is no number of frames)."""
    lo, hi = seconds_range(generator)
    if not lo <= seconds <= hi * actions:  # NaN fails too
        raise UserError(f"{seconds:g} s for {what} is outside what this model supports ({lo:g}–{hi:g} s per action)")


def action_frames(generator: MotionGenerator, seconds: float, what: str) -> int:
    """An action of ``seconds`` (:func:`check_seconds`) in the model's frames, whole steps."""
    check_seconds(generator, seconds, what)
    return generator.round_frames(round(seconds * generator.fps))


def share(total: int, typical: list[int]) -> list[int]:
    """Split ``total`` steps among actions in proportion to their typical lengths, at least one each."""
    weights = np.asarray(typical, dtype=np.float64)
    raw = np.maximum(1, np.floor(total * weights / weights.sum())).astype(int)
    raw[np.argmax(weights)] += total - int(raw.sum())
    return [int(n) for n in raw]


def length_cap(max_seconds: float | None) -> float | None:
    """The cap ``--max-seconds`` asks for: :data:`DEFAULT_MAX_SECONDS` when not given, none for 0."""
    if max_seconds is not None and not 0 <= max_seconds < math.inf:
        raise UserError(f"--max-seconds must be a positive number (0 for no cap), got {max_seconds:g}")
    return DEFAULT_MAX_SECONDS if max_seconds is None else max_seconds or None


def check_length(frames: Sequence[int], fps: float, max_seconds: float | None, remedy: str | None = None) -> None:
    """A one-line refusal, before sampling, of a generation longer than ``max_seconds`` (None: no
    cap): its time and its GIF grow with its length. ``remedy`` ends the line (default: the
    command line's flags; the API names its own fields)."""
    if max_seconds is not None and not 0 < max_seconds < math.inf:
        raise UserError(f"--max-seconds must be a positive number (0 for no cap), got {max_seconds:g}")
    total = sum(frames) / fps
    if max_seconds is not None and total > max_seconds:
        remedy = remedy or (
            f"give fewer or shorter prompts (--seconds), or --max-seconds {math.ceil(total)} to make it anyway"
        )
        raise UserError(
            f"the prompts make {total:.1f} s of motion in {len(frames)} action(s), over the "
            f"{max_seconds:g}-s cap; {remedy}"
        )


def check_prompted(
    prompts: Sequence[str], seconds: Sequence[float] | None, source: str | None, keep_body: str | None
) -> None:
    """`generate`'s request from prompts, checked before a model loads: a new motion, or the
    ``source`` motion with its ``keep_body`` part kept, which is as long as the source."""
    if not prompts:
        raise UserError('give at least one prompt, e.g. m2d2m generate "a person walks forward" "a person jumps"')
    if keep_body is not None and source is None:
        raise UserError(
            "--keep-body PART goes with --edit SOURCE: the motion to edit and the body part of it "
            "to keep, e.g. --model mmm-body --edit motion.features.npy --keep-body lower"
        )
    if source is not None and seconds is not None:
        raise UserError("--seconds does not go with --keep-body: the edited motion is as long as the source")


def plan_parts(
    named: Sequence[tuple[str, str]], prompts: Sequence[str], seconds: Sequence[float] | None, editing: bool
) -> tuple[dict[str, str], float | None]:
    """`generate --part PART=TEXT`'s request, checked before a model loads: each body part's
    sentence (a part not ``named`` does the one prompt) and the one length in seconds (None: the
    corpus's typical). Body-part control generates the whole motion, so it edits none."""
    if editing:
        raise UserError("--part does not go with --edit: body-part control generates the whole motion")
    if len(prompts) > 1 or (seconds is not None and len(seconds) > 1):
        raise UserError("with --part give at most one prompt (for the parts not named) and one --seconds")
    parts = dict(named)
    if len(parts) != len(named):
        raise UserError("name each body part once with --part")
    unknown = sorted(set(parts) - set(PARTS))
    if unknown:
        raise UserError(f"unknown body part {unknown[0]!r}: choose from {', '.join(PARTS)}")
    missing = [part for part in PARTS if part not in parts]
    if missing and not prompts:
        raise UserError(f"give a prompt for the parts not named ({', '.join(missing)}), or --part for each of them")
    parts.update({part: prompts[0] for part in missing})
    return parts, seconds[0] if seconds else None
