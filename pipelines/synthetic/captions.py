"""Captions of a clip's plan: sentence patterns by number of actions, filled with each
action's phrases and a subject; the plain one-action sentence of an action."""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np

from pipelines.synthetic.families import ACTIONS
from pipelines.synthetic.words import (
    SUBJECTS,
    Subject,
    Token,
    caption_text,
    choose,
    tagged_tokens,
)

CAPTIONS_PER_CLIP = 3


# Sentence patterns by number of actions: ``{S}`` the subject, ``<i:form>`` action i's phrase
# with its verbs in the "s" (walks) or "ing" (walking) form, anything else tagged words.
_PATTERNS: dict[int, tuple[str, ...]] = {
    1: ("{S} <0:s>", "{S} <0:s>", "{S} is/AUX <0:ing>", "{S} <0:ing>"),
    2: (
        "{S} <0:s> and/CCONJ then/ADV <1:s>",
        "{S} <0:s> , then/ADV <1:s>",
        "{S} <0:s> and/CCONJ <1:s>",
        "{S} first/ADV <0:s> and/CCONJ then/ADV <1:s>",
        "after/ADP <0:ing> , {S} <1:s>",
        "{S} <0:s> before/ADP <1:ing>",
        "{S} is/AUX <0:ing> and/CCONJ then/ADV <1:ing>",
        "{S} <0:ing> and/CCONJ then/ADV <1:ing>",
    ),
    3: (
        "{S} <0:s> , <1:s> , and/CCONJ then/ADV <2:s>",
        "{S} <0:s> , then/ADV <1:s> , and/CCONJ finally/ADV <2:s>",
        "{S} first/ADV <0:s> , then/ADV <1:s> and/CCONJ <2:s>",
        "after/ADP <0:ing> , {S} <1:s> and/CCONJ then/ADV <2:s>",
        "{S} is/AUX <0:ing> , <1:ing> , and/CCONJ then/ADV <2:ing>",
    ),
}


_SLOT = re.compile(r"<(\d):(s|ing)>")


def _sentence(pattern: str, phrases: Sequence[str], subject: Subject) -> list[Token]:
    """Tokens of one caption: the pattern with the subject and the action phrases filled in."""
    tokens: list[Token] = []
    for part in re.split(r"(\{S\}|<\d:(?:s|ing)>)", pattern):
        slot = _SLOT.fullmatch(part)
        if part == "{S}":
            tokens += tagged_tokens(subject.words, "s", subject)
        elif slot:
            tokens += tagged_tokens(phrases[int(slot.group(1))], slot.group(2), subject)
        elif part.strip():
            tokens += tagged_tokens(part, "s", subject)
    return tokens


def make_captions(
    plan: Sequence[tuple[str, dict]], rng: np.random.Generator, count: int = CAPTIONS_PER_CLIP
) -> list[list[Token]]:
    """``count`` different captions of a plan, each with its own subject, sentence pattern and
    phrasings; inside multi-action sentences, phrases that are themselves two clauses are rarer."""
    captions: list[list[Token]] = []
    seen: set[object] = set()
    texts: set[str] = set()
    for attempt in range(100):
        subject = SUBJECTS[int(rng.integers(len(SUBJECTS)))]
        pattern = choose(rng, _PATTERNS[len(plan)])
        phrases = []
        for name, params in plan:
            options = ACTIONS[name].phrases(params, rng)
            if len(plan) > 1 and rng.random() < 0.7:
                options = [o for o in options if " and/CCONJ " not in o] or options
            phrases.append(" ".join(choose(rng, options).split()))
        tokens = _sentence(pattern, phrases, subject)
        text = caption_text(tokens)
        # Prefer captions that differ in more than their subject.
        wording = (pattern, tuple(phrases)) if attempt < 60 else text
        if wording not in seen and text not in texts:
            seen.add(wording)
            texts.add(text)
            captions.append(tokens)
        if len(captions) == count:
            return captions
    raise RuntimeError(f"could not phrase {plan} in {count} different ways")


def action_text(name: str, params: dict) -> str:
    """One plain sentence for a single action ("a person walks forward slowly"), for stages that
    work on actions one at a time."""
    phrase = ACTIONS[name].phrases(params, np.random.default_rng(0))[0]
    return caption_text(_sentence("{S} <0:s>", [phrase], SUBJECTS[0]))


def is_multi_verb(tokens: Sequence[Token]) -> bool:
    return sum(t.tag == "VERB" for t in tokens) >= 2
