"""The tagged words of the captions: verb forms, numbers, subjects, and the ``word/POS`` tokens
that HumanML3D's ``text_process.py`` would give each word in its position."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

UPOS = frozenset("ADJ ADP ADV AUX CCONJ DET INTJ NOUN NUM PART PRON PROPN PUNCT SCONJ SYM VERB X".split())


# Verb forms the templates use: lemma → (third person singular, -ing form).
_VERBS = {
    "back": ("backs", "backing"),
    "bend": ("bends", "bending"),
    "bow": ("bows", "bowing"),
    "bring": ("brings", "bringing"),
    "clap": ("claps", "clapping"),
    "crouch": ("crouches", "crouching"),
    "do": ("does", "doing"),
    "get": ("gets", "getting"),
    "give": ("gives", "giving"),
    "hold": ("holds", "holding"),
    "hop": ("hops", "hopping"),
    "hurry": ("hurries", "hurrying"),
    "jog": ("jogs", "jogging"),
    "jump": ("jumps", "jumping"),
    "kick": ("kicks", "kicking"),
    "leap": ("leaps", "leaping"),
    "lift": ("lifts", "lifting"),
    "lower": ("lowers", "lowering"),
    "make": ("makes", "making"),
    "move": ("moves", "moving"),
    "punch": ("punches", "punching"),
    "put": ("puts", "putting"),
    "raise": ("raises", "raising"),
    "rise": ("rises", "rising"),
    "run": ("runs", "running"),
    "shuffle": ("shuffles", "shuffling"),
    "sidestep": ("sidesteps", "sidestepping"),
    "sit": ("sits", "sitting"),
    "sprint": ("sprints", "sprinting"),
    "squat": ("squats", "squatting"),
    "stand": ("stands", "standing"),
    "step": ("steps", "stepping"),
    "stop": ("stops", "stopping"),
    "stretch": ("stretches", "stretching"),
    "stroll": ("strolls", "strolling"),
    "take": ("takes", "taking"),
    "throw": ("throws", "throwing"),
    "turn": ("turns", "turning"),
    "walk": ("walks", "walking"),
    "wave": ("waves", "waving"),
}


_PLURALS = {
    "arms": "arm",
    "degrees": "degree",
    "feet": "foot",
    "fists": "fist",
    "hands": "hand",
    "hops": "hop",
    "jumps": "jump",
    "kicks": "kick",
    "knees": "knee",
    "punches": "punch",
    "sides": "side",
    "squats": "squat",
    "steps": "step",
    "times": "time",
}


_NUMBERS = ("zero one two three four five six seven eight nine ten eleven twelve thirteen fourteen fifteen").split()


@dataclass(frozen=True)
class Subject:
    """Who the caption is about, with the pronouns that agree with it."""

    words: str  # tagged
    their: str
    them: str
    themselves: str


SUBJECTS = (
    Subject("a/DET person/NOUN", "their", "them", "themselves"),
    Subject("the/DET person/NOUN", "their", "them", "themselves"),
    Subject("someone/PRON", "their", "them", "themselves"),
    Subject("a/DET figure/NOUN", "their", "them", "themselves"),
    Subject("a/DET man/NOUN", "his", "him", "himself"),
    Subject("the/DET man/NOUN", "his", "him", "himself"),
    Subject("a/DET woman/NOUN", "her", "her", "herself"),
    Subject("the/DET woman/NOUN", "her", "her", "herself"),
)


@dataclass(frozen=True)
class Token:
    """One word of a caption with its universal POS tag and the form HumanML3D lists it in."""

    text: str  # as written in the caption
    tag: str  # universal POS
    lemma: str  # as written in the token list


def tagged_tokens(template: str, form: str, subject: Subject) -> list[Token]:
    """Parse a tagged template: ``word/TAG`` items, ``@verb`` (a VERB inflected to ``form``:
    "s" or "ing"), ``,`` and the pronoun slots ``{their}``, ``{them}``, ``{themselves}``."""
    template = template.format(
        their=f"{subject.their}/PRON", them=f"{subject.them}/PRON", themselves=f"{subject.themselves}/PRON"
    )
    tokens = []
    for item in template.split():
        if item == ",":
            tokens.append(Token(",", "PUNCT", ","))
        elif item.startswith("@"):
            lemma = item[1:]
            third, gerund = _VERBS[lemma]
            tokens.append(Token(third if form == "s" else gerund, "VERB", lemma))
        else:
            word, tag = item.rsplit("/", 1)
            lemma = _PLURALS.get(word, word) if tag == "NOUN" and word != "left" else word
            tokens.append(Token(word, tag, lemma))
    return tokens


def caption_text(tokens: Sequence[Token]) -> str:
    return " ".join(t.text for t in tokens).replace(" ,", ",")


def caption_line(tokens: Sequence[Token]) -> str:
    """HumanML3D text line ``caption#word/POS ...#0.0#0.0`` (the caption covers the whole clip)."""
    tags = " ".join(f"{t.lemma}/{t.tag}" for t in tokens if t.lemma.isalpha())
    return f"{caption_text(tokens)}#{tags}#0.0#0.0"


# One function per family: the ways to say that action with its parameters, as tagged templates.
# Every template names the side and direction of the motion, and nearly all name its speed,
# count and amplitude, so that the text determines the motion.
def number_word(n: int) -> str:
    return f"{_NUMBERS[n]}/NUM"


def times_phrase(n: int, rng: np.random.Generator, optional_once: bool = False) -> str:
    """How many times: "once", "twice", "three times" (or nothing for a single one, sometimes)."""
    if n == 1:
        return "" if optional_once and rng.random() < 0.5 else "once/ADV"
    if n == 2 and rng.random() < 0.6:
        return "twice/ADV"
    return f"{number_word(n)} times/NOUN"


def choose(rng: np.random.Generator, options: Sequence[str]) -> str:
    return options[int(rng.integers(len(options)))]
