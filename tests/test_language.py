"""Verb decomposition of captions into action sentences, from corpus tags and from a trained tagger.

The table's token fields are written as en_core_web_sm writes HumanML3D's: lower case, NOUN and
VERB lemmatised (except "left"), possessives as DET, particles as ADP, punctuation dropped.
"""

from __future__ import annotations

import random
import subprocess
import sys
from pathlib import Path

import pytest

from pipelines import language
from pipelines.language import (
    Decomposition,
    Tagger,
    decompose,
    inflect_third_person,
    load_tagger,
    parse_tagged_tokens,
    train_tagger,
)

# caption, HumanML3D token field, expected verbs, expected action sentences
TABLE: list[tuple[str, str, tuple[str, ...], tuple[str, ...]]] = [
    (
        "a person walks in a circle",
        "a/DET person/NOUN walk/VERB in/ADP a/DET circle/NOUN",
        ("walk",),
        ("a person walks in a circle",),
    ),
    (
        "a man turns left and jumps",
        "a/DET man/NOUN turn/VERB left/ADV and/CCONJ jump/VERB",
        ("turn", "jump"),
        ("a person turns left", "a person jumps"),
    ),
    (
        "someone picks something up then puts it down",
        "someone/PRON pick/VERB something/PRON up/ADP then/ADV put/VERB it/PRON down/ADP",
        ("pick", "put"),
        ("a person picks something up", "a person puts it down"),
    ),
    ("a person is walking", "a/DET person/NOUN is/AUX walk/VERB", ("walk",), ("a person walks",)),
    (
        "a person walks forward while waving",
        "a/DET person/NOUN walk/VERB forward/ADV while/SCONJ wave/VERB",
        ("walk",),
        ("a person walks forward while waving",),
    ),
    (
        "walking forward, the man waves",
        "walk/VERB forward/ADV the/DET man/NOUN wave/VERB",
        ("walk", "wave"),
        ("a person walks forward", "a person waves"),
    ),
    (
        "the person jumps twice, then turns around and sits down",
        "the/DET person/NOUN jump/VERB twice/ADV then/ADV turn/VERB around/ADV and/CCONJ sit/VERB down/ADP",
        ("jump", "turn", "sit"),
        ("a person jumps twice", "a person turns around", "a person sits down"),
    ),
    (
        "a man kneels down on one knee",
        "a/DET man/NOUN kneel/VERB down/ADP on/ADP one/NUM knee/NOUN",
        ("kneel",),
        ("a person kneels down on one knee",),
    ),
    (
        "a figure walks backwards and stops",
        "a/DET figure/NOUN walk/VERB backwards/ADV and/CCONJ stop/VERB",
        ("walk", "stop"),
        ("a person walks backwards", "a person stops"),
    ),
    (
        "a person walks, turns around, and walks back",
        "a/DET person/NOUN walk/VERB turn/VERB around/ADV and/CCONJ walk/VERB back/ADV",
        ("walk", "turn", "walk"),
        ("a person walks", "a person turns around", "a person walks back"),
    ),
    (
        "a person jumps, spins, and lands",
        "a/DET person/NOUN jump/VERB spin/VERB and/CCONJ land/VERB",
        ("jump", "spin", "land"),
        ("a person jumps", "a person spins", "a person lands"),
    ),
    (
        "a man walks forward, picks up a box, and puts it on a table",
        "a/DET man/NOUN walk/VERB forward/ADV pick/VERB up/ADP a/DET box/NOUN and/CCONJ put/VERB "
        "it/PRON on/ADP a/DET table/NOUN",
        ("walk", "pick", "put"),
        ("a person walks forward", "a person picks up a box", "a person puts it on a table"),
    ),
    (
        "a person walks forward and then sits down",
        "a/DET person/NOUN walk/VERB forward/ADV and/CCONJ then/ADV sit/VERB down/ADP",
        ("walk", "sit"),
        ("a person walks forward", "a person sits down"),
    ),
    ("a man starts to run", "a/DET man/NOUN start/VERB to/PART run/VERB", ("run",), ("a person runs",)),
    (
        "a person begins walking forward",
        "a/DET person/NOUN begin/VERB walk/VERB forward/ADV",
        ("walk",),
        ("a person walks forward",),
    ),
    (
        "a person appears to be dancing",
        "a/DET person/NOUN appear/VERB to/PART be/AUX dance/VERB",
        ("dance",),
        ("a person dances",),
    ),
    (
        "a person waves with his right hand",
        "a/DET person/NOUN wave/VERB with/ADP his/DET right/ADJ hand/NOUN",
        ("wave",),
        ("a person waves with his right hand",),
    ),
    (
        "a person steps left then jumps",
        "a/DET person/NOUN step/VERB left/VERB then/ADV jump/VERB",
        ("step", "jump"),
        ("a person steps left", "a person jumps"),
    ),
    (
        "a person sits down after walking in a circle",
        "a/DET person/NOUN sit/VERB down/ADP after/ADP walk/VERB in/ADP a/DET circle/NOUN",
        ("walk", "sit"),
        ("a person walks in a circle", "a person sits down"),
    ),
    (
        "a man does jumping jacks",
        "a/DET man/NOUN do/VERB jump/VERB jack/NOUN",
        ("do",),
        ("a person does jumping jacks",),
    ),
    (
        "a person walks with his arms raised",
        "a/DET person/NOUN walk/VERB with/ADP his/DET arm/NOUN raise/VERB",
        ("walk",),
        ("a person walks with his arms raised",),
    ),
    (
        "a person stops walking and turns around",
        "a/DET person/NOUN stop/VERB walk/VERB and/CCONJ turn/VERB around/ADV",
        ("stop", "turn"),
        ("a person stops walking", "a person turns around"),
    ),
    ("the man is on all fours", "the/DET man/NOUN is/AUX on/ADP all/DET four/NOUN", (), ("a person is on all fours",)),
    (
        "the man kicks with his left leg, then punches with his right hand",
        "the/DET man/NOUN kick/VERB with/ADP his/DET left/ADJ leg/NOUN then/ADV punch/VERB with/ADP "
        "his/DET right/ADJ hand/NOUN",
        ("kick", "punch"),
        ("a person kicks with his left leg", "a person punches with his right hand"),
    ),
    (
        "a person raises both arms above their head and claps",
        "a/DET person/NOUN raise/VERB both/DET arm/NOUN above/ADP their/DET head/NOUN and/CCONJ clap/VERB",
        ("raise", "clap"),
        ("a person raises both arms above their head", "a person claps"),
    ),
    (
        "a person crouches down and then jumps up high",
        "a/DET person/NOUN crouch/VERB down/ADP and/CCONJ then/ADV jump/VERB up/ADV high/ADV",
        ("crouch", "jump"),
        ("a person crouches down", "a person jumps up high"),
    ),
    (
        "someone runs forward, jumps over an obstacle, and keeps running",
        "someone/PRON run/VERB forward/ADV jump/VERB over/ADP an/DET obstacle/NOUN and/CCONJ keep/VERB run/VERB",
        ("run", "jump", "run"),
        ("a person runs forward", "a person jumps over an obstacle", "a person runs"),
    ),
    (
        "a man goes to sit down on a chair",
        "a/DET man/NOUN go/VERB to/PART sit/VERB down/ADP on/ADP a/DET chair/NOUN",
        ("sit",),
        ("a person sits down on a chair",),
    ),
    (
        "a person walks over to pick up a box",
        "a/DET person/NOUN walk/VERB over/ADV to/PART pick/VERB up/ADP a/DET box/NOUN",
        ("walk", "pick"),
        ("a person walks over", "a person picks up a box"),
    ),
    (
        "a person is pushed backwards and falls down",
        "a/DET person/NOUN is/AUX push/VERB backwards/ADV and/CCONJ fall/VERB down/ADP",
        ("push", "fall"),
        ("a person is pushed backwards", "a person falls down"),
    ),
    (
        "a person washes their hands",
        "a/DET person/NOUN wash/VERB their/DET hand/NOUN",
        ("wash",),
        ("a person washes their hands",),
    ),
    (
        "a person carries a box and goes up the stairs",
        "a/DET person/NOUN carry/VERB a/DET box/NOUN and/CCONJ go/VERB up/ADP the/DET stair/NOUN",
        ("carry", "go"),
        ("a person carries a box", "a person goes up the stairs"),
    ),
    (
        "the person does not move",
        "the/DET person/NOUN does/AUX not/PART move/VERB",
        ("move",),
        ("a person does not move",),
    ),
    (
        "a person slowly walks forward",
        "a/DET person/NOUN slowly/ADV walk/VERB forward/ADV",
        ("walk",),
        ("a person slowly walks forward",),
    ),
    (
        "he throws a ball with his right hand",
        "he/PRON throw/VERB a/DET ball/NOUN with/ADP his/DET right/ADJ hand/NOUN",
        ("throw",),
        ("a person throws a ball with his right hand",),
    ),
    (
        "a person waves their hand while stepping sideways, then jumps up and spins",
        "a/DET person/NOUN wave/VERB their/DET hand/NOUN while/SCONJ step/VERB sideways/ADV then/ADV "
        "jump/VERB up/ADV and/CCONJ spin/VERB",
        ("wave", "jump", "spin"),
        ("a person waves their hand while stepping sideways", "a person jumps up", "a person spins"),
    ),
    (
        "a person's arms swing back and forth",
        "a/DET person/NOUN arm/NOUN swing/VERB back/ADV and/CCONJ forth/ADV",
        ("swing",),
        ("a person's arms swing back and forth",),
    ),
    (
        "a person walks counter-clockwise in a circle.",
        "a/DET person/NOUN walk/VERB counterclockwise/ADV in/ADP a/DET circle/NOUN",
        ("walk",),
        ("a person walks counter-clockwise in a circle",),
    ),
    (
        "the standing person kicks with their left foot before going back to their original stance.",
        "the/DET stand/VERB person/NOUN kick/VERB with/ADP their/DET left/ADJ foot/NOUN before/ADP "
        "go/VERB back/ADV to/ADP their/DET original/ADJ stance/NOUN",
        ("kick", "go"),
        ("a person kicks with their left foot", "a person goes back to their original stance"),
    ),
    ("a person in a t-pose", "a/DET person/NOUN in/ADP a/DET tpose/NOUN", (), ("a person in a t-pose",)),
    (
        "a man stands still, then runs in place",
        "a/DET man/NOUN stand/VERB still/ADV then/ADV run/VERB in/ADP place/NOUN",
        ("stand", "run"),
        ("a person stands still", "a person runs in place"),
    ),
    (
        "before sitting down, a person walks in a circle",
        "before/ADP sit/VERB down/ADP a/DET person/NOUN walk/VERB in/ADP a/DET circle/NOUN",
        ("walk", "sit"),
        ("a person walks in a circle", "a person sits down"),
    ),
    (
        "a person walks forward and after that sits down",
        "a/DET person/NOUN walk/VERB forward/ADV and/CCONJ after/ADP that/PRON sit/VERB down/ADP",
        ("walk", "sit"),
        ("a person walks forward", "a person sits down"),
    ),
    (
        "a person walks forward, turns around, and walks back to where they started",
        "a/DET person/NOUN walk/VERB forward/ADV turn/VERB around/ADV and/CCONJ walk/VERB back/ADV "
        "to/ADP where/SCONJ they/PRON start/VERB",
        ("walk", "turn", "walk"),
        ("a person walks forward", "a person turns around", "a person walks back to where they started"),
    ),
    (
        "a person stretches and then bends over",
        "a/DET person/NOUN stretch/VERB and/CCONJ then/ADV bend/VERB over/ADP",
        ("stretch", "bend"),
        ("a person stretches", "a person bends over"),
    ),
    (
        "a person is in a fighting position and avoids a punch",
        "a/DET person/NOUN is/AUX in/ADP a/DET fight/VERB position/NOUN and/CCONJ avoid/VERB a/DET punch/NOUN",
        ("be", "avoid"),
        ("a person is in a fighting position", "a person avoids a punch"),
    ),
    (
        "a person walks a quarter circle, taking four steps",
        "a/DET person/NOUN walk/VERB a/DET quarter/NOUN circle/NOUN take/VERB four/NUM step/NOUN",
        ("walk",),
        ("a person walks a quarter circle, taking four steps",),
    ),
    (
        "a man keeps on walking",
        "a/DET man/NOUN keep/VERB on/ADP walk/VERB",
        ("walk",),
        ("a person walks",),
    ),
]

# ------------------------------------------------------------------ synthetic tagged training set
# Verb phrases in the table's vocabulary, recombined with other subjects, connectives and forms.
# A token spec is "surface/POS", or "surface:word/POS" when HumanML3D writes the lemma.

VERBS: dict[str, tuple[str, str]] = {  # lemma: (3rd person singular, gerund)
    "walk": ("walks", "walking"),
    "turn": ("turns", "turning"),
    "jump": ("jumps", "jumping"),
    "pick": ("picks", "picking"),
    "put": ("puts", "putting"),
    "wave": ("waves", "waving"),
    "sit": ("sits", "sitting"),
    "kneel": ("kneels", "kneeling"),
    "stop": ("stops", "stopping"),
    "run": ("runs", "running"),
    "dance": ("dances", "dancing"),
    "step": ("steps", "stepping"),
    "kick": ("kicks", "kicking"),
    "punch": ("punches", "punching"),
    "raise": ("raises", "raising"),
    "clap": ("claps", "clapping"),
    "crouch": ("crouches", "crouching"),
    "throw": ("throws", "throwing"),
    "carry": ("carries", "carrying"),
    "go": ("goes", "going"),
    "wash": ("washes", "washing"),
    "stand": ("stands", "standing"),
    "spin": ("spins", "spinning"),
    "land": ("lands", "landing"),
    "push": ("pushes", "pushing"),
    "fall": ("falls", "falling"),
    "move": ("moves", "moving"),
    "swing": ("swings", "swinging"),
    "stretch": ("stretches", "stretching"),
    "bend": ("bends", "bending"),
    "lift": ("lifts", "lifting"),
    "climb": ("climbs", "climbing"),
    "squat": ("squats", "squatting"),
    "hop": ("hops", "hopping"),
    "jog": ("jogs", "jogging"),
    "reach": ("reaches", "reaching"),
    "catch": ("catches", "catching"),
    "bow": ("bows", "bowing"),
    "do": ("does", "doing"),
}
TAILS: dict[str, list[str]] = {
    "walk": [
        "forward/ADV",
        "in/ADP a/DET circle/NOUN",
        "backwards/ADV",
        "back/ADV",
        "over/ADV",
        "counter-clockwise:counterclockwise/ADV",
        "slowly/ADV",
        "with/ADP his/DET arms:arm/NOUN raised:raise/VERB",
        "up/ADP the/DET stairs:stair/NOUN",
        "back/ADV to/ADP where/SCONJ he/PRON started:start/VERB",
    ],
    "turn": ["around/ADV", "left/ADV", "right/ADV", "to/ADP the/DET left/NOUN"],
    "jump": [
        "",
        "up/ADV",
        "twice/ADV",
        "forward/ADV",
        "over/ADP an/DET obstacle/NOUN",
        "up/ADV high/ADV",
        "in/ADP place/NOUN",
    ],
    "pick": ["something/PRON up/ADP", "up/ADP a/DET box/NOUN", "it/PRON up/ADP", "up/ADP an/DET object/NOUN"],
    "put": [
        "it/PRON down/ADP",
        "it/PRON on/ADP a/DET table/NOUN",
        "something/PRON down/ADP",
        "the/DET box/NOUN down/ADP",
    ],
    "wave": ["", "with/ADP his/DET right/ADJ hand/NOUN", "their/DET hand/NOUN", "both/DET arms:arm/NOUN"],
    "sit": ["down/ADP", "down/ADP on/ADP a/DET chair/NOUN", "on/ADP the/DET ground/NOUN"],
    "kneel": ["down/ADP", "down/ADP on/ADP one/NUM knee/NOUN", "on/ADP the/DET floor/NOUN"],
    "stop": [""],
    "run": ["", "forward/ADV", "in/ADP place/NOUN", "in/ADP a/DET circle/NOUN"],
    "dance": ["", "happily/ADV", "in/ADP place/NOUN"],
    "step": ["forward/ADV", "left/VERB", "sideways/ADV", "back/ADV", "to/ADP the/DET side/NOUN"],
    "kick": [
        "with/ADP his/DET left/ADJ leg/NOUN",
        "with/ADP their/DET left/ADJ foot/NOUN",
        "a/DET ball/NOUN",
        "forward/ADV",
    ],
    "punch": ["with/ADP his/DET right/ADJ hand/NOUN", "forward/ADV", "twice/ADV"],
    "raise": [
        "both/DET arms:arm/NOUN above/ADP their/DET head/NOUN",
        "his/DET left/ADJ arm/NOUN",
        "their/DET arms:arm/NOUN",
    ],
    "clap": ["", "twice/ADV", "their/DET hands:hand/NOUN"],
    "crouch": ["down/ADP", ""],
    "throw": ["a/DET ball/NOUN with/ADP his/DET right/ADJ hand/NOUN", "something/PRON", "a/DET ball/NOUN"],
    "carry": ["a/DET box/NOUN", "something/PRON heavy/ADJ"],
    "go": ["up/ADP the/DET stairs:stair/NOUN", "back/ADV to/ADP their/DET original/ADJ stance/NOUN", "forward/ADV"],
    "wash": ["their/DET hands:hand/NOUN", "his/DET face/NOUN"],
    "stand": ["still/ADV", "up/ADP", "on/ADP one/NUM leg/NOUN"],
    "spin": ["", "around/ADV"],
    "land": ["", "on/ADP both/DET feet:foot/NOUN"],
    "push": ["backwards/ADV", "something/PRON"],
    "fall": ["down/ADP", "", "backwards/ADV"],
    "move": ["", "forward/ADV"],
    "swing": ["back/ADV and/CCONJ forth/ADV", "his/DET arms:arm/NOUN"],
    "stretch": ["", "his/DET arms:arm/NOUN"],
    "bend": ["over/ADP", "down/ADP", "his/DET knees:knee/NOUN"],
    "lift": ["a/DET box/NOUN", "his/DET right/ADJ leg/NOUN"],
    "climb": ["up/ADP a/DET ladder/NOUN", "over/ADP something/PRON"],
    "squat": ["down/ADP", ""],
    "hop": ["on/ADP one/NUM foot/NOUN", "forward/ADV"],
    "jog": ["forward/ADV", "in/ADP place/NOUN"],
    "reach": ["forward/ADV", "up/ADP"],
    "catch": ["a/DET ball/NOUN", "something/PRON"],
    "bow": ["", "down/ADP"],
    "do": ["jumping:jump/VERB jacks:jack/NOUN", "some/DET stretching:stretch/VERB", "a/DET cartwheel/NOUN"],
}
BODY_PARTS = ["arms:arm/NOUN", "legs:leg/NOUN", "hands:hand/NOUN"]
STATES = [
    "on/ADP all/DET fours:four/NOUN",
    "in/ADP a/DET t-pose:tpose/NOUN",
    "on/ADP the/DET ground/NOUN",
    "in/ADP a/DET crouch/NOUN",
]
PARTICIPLES = {"push": "pushed", "lift": "lifted", "throw": "thrown", "carry": "carried"}
SUBJECTS = [
    "a/DET person/NOUN",
    "a/DET man/NOUN",
    "the/DET man/NOUN",
    "someone/PRON",
    "a/DET figure/NOUN",
    "the/DET person/NOUN",
    "a/DET woman/NOUN",
    "he/PRON",
    "the/DET standing:stand/VERB person/NOUN",
]
CONNECTIVES = [
    "and/CCONJ",
    "and/CCONJ then/ADV",
    ",/ then/ADV",
    "then/ADV",
    ",/",
    "while/SCONJ",
    "after/ADP",
    "before/ADP",
    "and/CCONJ after/ADP that/PRON",
]

Piece = tuple[str, str, str]  # surface, HumanML3D word, POS ("" for punctuation)


def _pieces(spec: str) -> list[Piece]:
    out = []
    for token in spec.split():
        text, _, pos = token.rpartition("/")
        surface, _, word = text.partition(":")
        out.append((surface, word or surface, pos))
    return out


def _verb_phrase(rng: random.Random, form: str, lemma: str | None = None) -> list[Piece]:
    lemma = lemma or rng.choice(sorted(VERBS))
    surface = {"3rd": VERBS[lemma][0], "ing": VERBS[lemma][1], "base": lemma}[form]
    return [(surface, lemma, "VERB"), *_pieces(rng.choice(TAILS[lemma]))]


def _caption(rng: random.Random) -> list[Piece]:
    pieces = _clauses(rng)
    return pieces + _pieces("./") if rng.random() < 0.3 else pieces


def _clauses(rng: random.Random) -> list[Piece]:
    subject = _pieces(rng.choice(SUBJECTS))
    first = _verb_phrase(rng, "3rd")
    kind = rng.randrange(11)
    if kind == 10:
        return subject + _pieces(rng.choice(["is/AUX ", ""]) + rng.choice(STATES))
    if kind == 9:
        verb = rng.choice(sorted(PARTICIPLES))
        passive = [(PARTICIPLES[verb], verb, "VERB"), *_pieces(rng.choice(TAILS[verb]))]
        return subject + _pieces("is/AUX") + passive + _pieces("and/CCONJ") + first
    if kind == 8:
        owner = rng.choice(["a/DET person/NOUN 's/", "the/DET man/NOUN 's/", "his/DET"])
        verb = rng.choice(["swing", "move", "wave", "stretch"])
        return _pieces(f"{owner} {rng.choice(BODY_PARTS)}") + _verb_phrase(rng, "base", verb)
    if kind == 0:
        return subject + first
    if kind == 1:
        connective = rng.choice(CONNECTIVES)
        form = "ing" if connective.split("/")[0] in ("while", "after", "before") else "3rd"
        return subject + first + _pieces(connective) + _verb_phrase(rng, form)
    if kind == 2:
        return (
            subject
            + first
            + _pieces(",/")
            + _verb_phrase(rng, "3rd")
            + _pieces(",/ and/CCONJ")
            + _verb_phrase(rng, "3rd")
        )
    if kind == 3:
        return subject + _pieces("is/AUX") + _verb_phrase(rng, "ing")
    if kind == 4:
        lead = _pieces(rng.choice(["", "before/ADP", "after/ADP", "while/SCONJ"]))
        return lead + _verb_phrase(rng, "ing") + _pieces(",/") + subject + first
    if kind == 5:
        lead = rng.choice(
            [
                "starts:start/VERB to/PART",
                "begins:begin/VERB to/PART",
                "appears:appear/VERB to/PART be/AUX",
                "goes:go/VERB to/PART",
            ]
        )
        form = "ing" if lead.endswith("AUX") else "base"
        return subject + _pieces(lead) + _verb_phrase(rng, form)
    if kind == 6:
        lead = rng.choice(["begins:begin/VERB", "keeps:keep/VERB", "stops:stop/VERB"])
        return subject + _pieces(lead) + _verb_phrase(rng, "ing") + _pieces("and/CCONJ") + first
    lead = rng.choice(["slowly/ADV", "quickly/ADV", "does/AUX not/PART"])
    return subject + _pieces(lead) + _verb_phrase(rng, "base" if "not" in lead else "3rd")


def _render_caption(pieces: list[Piece]) -> str:
    return "".join(("" if s in (",", ".", "'s") or not i else " ") + s for i, (s, _, _) in enumerate(pieces))


def synthetic_corpus(n: int, seed: int) -> list[tuple[str, list[tuple[str, str]]]]:
    """``n`` HumanML3D-style (caption, tagged words) pairs built from the phrase inventory."""
    rng = random.Random(seed)
    corpus = []
    for _ in range(n):
        pieces = _caption(rng)
        tagged = [(w.replace("-", ""), p) for s, w, p in pieces if p]
        corpus.append((_render_caption(pieces), tagged))
    return corpus


# -------------------------------------------------------------------------------------- fixtures


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> tuple[Tagger, Path]:
    """A tagger trained on 600 synthetic captions (a few seconds), and where it was saved."""
    out = tmp_path_factory.mktemp("nlp")
    return train_tagger(synthetic_corpus(600, seed=0), out, seed=0), out


# ----------------------------------------------------------------------------------------- rules


@pytest.mark.parametrize(("caption", "field", "verbs", "actions"), TABLE, ids=[r[0] for r in TABLE])
def test_table_from_corpus_tags(caption: str, field: str, verbs: tuple[str, ...], actions: tuple[str, ...]) -> None:
    assert decompose(caption, parse_tagged_tokens(field)) == Decomposition(actions, verbs)


def test_table_from_trained_tagger(trained: tuple[Tagger, Path]) -> None:
    tagger, _ = trained
    misses = []
    for caption, _, verbs, actions in TABLE:
        got = decompose(caption, tagger=tagger)
        if got != Decomposition(actions, verbs):
            misses.append(f"{caption!r}: {got} tagged {tagger.tag(caption)}")
    accuracy = 1 - len(misses) / len(TABLE)
    print(f"trained tagger: {accuracy:.1%} of {len(TABLE)} table captions exactly right", *misses)
    assert accuracy >= 0.9, "\n".join(misses)


def test_misaligned_tags_fall_back_to_the_tagged_words() -> None:
    # The tags describe a longer caption than the text: the tagged words are used as they are.
    tags = parse_tagged_tokens("a/DET person/NOUN walk/VERB forward/ADV and/CCONJ sit/VERB")
    assert decompose("a person walks forward", tags) == Decomposition(
        ("a person walks forward", "a person sits"), ("walk", "sit")
    )


def test_caption_without_tags_is_kept() -> None:
    expected = Decomposition(("a person in a t-pose",), ())
    assert decompose("  A  person in a T-pose. ", []) == expected


def test_decompose_needs_a_caption_and_tags_or_a_tagger() -> None:
    with pytest.raises(ValueError, match="tagged tokens or a Tagger"):
        decompose("a person walks")
    with pytest.raises(ValueError, match="empty caption"):
        decompose("   ", [])


@pytest.mark.parametrize(
    ("lemma", "expected"),
    [
        ("walk", "walks"),
        ("go", "goes"),
        ("carry", "carries"),
        ("do", "does"),
        ("be", "is"),
        ("have", "has"),
        ("wash", "washes"),
        ("catch", "catches"),
        ("fix", "fixes"),
        ("waltz", "waltzes"),
        ("toss", "tosses"),
        ("play", "plays"),
        ("fly", "flies"),
        ("echo", "echoes"),
        ("tiptoe", "tiptoes"),
        ("stay", "stays"),
        ("Stretch", "stretches"),
        ("bounce", "bounces"),
        ("look", "looks"),
        ("perfom", "perfoms"),  # a verb lemminflect does not know: its rules
    ],
)
def test_inflect_third_person(lemma: str, expected: str) -> None:
    assert inflect_third_person(lemma) == expected


def test_inflect_rejects_empty() -> None:
    with pytest.raises(ValueError):
        inflect_third_person(" ")


def test_parse_tagged_tokens() -> None:
    assert parse_tagged_tokens("a/DET person/NOUN walk/VERB") == [("a", "DET"), ("person", "NOUN"), ("walk", "VERB")]
    assert parse_tagged_tokens("") == []
    assert parse_tagged_tokens("  ") == []


@pytest.mark.parametrize("field", ["a/DET person", "a/det", "/NOUN", "walk/", "walk/VERBS"])
def test_parse_tagged_tokens_rejects_malformed(field: str) -> None:
    with pytest.raises(ValueError, match="malformed tagged token"):
        parse_tagged_tokens(field)


# ---------------------------------------------------------------------------------------- tagger


def test_tag_many_matches_tag(trained: tuple[Tagger, Path]) -> None:
    tagger, _ = trained
    captions = [caption for caption, *_ in TABLE[:8]]
    assert tagger.tag_many(captions, batch_size=3) == [tagger.tag(c) for c in captions]
    assert all(len(triple) == 3 for triple in tagger.tag(captions[0]))


def test_saved_tagger_round_trip(trained: tuple[Tagger, Path], monkeypatch: pytest.MonkeyPatch) -> None:
    tagger, out = trained
    monkeypatch.setattr(language.spacy.util, "is_package", lambda name: False)
    loaded = load_tagger(out)
    captions = [caption for caption, *_ in TABLE]
    assert loaded.tag_many(captions) == tagger.tag_many(captions)
    assert loaded.nlp.meta["m2d2m"]["trained_on"] == 600


def test_saved_tagger_loads_with_spacy_alone(trained: tuple[Tagger, Path]) -> None:
    """No project code, no spacy-lookups-data, no network: what a fresh install has."""
    tagger, out = trained
    script = (
        "import sys, json; sys.modules['spacy_lookups_data'] = None; import spacy; "
        f"nlp = spacy.load({str(out)!r}); "
        "print(json.dumps([t.pos_ for t in nlp('a person walks forward and then sits down')]))"
    )
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True, timeout=120)
    expected = [pos for _, _, pos in tagger.tag("a person walks forward and then sits down")]
    assert result.stdout.strip() == str(expected).replace("'", '"')


def test_load_tagger_prefers_installed_small_model(monkeypatch: pytest.MonkeyPatch) -> None:
    loaded: list[str] = []
    monkeypatch.setattr(language.spacy.util, "is_package", lambda name: name == "en_core_web_sm")
    monkeypatch.setattr(language.spacy, "load", lambda name, **_: loaded.append(name) or language.spacy.blank("en"))
    load_tagger("ignored")
    assert loaded == ["en_core_web_sm"]


def test_load_tagger_without_any_pipeline_says_what_to_do(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(language.spacy.util, "is_package", lambda name: False)
    with pytest.raises(FileNotFoundError, match="m2d2m data"):
        load_tagger(tmp_path / "missing")
    with pytest.raises(FileNotFoundError, match="m2d2m data"):
        load_tagger()


def test_training_is_deterministic(tmp_path: Path) -> None:
    corpus = synthetic_corpus(120, seed=1)

    def weights(seed: int, name: str) -> bytes:
        tagger = train_tagger(corpus, tmp_path / name, seed=seed, epochs=2)
        return b"".join(tagger.nlp.get_pipe(p).model.to_bytes() for p in tagger.nlp.pipe_names)

    first = weights(0, "a")
    assert weights(0, "b") == first
    assert weights(1, "c") != first


def test_training_needs_aligned_captions(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="nothing to train"):
        train_tagger([("a person walks", [("walk", "VERB")])], tmp_path)
