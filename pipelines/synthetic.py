"""The embedded synthetic motion-language corpus, written in HumanML3D's raw layout.

Real corpora cannot be redistributed (AMASS licence), so the demo and the tests run on a corpus
the project makes itself: clips of 1–3 chained actions (motions from
:mod:`pipelines.synthetic_motion`) with three captions each, tagged the way HumanML3D's
``text_process.py`` tags them. Everything is a function of ``(seed, clip index)``, so the corpus
is byte-identical whatever the number of workers.

Layout under ``out_dir``::

    joints/<id>.npy     float32 (T, 22, 3), 20 fps, 40 ≤ T ≤ 199
    texts/<id>.txt      caption#word/POS word/POS ...#0.0#0.0   (three lines)
    train.txt val.txt test.txt
    annotations.jsonl   per clip: actions (family, parameters, frame range), body scale, captions
    corpus.json         seed, clip count, families, generator version, summary

Captions are built from a small grammar whose every word carries the universal POS tag spaCy's
``en_core_web_sm`` gives it in that position (``is``/AUX, ``his``/PRON, ``left``/ADJ before a noun
and ADV after "turn", particles such as "down" in "sits down"/ADP); NOUN and VERB tokens are
written as their lemma except the word ``left``, and punctuation is kept in the caption but not in
the tokens, exactly as HumanML3D's processed texts.
"""

from __future__ import annotations

import json
import multiprocessing
import re
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from functools import partial
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np

from pipelines.synthetic_motion import ACTIONS, FPS, Texture, compose, program_joints

GENERATOR_VERSION = "1.1"
# Real capture's high-frequency content, calibrated against HumanML3D (bench/calibrate_corpus.py).
TEXTURE = Texture(pelvis=0.00169, wrists=0.00324)
FAMILIES: tuple[str, ...] = tuple(ACTIONS)
MIN_FRAMES, MAX_FRAMES = 40, 199  # HumanML3D keeps 40 ≤ T < 200
SPLITS = {"train": 0.80, "val": 0.05, "test": 0.15}
CAPTIONS_PER_CLIP = 3
UPOS = frozenset(
    "ADJ ADP ADV AUX CCONJ DET INTJ NOUN NUM PART PRON PROPN PUNCT SCONJ SYM VERB X".split()
)
_ID = re.compile(r"^\d{6}$")


# --------------------------------------------------------------------------- words


# Verb forms the templates use: lemma → (third person singular, -ing form).
_VERBS = {
    "back": ("backs", "backing"), "bend": ("bends", "bending"), "bow": ("bows", "bowing"),
    "bring": ("brings", "bringing"), "clap": ("claps", "clapping"), "crouch": ("crouches", "crouching"),
    "do": ("does", "doing"), "get": ("gets", "getting"), "give": ("gives", "giving"),
    "hold": ("holds", "holding"), "hop": ("hops", "hopping"), "hurry": ("hurries", "hurrying"),
    "jog": ("jogs", "jogging"), "jump": ("jumps", "jumping"), "kick": ("kicks", "kicking"),
    "leap": ("leaps", "leaping"), "lift": ("lifts", "lifting"), "lower": ("lowers", "lowering"),
    "make": ("makes", "making"), "move": ("moves", "moving"), "punch": ("punches", "punching"),
    "put": ("puts", "putting"), "raise": ("raises", "raising"), "rise": ("rises", "rising"),
    "run": ("runs", "running"), "shuffle": ("shuffles", "shuffling"),
    "sidestep": ("sidesteps", "sidestepping"), "sit": ("sits", "sitting"),
    "sprint": ("sprints", "sprinting"), "squat": ("squats", "squatting"),
    "stand": ("stands", "standing"), "step": ("steps", "stepping"), "stop": ("stops", "stopping"),
    "stretch": ("stretches", "stretching"), "stroll": ("strolls", "strolling"),
    "take": ("takes", "taking"), "throw": ("throws", "throwing"), "turn": ("turns", "turning"),
    "walk": ("walks", "walking"), "wave": ("waves", "waving"),
}
_PLURALS = {
    "arms": "arm", "degrees": "degree", "feet": "foot", "fists": "fist", "hands": "hand",
    "hops": "hop", "jumps": "jump", "kicks": "kick", "knees": "knee", "punches": "punch",
    "sides": "side", "squats": "squat", "steps": "step", "times": "time",
}
_NUMBERS = ("zero one two three four five six seven eight nine ten eleven twelve thirteen "
            "fourteen fifteen").split()


@dataclass(frozen=True)
class Subject:
    """Who the caption is about, with the pronouns that agree with it."""

    words: str  # tagged
    their: str
    them: str
    themselves: str


_SUBJECTS = (
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


def _tokens(template: str, form: str, subject: Subject) -> list[Token]:
    """Parse a tagged template: ``word/TAG`` items, ``@verb`` (a VERB inflected to ``form``:
    "s" or "ing"), ``,`` and the pronoun slots ``{their}``, ``{them}``, ``{themselves}``."""
    template = template.format(their=f"{subject.their}/PRON", them=f"{subject.them}/PRON",
                               themselves=f"{subject.themselves}/PRON")
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


# --------------------------------------------------------------------------- action phrases
# One function per family: the ways to say that action with its parameters, as tagged templates.
# Every template names the side and direction of the motion, and nearly all name its speed,
# count and amplitude, so that the text determines the motion.


def _num(n: int) -> str:
    return f"{_NUMBERS[n]}/NUM"


def _times(n: int, rng: np.random.Generator, optional_once: bool = False) -> str:
    """How many times: "once", "twice", "three times" (or nothing for a single one, sometimes)."""
    if n == 1:
        return "" if optional_once and rng.random() < 0.5 else "once/ADV"
    if n == 2 and rng.random() < 0.6:
        return "twice/ADV"
    return f"{_num(n)} times/NOUN"


def _choose(rng: np.random.Generator, options: Sequence[str]) -> str:
    return options[int(rng.integers(len(options)))]


def _walk(p: dict, rng: np.random.Generator) -> list[str]:
    speed = _choose(rng, {
        "slow": ("slowly/ADV", "at/ADP a/DET slow/ADJ pace/NOUN"),
        "normal": ("", "", "at/ADP a/DET normal/ADJ pace/NOUN", "at/ADP a/DET steady/ADJ pace/NOUN"),
        "fast": ("quickly/ADV", "briskly/ADV", "fast/ADV", "at/ADP a/DET fast/ADJ pace/NOUN"),
    }[p["speed"]])
    n = _num(p["steps"])
    phrases = [f"@walk forward/ADV {speed}", f"@take {n} steps/NOUN forward/ADV {speed}",
               f"@walk {n} steps/NOUN forward/ADV {speed}", f"@walk straight/ADV ahead/ADV {speed}",
               f"@walk forward/ADV {speed} and/CCONJ @stop"]
    if p["speed"] == "slow":
        phrases.append("@stroll slowly/ADV forward/ADV")
    if p["speed"] == "fast":
        phrases.append(f"@hurry forward/ADV {n} steps/NOUN")
    return phrases


def _walk_backwards(p: dict, rng: np.random.Generator) -> list[str]:
    speed = "slowly/ADV" if p["speed"] == "slow" else ""
    back = _choose(rng, ("backwards/ADV", "backward/ADV"))
    n = _num(p["steps"])
    return [f"@walk {back} {speed}", f"@take {n} steps/NOUN {back} {speed}",
            f"@walk {back} {n} steps/NOUN {speed}", f"@back up/ADP {speed}", f"@move {back} {speed}"]


def _walk_circle(p: dict, rng: np.random.Generator) -> list[str]:
    clockwise = p["direction"] == "clockwise"
    way = "clockwise" if clockwise else _choose(rng, ("counterclockwise", "anticlockwise"))
    side = "right" if clockwise else "left"
    return [f"@walk in/ADP a/DET circle/NOUN {way}/ADV", f"@walk {way}/ADV in/ADP a/DET circle/NOUN",
            f"@walk in/ADP {'an' if way[0] == 'a' else 'a'}/DET {way}/ADJ circle/NOUN",
            f"@walk around/ADV in/ADP a/DET circle/NOUN to/ADP the/DET {side}/NOUN",
            f"@walk in/ADP a/DET full/ADJ circle/NOUN {way}/ADV",
            f"@walk around/ADV in/ADP a/DET circle/NOUN {way}/ADV"]


def _jog(p: dict, rng: np.random.Generator) -> list[str]:
    speed = _choose(rng, ("slowly/ADV", "lightly/ADV", "at/ADP an/DET easy/ADJ pace/NOUN")) \
        if p["speed"] == "slow" else ""
    return [f"@jog forward/ADV {speed}", f"@jog straight/ADV ahead/ADV {speed}",
            f"@jog forward/ADV {speed} and/CCONJ @stop",
            f"@jog a/DET short/ADJ distance/NOUN forward/ADV {speed}"]


def _run(p: dict, rng: np.random.Generator) -> list[str]:
    speed = _choose(rng, ("quickly/ADV", "fast/ADV", "at/ADP full/ADJ speed/NOUN")) \
        if p["speed"] == "fast" else ""
    phrases = [f"@run forward/ADV {speed}", f"@run straight/ADV ahead/ADV {speed}",
               f"@run forward/ADV {speed} and/CCONJ @stop",
               f"@run a/DET short/ADJ distance/NOUN forward/ADV {speed}"]
    if p["speed"] == "fast":
        phrases.append("@sprint forward/ADV")
    return phrases


def _sidestep(p: dict, rng: np.random.Generator) -> list[str]:
    side, n = p["side"], p["count"]
    return [f"@sidestep to/ADP the/DET {side}/NOUN {_times(n, rng)}",
            f"@take {_num(n)} side/NOUN steps/NOUN to/ADP the/DET {side}/NOUN",
            f"@take {_num(n)} steps/NOUN sideways/ADV to/ADP the/DET {side}/NOUN",
            f"@step sideways/ADV to/ADP {{their}} {side}/NOUN {_times(n, rng)}",
            f"@shuffle {_num(n)} steps/NOUN to/ADP the/DET {side}/NOUN"]


def _turn(p: dict, rng: np.random.Generator) -> list[str]:
    side = p["side"]
    if p["angle"] == 45:
        return [f"@turn slightly/ADV to/ADP the/DET {side}/NOUN", f"@turn slightly/ADV {side}/ADV",
                f"@turn forty/NUM five/NUM degrees/NOUN to/ADP the/DET {side}/NOUN"]
    if p["angle"] == 90:
        return [f"@turn {side}/ADV", f"@turn to/ADP the/DET {side}/NOUN",
                f"@turn ninety/NUM degrees/NOUN to/ADP the/DET {side}/NOUN",
                f"@turn to/ADP {{their}} {side}/NOUN",
                f"@make a/DET quarter/NOUN turn/NOUN to/ADP the/DET {side}/NOUN"]
    way = "counterclockwise" if side == "left" else "clockwise"
    return [f"@turn around/ADV to/ADP the/DET {side}/NOUN",
            f"@turn around/ADV over/ADP {{their}} {side}/ADJ shoulder/NOUN",
            f"@turn one/NUM hundred/NUM and/CCONJ eighty/NUM degrees/NOUN to/ADP the/DET {side}/NOUN",
            f"@make a/DET half/ADJ turn/NOUN to/ADP the/DET {side}/NOUN",
            f"@turn around/ADV {way}/ADV"]


def _jump(p: dict, rng: np.random.Generator) -> list[str]:
    n = p["count"]
    times = _times(n, rng, optional_once=True)
    if p["direction"] == "forward":
        phrases = [f"@jump forward/ADV {times}", f"@leap forward/ADV {times}",
                   f"@jump forward/ADV with/ADP both/DET feet/NOUN {times}"]
        phrases.append(f"@do {_num(n)} jumps/NOUN forward/ADV" if n > 1
                       else "@do a/DET jump/NOUN forward/ADV")
        return phrases
    phrases = [f"@jump in/ADP place/NOUN {times}", f"@jump on/ADP the/DET spot/NOUN {times}",
               f"@jump straight/ADV up/ADV {times}"]
    phrases.append(f"@do {_num(n)} jumps/NOUN in/ADP place/NOUN" if n > 1
                   else "@do a/DET jump/NOUN in/ADP place/NOUN")
    if n > 1:
        phrases.append(f"@jump up/ADV and/CCONJ down/ADV {times}")
    return phrases


def _hop(p: dict, rng: np.random.Generator) -> list[str]:
    side, n = p["side"], p["count"]
    other = "right" if side == "left" else "left"
    where = "forward/ADV" if p["direction"] == "forward" else _choose(
        rng, ("in/ADP place/NOUN", "on/ADP the/DET spot/NOUN"))
    times = _times(n, rng)
    return [f"@hop {where} on/ADP {{their}} {side}/ADJ leg/NOUN {times}",
            f"@hop on/ADP {{their}} {side}/ADJ foot/NOUN {where} {times}",
            f"@hop {times} on/ADP the/DET {side}/ADJ leg/NOUN {where}",
            f"@stand on/ADP {{their}} {side}/ADJ leg/NOUN and/CCONJ @hop {where} {times}",
            f"@lift {{their}} {other}/ADJ foot/NOUN and/CCONJ @hop {where} on/ADP the/DET {side}/ADJ one/NOUN {times}",
            f"@do {_num(n)} hops/NOUN {where} on/ADP {{their}} {side}/ADJ leg/NOUN"]


def _wave(p: dict, rng: np.random.Generator) -> list[str]:
    times = _times(p["count"], rng)
    if p["side"] == "both":
        return [f"@wave both/DET hands/NOUN {times}", f"@wave with/ADP both/DET hands/NOUN {times}",
                f"@raise both/DET hands/NOUN and/CCONJ @wave {times}",
                f"@wave both/DET arms/NOUN above/ADP {{their}} head/NOUN {times}"]
    side = p["side"]
    hand = f"{{their}} {side}/ADJ hand/NOUN"
    return [f"@wave {hand} {times}", f"@wave with/ADP {hand} {times}",
            f"@wave {times} with/ADP the/DET {side}/ADJ hand/NOUN",
            f"@raise {hand} and/CCONJ @wave {times}",
            f"@wave {hand} back/ADV and/CCONJ forth/ADV {times}"]


def _raise_arms(p: dict, rng: np.random.Generator) -> list[str]:
    both = p["side"] == "both"
    arms = _choose(rng, ("both/DET arms/NOUN", "{their} arms/NOUN")) if both \
        else f"{{their}} {p['side']}/ADJ arm/NOUN"
    it = "them/PRON" if both else "it/PRON"
    if p["direction"] == "up":
        return [f"@raise {arms} above/ADP {{their}} head/NOUN", f"@raise {arms} straight/ADV up/ADV",
                f"@lift {arms} over/ADP {{their}} head/NOUN",
                f"@raise {arms} above/ADP {{their}} head/NOUN and/CCONJ @lower {it}",
                f"@put {arms} up/ADP in/ADP the/DET air/NOUN"]
    if p["direction"] == "forward":
        return [f"@raise {arms} in/ADP front/NOUN of/ADP {{them}}",
                f"@stretch {arms} out/ADP in/ADP front/NOUN of/ADP {{them}}",
                f"@lift {arms} forward/ADV to/ADP shoulder/NOUN height/NOUN",
                f"@raise {arms} forward/ADV and/CCONJ then/ADV @lower {it}"]
    sides = "the/DET sides/NOUN" if both else "the/DET side/NOUN"
    return [f"@raise {arms} out/ADP to/ADP {sides}", f"@stretch {arms} out/ADP sideways/ADV",
            f"@lift {arms} sideways/ADV to/ADP shoulder/NOUN height/NOUN",
            f"@hold {arms} out/ADP to/ADP {sides} and/CCONJ then/ADV @lower {it}"]


def _clap(p: dict, rng: np.random.Generator) -> list[str]:
    times = _times(p["count"], rng)
    return [f"@clap {times}", f"@clap {{their}} hands/NOUN {times}",
            f"@clap {_num(p['count'])} times/NOUN", f"@clap {{their}} hands/NOUN together/ADV {times}",
            f"@bring {{their}} hands/NOUN together/ADV and/CCONJ @clap {times}"]


def _punch(p: dict, rng: np.random.Generator) -> list[str]:
    side, n = p["side"], p["count"]
    times = _times(n, rng, optional_once=True)
    phrases = [f"@punch forward/ADV with/ADP {{their}} {side}/ADJ hand/NOUN {times}",
               f"@punch with/ADP {{their}} {side}/ADJ fist/NOUN {times}",
               f"@punch the/DET air/NOUN with/ADP {{their}} {side}/ADJ fist/NOUN {times}",
               f"@raise {{their}} fists/NOUN and/CCONJ @punch with/ADP the/DET {side}/ADJ hand/NOUN {times}"]
    phrases.append(f"@throw {_num(n)} punches/NOUN with/ADP {{their}} {side}/ADJ arm/NOUN" if n > 1
                   else f"@throw a/DET {side}/ADJ punch/NOUN")
    return phrases


def _kick(p: dict, rng: np.random.Generator) -> list[str]:
    side, n, height = p["side"], p["count"], p["height"]
    times = _times(n, rng, optional_once=True)
    kicks = f"a/DET {height}/ADJ kick/NOUN" if n == 1 else f"two/NUM {height}/ADJ kicks/NOUN"
    return [f"@kick {height}/ADV with/ADP {{their}} {side}/ADJ leg/NOUN {times}",
            f"@kick {{their}} {side}/ADJ leg/NOUN {height}/ADV {times}",
            f"@kick forward/ADV {height}/ADV with/ADP the/DET {side}/ADJ foot/NOUN {times}",
            f"@do {kicks} with/ADP {{their}} {side}/ADJ leg/NOUN",
            f"@lift {{their}} {side}/ADJ knee/NOUN and/CCONJ @kick forward/ADV {height}/ADV {times}"]


def _squat(p: dict, rng: np.random.Generator) -> list[str]:
    n, deep = p["count"], p["depth"] == "deep"
    how = _choose(rng, ("deeply/ADV", "low/ADV")) if deep else "halfway/ADV"
    times = _times(n, rng, optional_once=True)
    adjective = "deep/ADJ" if deep else "shallow/ADJ"
    squats = f"a/DET {adjective} squat/NOUN" if n == 1 else f"{_num(n)} {adjective} squats/NOUN"
    return [f"@squat down/ADP {how} {times}", f"@squat {how} {times}", f"@do {squats}",
            f"@squat down/ADP {how} and/CCONJ @stand back/ADV up/ADP {times}",
            f"@bend {{their}} knees/NOUN and/CCONJ @squat {how} {times}"]


def _bow(p: dict, rng: np.random.Generator) -> list[str]:
    deep = p["depth"] == "deep"
    how = _choose(rng, ("deeply/ADV", "low/ADV")) if deep else "slightly/ADV"
    adjective = "deep/ADJ" if deep else _choose(rng, ("small/ADJ", "slight/ADJ"))
    return [f"@bow {how}", f"@take a/DET {adjective} bow/NOUN", f"@bow forward/ADV {how}",
            f"@bend forward/ADV {how} at/ADP the/DET waist/NOUN",
            f"@bow {how} and/CCONJ @stand back/ADV up/ADP", f"@give a/DET {adjective} bow/NOUN"]


def _sit_down(p: dict, rng: np.random.Generator) -> list[str]:
    slowly = "slowly/ADV" if p["speed"] == "slow" else ""
    return [f"@sit down/ADP {slowly}", f"@sit down/ADP on/ADP a/DET chair/NOUN {slowly}",
            f"@sit {slowly} down/ADP on/ADP a/DET seat/NOUN", f"@take a/DET seat/NOUN {slowly}",
            f"@lower {{themselves}} {slowly} onto/ADP a/DET chair/NOUN"]


def _stand_up(p: dict, rng: np.random.Generator) -> list[str]:
    slowly = "slowly/ADV" if p["speed"] == "slow" else ""
    return [f"@stand up/ADP {slowly}", f"@get up/ADP {slowly}",
            f"@stand up/ADP from/ADP the/DET chair/NOUN {slowly}",
            f"@get up/ADP from/ADP {{their}} seat/NOUN {slowly}",
            f"@rise {slowly} from/ADP the/DET chair/NOUN", f"@rise to/ADP {{their}} feet/NOUN {slowly}"]


_PHRASES: dict[str, Callable[[dict, np.random.Generator], list[str]]] = {
    "walk": _walk, "walk_backwards": _walk_backwards, "walk_circle": _walk_circle, "jog": _jog,
    "run": _run, "sidestep": _sidestep, "turn": _turn, "jump": _jump, "hop": _hop, "wave": _wave,
    "raise_arms": _raise_arms, "clap": _clap, "punch": _punch, "kick": _kick, "squat": _squat,
    "bow": _bow, "sit_down": _sit_down, "stand_up": _stand_up,
}


# --------------------------------------------------------------------------- captions

# Sentence patterns by number of actions: ``{S}`` the subject, ``<i:form>`` action i's phrase
# with its verbs in the "s" (walks) or "ing" (walking) form, anything else tagged words.
_PATTERNS: dict[int, tuple[str, ...]] = {
    1: ("{S} <0:s>", "{S} <0:s>", "{S} is/AUX <0:ing>", "{S} <0:ing>"),
    2: ("{S} <0:s> and/CCONJ then/ADV <1:s>", "{S} <0:s> , then/ADV <1:s>",
        "{S} <0:s> and/CCONJ <1:s>", "{S} first/ADV <0:s> and/CCONJ then/ADV <1:s>",
        "after/ADP <0:ing> , {S} <1:s>", "{S} <0:s> before/ADP <1:ing>",
        "{S} is/AUX <0:ing> and/CCONJ then/ADV <1:ing>", "{S} <0:ing> and/CCONJ then/ADV <1:ing>"),
    3: ("{S} <0:s> , <1:s> , and/CCONJ then/ADV <2:s>",
        "{S} <0:s> , then/ADV <1:s> , and/CCONJ finally/ADV <2:s>",
        "{S} first/ADV <0:s> , then/ADV <1:s> and/CCONJ <2:s>",
        "after/ADP <0:ing> , {S} <1:s> and/CCONJ then/ADV <2:s>",
        "{S} is/AUX <0:ing> , <1:ing> , and/CCONJ then/ADV <2:ing>"),
}
_SLOT = re.compile(r"<(\d):(s|ing)>")


def _sentence(pattern: str, phrases: Sequence[str], subject: Subject) -> list[Token]:
    """Tokens of one caption: the pattern with the subject and the action phrases filled in."""
    tokens: list[Token] = []
    for part in re.split(r"(\{S\}|<\d:(?:s|ing)>)", pattern):
        slot = _SLOT.fullmatch(part)
        if part == "{S}":
            tokens += _tokens(subject.words, "s", subject)
        elif slot:
            tokens += _tokens(phrases[int(slot.group(1))], slot.group(2), subject)
        elif part.strip():
            tokens += _tokens(part, "s", subject)
    return tokens


def make_captions(plan: Sequence[tuple[str, dict]], rng: np.random.Generator,
                  count: int = CAPTIONS_PER_CLIP) -> list[list[Token]]:
    """``count`` different captions of a plan, each with its own subject, sentence pattern and
    phrasings; inside multi-action sentences, phrases that are themselves two clauses are rarer."""
    captions: list[list[Token]] = []
    seen: set[object] = set()
    texts: set[str] = set()
    for attempt in range(100):
        subject = _SUBJECTS[int(rng.integers(len(_SUBJECTS)))]
        pattern = _choose(rng, _PATTERNS[len(plan)])
        phrases = []
        for name, params in plan:
            options = _PHRASES[name](params, rng)
            if len(plan) > 1 and rng.random() < 0.7:
                options = [o for o in options if " and/CCONJ " not in o] or options
            phrases.append(" ".join(_choose(rng, options).split()))
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
    phrase = _PHRASES[name](params, np.random.default_rng(0))[0]
    return caption_text(_sentence("{S} <0:s>", [phrase], _SUBJECTS[0]))


def is_multi_verb(tokens: Sequence[Token]) -> bool:
    return sum(t.tag == "VERB" for t in tokens) >= 2


# --------------------------------------------------------------------------- clips


def check_families(families: Iterable[str] | None) -> tuple[str, ...]:
    """The families to draw from, in canonical order; unknown names are an error."""
    if families is None:
        return FAMILIES
    families = (families,) if isinstance(families, str) else tuple(families)
    unknown = sorted(set(families) - set(FAMILIES))
    if unknown or not families:
        raise ValueError(
            f"unknown action families {unknown or '(none given)'}; valid: {', '.join(FAMILIES)}"
        )
    return tuple(f for f in FAMILIES if f in families)


def sample_plan(rng: np.random.Generator, families: Sequence[str], max_actions: int = 3,
                ) -> list[tuple[str, dict]]:
    """1–``max_actions`` actions that can follow each other: nothing but "stand up" after
    "sit down", "stand up" only from a seat, and no family twice in a row."""
    count = int(rng.choice(3, p=(0.4, 0.35, 0.25))) + 1
    plan: list[tuple[str, dict]] = []
    seated = False
    for i in range(min(count, max_actions)):
        if i == 0:
            options = list(families)
        else:
            options = [f for f in families if ACTIONS[f].seated_before == seated and f != plan[-1][0]]
        if not options:
            break
        name = options[int(rng.integers(len(options)))]
        plan.append((name, ACTIONS[name].sample(rng)))
        seated = ACTIONS[name].seated_after
    return plan


@dataclass(frozen=True)
class Clip:
    """One generated clip: its joints and everything written about it."""

    id: str
    joints: np.ndarray
    plan: list[tuple[str, dict]]
    segments: tuple[tuple[int, int], ...]
    captions: list[list[Token]]
    body_scale: float

    def annotation(self) -> dict:
        return {
            "id": self.id,
            "frames": len(self.joints),
            "body_scale": round(self.body_scale, 4),
            "actions": [
                {"family": name, "params": params, "start": start, "end": end,
                 "text": action_text(name, params)}
                for (name, params), (start, end) in zip(self.plan, self.segments)
            ],
            "captions": [caption_text(c) for c in self.captions],
        }


def make_clip(index: int, seed: int = 0, families: Sequence[str] = FAMILIES,
              max_actions: int = 3, texture: Texture = TEXTURE) -> Clip:
    """Clip number ``index`` of the corpus with ``seed``: a function of (seed, index) only.
    A plan whose motion would exceed 199 frames loses its last action (a lone action that is
    too long is drawn again), so long families keep their share of first actions. The texture
    is drawn from its own stream, so plans, captions and bodies do not depend on it."""
    rng = np.random.default_rng([seed, index])
    plan = sample_plan(rng, families, max_actions)
    for _ in range(40):
        composition = compose(plan, rng, MIN_FRAMES)
        if len(composition.program) <= MAX_FRAMES:
            break
        plan = plan[:-1] if len(plan) > 1 else sample_plan(rng, families, 1)
    else:
        raise RuntimeError(f"clip {index}: no plan of {families} fits in {MAX_FRAMES} frames")
    program = texture.apply(composition.program, np.random.default_rng([seed, index, 2]))
    joints = program_joints(program, composition.body).astype(np.float32)
    return Clip(f"{index:06d}", joints, plan, composition.segments, make_captions(plan, rng),
                composition.body.scale)


# --------------------------------------------------------------------------- the corpus


def assign_splits(ids: Sequence[str], seed: int) -> dict[str, list[str]]:
    """Deterministic ~80/5/15 split of ``ids`` (each list sorted)."""
    order = np.random.default_rng([seed, 1_000_003]).permutation(len(ids))
    n_val = int(round(SPLITS["val"] * len(ids)))
    n_test = int(round(SPLITS["test"] * len(ids)))
    shuffled = [ids[i] for i in order]
    return {
        "train": sorted(shuffled[n_val + n_test:]),
        "val": sorted(shuffled[:n_val]),
        "test": sorted(shuffled[n_val:n_val + n_test]),
    }


def _write_clip(out: Path, seed: int, families: tuple[str, ...], max_actions: int,
                index: int) -> tuple[dict, int]:
    """Generate and write one clip; returns its annotation and how many captions are multi-verb."""
    clip = make_clip(index, seed, families, max_actions)
    np.save(out / "joints" / f"{clip.id}.npy", clip.joints)
    lines = "".join(caption_line(c) + "\n" for c in clip.captions)
    (out / "texts" / f"{clip.id}.txt").write_text(lines, encoding="utf-8")
    return clip.annotation(), sum(is_multi_verb(c) for c in clip.captions)


def _remove_stale(out: Path) -> None:
    """Delete clips of an earlier run in the same directory, so the layout matches the splits."""
    for folder, suffix in (("joints", ".npy"), ("texts", ".txt")):
        for path in (out / folder).glob(f"*{suffix}"):
            if _ID.match(path.stem):
                path.unlink()


def existing_corpus(out_dir: str | Path, clips: int, seed: int, families: Sequence[str] | None = None) -> bool:
    """Whether ``out_dir`` already holds exactly this corpus (so generating it again is nothing to
    do); ValueError when it holds a different one, which only an explicit rebuild may replace."""
    marker = Path(out_dir) / "corpus.json"
    if not marker.exists():
        return False
    existing = json.loads(marker.read_text(encoding="utf-8"))
    wanted = {"clips": clips, "seed": seed, "families": list(families or FAMILIES),
              "version": GENERATOR_VERSION}
    different = [key for key, value in wanted.items() if existing.get(key) != value]
    if not different:
        return True
    raise ValueError(f"{out_dir} holds a different corpus ({marker}: other {', '.join(different)}); "
                     "use another --out or --force")


def generate_corpus(
    out_dir: str | Path,
    clips: int = 2000,
    seed: int = 0,
    families: Sequence[str] | None = None,
    workers: int = 1,
    progress: bool = False,
    max_actions: int = 3,
) -> dict:
    """Write the synthetic corpus (layout in the module docstring) and return its summary:
    clip counts per split, captions, multi-verb caption share, frames, hours, actions per family.

    ``families`` restricts the action families (``FAMILIES`` lists them); ``max_actions=1``
    makes a corpus of single actions. The files depend only on (clips, seed, families,
    max_actions), never on ``workers``.
    """
    families = check_families(families)
    if clips < 1:
        raise ValueError(f"clips must be at least 1, got {clips}")
    if max_actions < 1:
        raise ValueError(f"max_actions must be at least 1, got {max_actions}")
    out = Path(out_dir)
    for folder in ("joints", "texts"):
        (out / folder).mkdir(parents=True, exist_ok=True)
    _remove_stale(out)

    job = partial(_write_clip, out, seed, families, max_actions)
    if workers > 1:
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
            results = _progress(pool.map(job, range(clips), chunksize=16), clips, progress)
            results = list(results)
    else:
        results = list(_progress(map(job, range(clips)), clips, progress))

    records = [record for record, _ in results]
    with open(out / "annotations.jsonl", "w", encoding="utf-8") as f:
        for record in records:
            f.write(json.dumps(record, sort_keys=True) + "\n")
    splits = assign_splits([r["id"] for r in records], seed)
    for name, ids in splits.items():
        (out / f"{name}.txt").write_text("".join(i + "\n" for i in ids), encoding="utf-8")

    frames = sum(r["frames"] for r in records)
    captions = sum(len(r["captions"]) for r in records)
    per_family = Counter(a["family"] for r in records for a in r["actions"])
    summary = {
        "clips": clips,
        "splits": {name: len(ids) for name, ids in splits.items()},
        "captions": captions,
        "multi_verb_share": round(sum(n for _, n in results) / captions, 4),
        "frames": frames,
        "hours": round(frames / FPS / 3600.0, 4),
        "families": {f: per_family.get(f, 0) for f in families},
    }
    corpus = {"generator": "pipelines.synthetic", "version": GENERATOR_VERSION, "seed": seed,
              "clips": clips, "fps": FPS, "families": list(families), "max_actions": max_actions,
              "texture": asdict(TEXTURE), "summary": summary}
    (out / "corpus.json").write_text(json.dumps(corpus, indent=2) + "\n", encoding="utf-8")
    return summary


def _progress(results: Iterable, total: int, enabled: bool) -> Iterable:
    if not enabled:
        return results
    from tqdm import tqdm

    return tqdm(results, total=total, desc="synthetic corpus", unit="clip")
