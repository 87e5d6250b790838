"""Verb decomposition of captions into action sentences (M2D2M's action-sentence conditioning).

M2D2M conditions its denoiser on *action sentences*: a caption is split at its action verbs and each
piece is rewritten with a neutral subject ("a person walks forward and then sits down" ->
"a person walks forward", "a person sits down"). The same function serves the dataset pipeline,
where HumanML3D / KIT-ML ship spaCy ``en_core_web_sm`` tags with every caption
(``caption#word/UPOS ...#start#end``, EricGuo5513/HumanML3D, ``HumanML3D/texts``; docs/data.md), and free-text prompts at
generation time, where a :class:`Tagger` supplies the tags: ``en_core_web_sm`` when it is
installed, otherwise a small spaCy pipeline trained here on the corpus's own tagged captions.

No dependency parse is available (the trained pipeline only tags and lemmatises), so clauses are
found with part-of-speech rules. What counts as an action verb:

* every ``VERB`` token, except
* catenative / aspectual verbs followed by another verb ("starts to walk", "begins walking",
  "keeps walking", "keeps on walking", "tries to", "goes to sit", "appears to be walking"): the
  action is the second verb, the first is dropped;
* "appear" and "seem" (never actions; "a person seems happy" has no action verb);
* a verb used as a noun modifier or object: after a determiner, possessive, adjective or number
  ("the standing person", "does some stretching"), after "do"/"perform"/"make"
  ("does jumping jacks"), the gerund after "stop"/"finish" ("stops walking"), and a verb right
  after the noun of a with-phrase ("walks with his arms raised");
* a verb in a relative clause ("walks back to where he started", "the man who is walking");
* a verb that happens *with* the one before it: one opening a "while" / "as" / "during" clause
  ("walks in a circle while waving" is one action), and a participle that says how the action
  before it is done ("walks a quarter circle, taking four steps"), unless and/then/a list joins
  them ("is walking, jumping, and then walks");
* direction words that taggers mislabel as verbs ("left", "right", "back", "up", "still").

``AUX`` tokens are never actions: "is walking" -> "a person walks", "is pushed" and "gets pushed"
-> "a person is pushed" (passive kept), "does not move" -> "a person does not move". A state
clause among actions is one ("is in a fighting position and avoids a punch" -> "a person is in a
fighting position", "a person avoids a punch"). A caption with no action verb gives one action:
the caption itself, its leading subject replaced by the neutral one when it has a recognisable
one. A clause introduced by "after" ("sits down after walking") is moved before the clause it
follows, and a leading "before" clause after the one that follows it, so that the actions are in
temporal order.

Tags from a :class:`Tagger` are checked word by word against the English lexicon of lemminflect
(bjascob/LemmInflect, MIT) before the rules run (:func:`_lexical_check`): a tagger trained on a
few template captions guesses at every word it never saw, and calls "steps" in "a few steps" or
"180" a verb. Inflection ("bounces", "looks") is lemminflect's too. A prompt that is mostly not
English is kept whole, one action, rather than split into franglais. :func:`same_split` scores a
split against a labelled one (``tests/fixtures/real-captions``, docs/data.md).
"""

from __future__ import annotations

import random
import re
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import lru_cache
from itertools import pairwise
from pathlib import Path
from typing import NamedTuple

import spacy
from lemminflect import getAllInflections, getAllLemmas, getAllLemmasOOV, getInflection
from spacy.lang.en.lex_attrs import like_num
from spacy.language import Language
from spacy.tokens import Doc
from spacy.training import Example
from spacy.util import fix_random_seed, minibatch

NEUTRAL_SUBJECT = "a person"
SMALL_MODEL = "en_core_web_sm"
LEMMA_TABLE = "m2d2m_corpus_lemmas"  # "<UPOS> <surface>" -> the corpus's lemma, in the saved vocab

UPOS_TAGS = frozenset(
    {"ADJ", "ADP", "ADV", "AUX", "CCONJ", "DET", "INTJ", "NOUN", "NUM", "PART", "PRON", "PROPN"}
    | {"PUNCT", "SCONJ", "SYM", "VERB", "X"}
)
_LEMMATISED_POS = ("NOUN", "VERB")  # HumanML3D writes these as lemmas (except the word "left")

# Verbs whose action is the verb that follows them.
_CATENATIVE = frozenset(
    {"start", "begin", "continue", "proceed", "keep", "resume", "go", "try", "attempt"}
    | {"prepare", "appear", "seem", "tend", "manage"}
)
_STATIVE = frozenset({"appear", "seem"})
LIGHT_VERBS = frozenset({"do", "perform", "make"})  # "does jumping jacks": the gerund is the object
_STOP = frozenset({"stop", "finish", "quit", "cease"})  # "stops walking": one action, "stop"
# Words whose verb reading captions never use ("turns left", "steps back", "stands still").
_NEVER_VERBS = frozenset({"left", "right", "up", "down", "back", "forward", "forwards", "over", "still", "front"})
_POSSESSIVES = frozenset({"his", "her", "their", "its", "my", "your", "our"})
_MODIFIER_BEFORE = frozenset({"DET", "ADJ", "NUM"})

_SEPARATOR_PUNCT = frozenset(",;.:!?")
_SEQUENCE_ADVERBS = frozenset(
    {"then", "afterwards", "afterward", "finally", "next", "later", "subsequently", "eventually"}
    | {"first", "firstly", "lastly", "also"}
)
_ORDER_WORDS = frozenset({"before", "after", "until", "till", "when", "while", "as"})
_SIMULTANEOUS = frozenset({"while", "whilst", "during", "as"})  # what they open happens at the same time
_ANAPHORS = frozenset({"that", "this", "which"})  # "after that" is a plain sequence marker
_RELATIVES = frozenset({"where", "who", "which", "whom", "whose", "what"})
_NEGATIONS = frozenset({"not", "n't"})
# Verbs that need a particle or an object to say a movement ("gets up", "puts down", "takes a step").
_PARTICLE_VERBS = frozenset({"get", "put", "take", "have", "be", "let", "give", "set", "bring", "show", "use", "come"})
_PASSIVE_AUX = frozenset({"is", "are", "was", "were", "be", "been", "being", "get", "gets", "got", "getting"})
_NP_POS = frozenset({"DET", "NOUN", "PROPN", "PRON", "ADJ", "NUM"})
_SUBJECTS = frozenset(
    {"person", "man", "woman", "figure", "human", "someone", "somebody", "guy", "boy", "girl"}
    | {"individual", "character", "he", "she", "they", "people", "child", "kid", "lady"}
    | {"gentleman", "male", "female", "adult", "dancer", "player", "athlete", "actor", "subject"}
    | {"stickman"}
)
_GET = frozenset({"get", "gets", "got", "gotten", "getting"})  # "gets pushed": a passive auxiliary
_BE = frozenset({"is", "are", "was", "were"})

# Function words, a closed class that lemminflect's open-class lexicon leaves out, with the tag
# en_core_web_sm gives them in captions (possessives DET, as HumanML3D's tags have them).
_FUNCTION_WORDS: dict[str, str] = {
    **dict.fromkeys(
        "a an the this these those some any each every both all another several either neither no".split(), "DET"
    ),
    **dict.fromkeys(sorted(_POSSESSIVES), "DET"),
    **dict.fromkeys(
        "that he she it they him them himself herself itself themselves someone somebody something anyone anybody "
        "anything everyone everybody everything nobody nothing who whom whose which what".split(),
        "PRON",
    ),
    **dict.fromkeys(
        "in on at to from with without by of for into onto towards toward through across along behind above below "
        "beneath beside besides between near during like against off under upon via per".split(),
        "ADP",
    ),
    **dict.fromkeys("and or but nor".split(), "CCONJ"),
    **dict.fromkeys(
        "while whilst after before until till when as if because since so than though although where".split(), "SCONJ"
    ),
    **dict.fromkeys(sorted(_NEGATIONS), "PART"),
    "'s": "X",  # the possessive, as the corpus path tags it
    **dict.fromkeys("is are was were be been being am".split(), "AUX"),
}
_NO_SPACE_BEFORE = re.compile(r"^(?:[,;.:!?)\]]|'|n't$)")


@dataclass(frozen=True)
class Decomposition:
    """A caption's action sentences in temporal order, and the lemmas of their verbs.

    ``verbs[i]`` is the verb of ``actions[i]``; a caption without an action verb has one action
    and no verbs (so ``len(verbs) == 1`` selects M2D2M's single-action captions).
    """

    actions: tuple[str, ...]
    verbs: tuple[str, ...]


class _Tok(NamedTuple):
    text: str  # surface form, lower case, hyphens kept
    lemma: str
    pos: str
    space: bool  # preceded by whitespace


# ----------------------------------------------------------------------------------------- tags


def parse_tagged_tokens(field: str) -> list[tuple[str, str]]:
    """The (word, UPOS) pairs of a HumanML3D token field ``"a/DET person/NOUN ..."``.

    An empty field gives ``[]``; a token that is not ``word/UPOS`` raises ``ValueError``, so the
    data pipeline can quarantine the line instead of decomposing garbage.
    """
    pairs = []
    for token in field.split():
        word, slash, pos = token.rpartition("/")
        if not slash or not word or pos not in UPOS_TAGS:
            raise ValueError(
                f"malformed tagged token {token!r} in {field!r}: expected word/UPOS with UPOS one "
                f"of {' '.join(sorted(UPOS_TAGS))}"
            )
        pairs.append((word, pos))
    return pairs


def inflect_third_person(lemma: str) -> str:
    """3rd person singular present of a verb lemma ("carry" -> "carries"), for action sentences.

    lemminflect's lexicon, and for a verb it does not know (a typo, a coinage) its inflection
    rules, so "perfom" stays "perfoms" rather than failing.
    """
    verb = lemma.strip().lower()
    if not verb:
        raise ValueError("cannot inflect an empty verb")
    return getInflection(verb, "VBZ", inflect_oov=True)[0]


def action_verbs(verbs: Iterable[str]) -> list[str]:
    """The ``verbs`` (a model's, of its single-action captions) that name an action alone, sorted:
    what a model can be asked for by name ("a person jumps"). Not a light verb ("do": its action
    is its object), nor one whose action is the verb after it ("start", "go"), nor one that needs
    a particle or an object ("get" up, "put" down), nor a word taggers mislabel as a verb ("back")."""
    stop = LIGHT_VERBS | _CATENATIVE | _STATIVE | _PARTICLE_VERBS | _NEVER_VERBS
    return sorted(verb for verb in set(verbs) if verb not in stop)


@lru_cache(maxsize=1)
def _tokenizer() -> spacy.tokenizer.Tokenizer:
    """spaCy's English rule tokenizer: the same rules as en_core_web_sm, no model needed."""
    return spacy.blank("en").tokenizer


def _normalise(caption: str) -> tuple[str, list[int]]:
    """The caption as HumanML3D tagged it (lower case, '-' removed, whitespace collapsed), and for
    each of its characters the index in ``caption.lower()``, to recover surfaces with hyphens."""
    chars: list[str] = []
    index: list[int] = []
    for i, ch in enumerate(caption.lower()):
        if ch == "-" or (ch.isspace() and (not chars or chars[-1] == " ")):
            continue
        chars.append(" " if ch.isspace() else ch)
        index.append(i)
    if chars and chars[-1] == " ":
        chars.pop()
        index.pop()
    return "".join(chars), index


def _spans(text: str, words: Sequence[str]) -> list[tuple[int, int]] | None:
    """Character spans of consecutive ``words`` in ``text``, or None if they are not in order."""
    spans, at = [], 0
    for word in words:
        start = text.find(word, at)
        if start < 0 or text[at:start].strip():
            return None
        spans.append((start, start + len(word)))
        at = start + len(word)
    return spans


def _surface_tokens(caption: str, words: Sequence[str]) -> list[tuple[str, bool]] | None:
    """(surface, preceded-by-space) for tokens ``words`` of the normalised caption."""
    norm, index = _normalise(caption)
    spans = _spans(norm, words)
    if spans is None:
        return None
    lowered = caption.lower()
    return [(lowered[index[a] : index[b - 1] + 1], a > 0 and norm[a - 1] == " ") for a, b in spans]


def _align(norm: str, tagged: Sequence[tuple[str, str]]) -> list[_Tok] | None:
    """Every spaCy token of the normalised caption with its lemma and UPOS from HumanML3D tags.

    HumanML3D kept only alphabetic tokens, so these must match the tags one to one, and every
    word that was not lemmatised must equal its token; other tokens become NUM / PUNCT / X.
    Returns None when the caption and its tags do not line up.
    """
    tokens = list(_tokenizer()(norm))
    alpha = [t for t in tokens if t.text.isalpha()]
    if len(alpha) != len(tagged):
        return None
    tags = {}
    for token, (word, pos) in zip(alpha, tagged, strict=True):
        word = word.lower()
        lemmatised = pos in _LEMMATISED_POS and word != "left"
        if not lemmatised and word != token.text:
            return None
        tags[token.i] = (word if lemmatised else token.text, pos)
    out = []
    for t in tokens:
        lemma, pos = tags.get(t.i) or (
            t.text,
            "NUM" if t.like_num else "PUNCT" if t.is_punct else "X",
        )
        out.append(_Tok(t.text, lemma, pos, t.idx > 0 and norm[t.idx - 1] == " "))
    return out


def _tokens_from_tags(caption: str, tagged: Sequence[tuple[str, str]]) -> list[_Tok]:
    """Tokens with the corpus tags, surfaces taken from the caption when the two align (else the
    tagged words themselves, lemmas included)."""
    aligned = _align(_normalise(caption)[0], tagged)
    if aligned is not None:
        surfaces = _surface_tokens(caption, [t.text for t in aligned])
        if surfaces is not None:
            return [t._replace(text=s, space=sp) for t, (s, sp) in zip(aligned, surfaces, strict=True)]
    return [_Tok(w.lower(), w.lower(), pos, i > 0) for i, (w, pos) in enumerate(tagged)]


def _tokens_from_tagger(caption: str, tagger: Tagger) -> list[_Tok]:
    """Tokens tagged by ``tagger`` and checked against the lexicon (:func:`_lexical_check`);
    surfaces (with hyphens) from the caption where possible."""
    norm, _ = _normalise(caption)
    tagged = tagger.tag(norm)
    surfaces = _surface_tokens(caption, [w for w, _, _ in tagged])
    if surfaces is None:
        surfaces = [(w.lower(), i > 0) for i, (w, _, _) in enumerate(tagged)]
    toks = [_Tok(s, lemma.lower(), pos, sp) for (s, sp), (_, lemma, pos) in zip(surfaces, tagged, strict=True)]
    return _lexical_check(toks)


# --------------------------------------------------------------------------------- lexical check


@lru_cache(maxsize=8192)
def _readings(word: str) -> dict[str, tuple[str, ...]]:
    """lemminflect's open-class readings of ``word``: UPOS -> lemmas; {} for a word it lacks."""
    return getAllLemmas(word)


def _verb_form(word: str, tag: str) -> bool:
    """Whether ``word`` is the ``tag`` form (Penn: VBZ, VBN) of one of its verb lemmas."""
    return any(word in getAllInflections(lemma, "VERB").get(tag, ()) for lemma in _readings(word).get("VERB", ()))


def _opens_clause(toks: Sequence[_Tok], i: int) -> bool:
    """Whether a clause can start right after ``toks[i]``: a separating punctuation mark, a
    conjunction, a sequence adverb, an ordering word or "after that" (not "/" or a bracket)."""
    tok = toks[i]
    return (
        tok.text in _SEPARATOR_PUNCT
        or tok.pos in ("CCONJ", "SCONJ")
        or tok.text in _SEQUENCE_ADVERBS
        or tok.text in _ORDER_WORDS
        or (tok.text in _ANAPHORS and i > 0 and toks[i - 1].text in ("after", "before"))
    )


def _noun_modifier(word: str) -> bool:
    """Whether ``word`` reads as a noun and not as a particle ("height", "level", not "up"): a
    word before it is then a noun too ("to shoulder height")."""
    return "NOUN" in _readings(word) and word not in _NEVER_VERBS and word not in _FUNCTION_WORDS


def _subject_before(left: Sequence[_Tok], end: int) -> bool:
    """Whether ``left[: end + 1]`` ends with a noun phrase that opens its clause: a subject
    ("a person", "then the man", "a person's arms"), not an object ("walks a few steps")."""

    def in_phrase(k: int) -> bool:  # "the standing person": a verb after a determiner modifies
        return left[k].pos in _NP_POS or left[k].text in ("'s", "'") or (k > 0 and left[k - 1].pos == "DET")

    j = end
    while j >= 0 and in_phrase(j):
        j -= 1
    return j < 0 or _opens_clause(left, j)


def _verb_slot(left: Sequence[_Tok], word: str, right: Sequence[_Tok]) -> bool:
    """Whether a verb can stand after the (checked) tokens ``left``: where a sentence or clause
    starts (imperatives, "and then turns"; not "elbows bent"), after a subject or an auxiliary, a
    gerund after a catenative ("keeps walking", not "the starting position"), after an infinitive
    "to" ("to pick", not "to shoulder height"), and, run on, after a verb and its adverbs ("walks
    forward turns around")."""
    after = right[0].text if right else ""
    j = len(left) - 1
    while j >= 0 and left[j].pos in ("ADV", "PART") and left[j].text not in _SEQUENCE_ADVERBS:
        j -= 1
    if j < 0 or _opens_clause(left, j):
        return not ("NOUN" in _readings(word) and after not in _NEVER_VERBS and _verb_form(after, "VBN"))
    prev = left[j]
    if prev.pos == "AUX":
        return True
    if prev.text == "to":
        catenative = j > 0 and left[j - 1].pos == "VERB" and left[j - 1].lemma in _CATENATIVE  # "tries to run fast"
        return word in _readings(word).get("VERB", (word,)) and (catenative or not _noun_modifier(after))
    if prev.pos == "VERB":
        gerund = prev.lemma in _CATENATIVE and _verb_form(word, "VBG") and not (j > 0 and left[j - 1].pos == "DET")
        return gerund or (j < len(left) - 1 and _verb_form(word, "VBZ"))
    participle = _verb_form(word, "VBN") and word not in _readings(word)["VERB"]  # "elbows bent"
    # a subject's noun ("a person walks a person walks", captions run on without punctuation) starts a
    # clause even after a verb, where another noun phrase would be its object ("walks a few steps")
    run_on = prev.text in _SUBJECTS and _verb_form(word, "VBZ")
    return prev.pos in ("NOUN", "PRON", "PROPN") and (_subject_before(left, j) or run_on) and not participle


def _checked(left: Sequence[_Tok], tok: _Tok, right: Sequence[_Tok]) -> _Tok:
    """``tok`` with the tag and lemma the lexicon allows after the checked tokens ``left``."""
    word = tok.text
    if _is_punct(tok):
        return tok._replace(pos="PUNCT", lemma=word)
    if any(ch.isdigit() for ch in word) or (like_num(word) and word not in _SEQUENCE_ADVERBS):
        return tok._replace(pos="NUM", lemma=word)
    if word in _GET and right and (right[0].text.endswith("ed") or _verb_form(right[0].text, "VBN")):
        return tok._replace(pos="AUX", lemma="get")
    if word in _FUNCTION_WORDS:
        pos = _FUNCTION_WORDS[word]
        return tok._replace(pos=pos, lemma=_readings(word).get(pos, (word,))[0])
    if word in _SUBJECTS:  # "Subject walks forward", "Person looks around"
        return tok._replace(pos="NOUN", lemma=word)
    readings = _readings(word)
    if not readings:  # a word neither knows (a typo): the tagger's guess, a verb only where one can stand
        if tok.pos != "VERB":
            return tok
        if not _verb_slot(left, word, right):
            return tok._replace(pos="NOUN", lemma=word)
        return tok if tok.lemma != word else tok._replace(lemma=getAllLemmasOOV(word, "VERB")["VERB"][0])
    if "AUX" in readings and right and right[0].text in _NEGATIONS:  # "does not move"
        return tok._replace(pos="AUX", lemma=readings["AUX"][0])
    others = [pos for pos in (tok.pos, "NOUN", "ADV", "ADJ", "PROPN", "AUX") if pos in readings and pos != "VERB"]
    if "VERB" in readings and word not in _NEVER_VERBS and (not others or _verb_slot(left, word, right)):
        return tok._replace(pos="VERB", lemma=readings["VERB"][0])
    if others:
        pos = others[0]
        return tok._replace(pos=pos, lemma=readings[pos][0] if pos in _LEMMATISED_POS else word)
    return tok


def _lexical_check(toks: Sequence[_Tok]) -> list[_Tok]:
    """The tagger's tags checked, left to right, against what each word can be.

    A tagger trained on template captions guesses at every word it never saw ("steps"/VERB in
    "a few steps", "180"/PRON, "waits" lemmatised as "waits"). So numbers are NUM, function words
    take their one tag, a "get" before a participle is the passive's auxiliary, and a word in
    lemminflect's lexicon takes one of its readings, with the lexicon's lemma: VERB only where a
    verb can stand (:func:`_verb_slot`) or when it has no other reading ("walking", "pushed").
    A word neither knows (a typo) keeps the tagger's guess.
    """
    out: list[_Tok] = []
    for i, tok in enumerate(toks):
        out.append(_checked(out, tok, toks[i + 1 :]))
    return out


# ---------------------------------------------------------------------------- decomposition rules


def _past_or_participle(tok: _Tok) -> bool:
    """A verb form that is neither base, 3rd person present nor gerund ("raised", "held")."""
    return tok.text not in (tok.lemma, inflect_third_person(tok.lemma)) and not tok.text.endswith("ing")


def _is_separator(toks: Sequence[_Tok], i: int, dropped: set[int]) -> bool:
    """Whether token ``i`` can end one clause and introduce the next: what opens a clause
    (:func:`_opens_clause`), or an infinitive "to" that is not a catenative's ("walks to sit")."""
    return _opens_clause(toks, i) or (toks[i].text == "to" and i not in dropped)


def _in_with_phrase(toks: Sequence[_Tok], i: int) -> bool:
    """Whether token ``i`` follows "with"/"without" with no verb or separator in between."""
    for j in range(i - 1, -1, -1):
        if toks[j].text in ("with", "without"):
            return True
        if toks[j].pos == "VERB" or toks[j].text in _SEPARATOR_PUNCT or toks[j].pos == "CCONJ":
            return False
    return False


def _in_relative_clause(toks: Sequence[_Tok], i: int) -> bool:
    """Whether token ``i`` follows a relative word ("to where he started", "the man who is
    walking") with only pronouns, auxiliaries and adverbs in between."""
    for j in range(i - 1, -1, -1):
        if toks[j].text in _RELATIVES:
            return True
        if toks[j].pos not in ("PRON", "AUX", "ADV", "PART"):
            return False
    return False


def _is_modifier(toks: Sequence[_Tok], i: int) -> bool:
    """Whether VERB token ``i`` modifies a noun, is an object or sits in a relative clause,
    rather than being an action."""
    if i == 0:
        return False
    prev = toks[i - 1]
    return (
        _in_relative_clause(toks, i)
        or prev.pos in _MODIFIER_BEFORE
        or prev.text in _POSSESSIVES
        or (prev.pos == "VERB" and prev.lemma in LIGHT_VERBS)
        or (prev.pos == "VERB" and prev.lemma in _STOP and toks[i].text.endswith("ing"))
        or (prev.pos in ("NOUN", "PRON", "PROPN") and _in_with_phrase(toks, i))
    )


def _find_actions(toks: Sequence[_Tok]) -> tuple[list[int], set[int]]:
    """Indices of the action verbs, and of the catenative words ("starts to", "keeps on") to drop."""
    candidates = [
        i for i, t in enumerate(toks) if t.pos == "VERB" and t.text not in _NEVER_VERBS and not _is_modifier(toks, i)
    ]
    verbs = set(candidates)
    dropped: set[int] = set()
    for i in candidates:
        if toks[i].lemma not in _CATENATIVE:
            continue
        j = i + 1
        has_to = j < len(toks) and toks[j].text == "to"
        has_on = j < len(toks) and toks[j].text == "on"  # "keeps on walking", "goes on walking"
        if has_to:
            j += 1
            while j < len(toks) and toks[j].pos == "ADV":
                j += 1
        if has_on:
            j += 1
        if j < len(toks) and toks[j].pos == "AUX" and toks[j].text in _PASSIVE_AUX:
            j += 1
        if j in verbs:
            dropped.update({i, i + 1} if has_to or has_on else {i})
    verbs_kept = [i for i in candidates if i not in dropped and toks[i].lemma not in _STATIVE]
    actions = [i for prev, i in zip([None, *verbs_kept], verbs_kept) if prev is None or not _accompanies(toks, prev, i)]
    if actions:
        actions = sorted(actions + [i for i in range(len(toks)) if _is_state_clause(toks, i, verbs)])
    return actions, dropped


def _accompanies(toks: Sequence[_Tok], prev: int, verb: int) -> bool:
    """Whether ``verb`` happens with the verb ``prev`` before it rather than after it: it opens a
    "while" / "as" / "during" clause, or it is a participle that says how the earlier action is
    done ("walks a quarter circle, taking four steps", "walks forward starting with the left
    foot"), not one of a list ("is walking 3 steps, jumping ..., and walks ...")."""
    between = toks[prev + 1 : verb]
    if any(t.text in _SIMULTANEOUS for t in between):
        return True
    marks = _SEQUENCE_ADVERBS | _ORDER_WORDS | (_SEPARATOR_PUNCT - {","})
    sequenced = any(t.pos == "CCONJ" or t.text in marks for t in between)
    listed = any(t.text == "," for t in between) and toks[prev].text.endswith("ing")
    return toks[verb].text.endswith("ing") and not sequenced and not listed


def _is_state_clause(toks: Sequence[_Tok], i: int, verbs: set[int]) -> bool:
    """Whether ``toks[i]`` is the "is" of a clause with no other verb ("is in a fighting position
    and avoids a punch"): the state is an action of its own among others."""
    if toks[i].pos != "AUX" or toks[i].text not in _BE or _in_relative_clause(toks, i):
        return False
    for j in range(i + 1, len(toks)):
        if j in verbs or toks[j].pos == "AUX":
            return False
        if _is_separator(toks, j, set()) and toks[j].text not in _SEQUENCE_ADVERBS:
            return j > i + 1
    return True


def _aux_then(toks: Sequence[_Tok], i: int) -> bool:
    """Whether ``toks[i]`` is a sequence adverb right after an auxiliary ("and is then shoved
    back"): the auxiliary stays with the verb after it."""
    return toks[i].text in _SEQUENCE_ADVERBS and i > 0 and toks[i - 1].pos == "AUX"


def _split(toks: Sequence[_Tok], prev_verb: int, verb: int, dropped: set[int]) -> int:
    """Where the clause of ``prev_verb`` ends: the separators, subject and pre-verbal words
    (adverbs, auxiliaries, catenatives) between the two verbs belong to the next clause."""

    def preverbal(i: int) -> bool:
        return toks[i].pos in ("ADV", "AUX", "PART") or i in dropped

    def joins_next(i: int) -> bool:
        return not _is_separator(toks, i, dropped) or (_aux_then(toks, i) and i - 1 > prev_verb)

    j = verb
    while j - 1 > prev_verb and preverbal(j - 1) and joins_next(j - 1):
        j -= 1
    while j - 1 > prev_verb and toks[j - 1].pos in _NP_POS and not _is_separator(toks, j - 1, dropped):
        j -= 1
    separators_end = j
    while j - 1 > prev_verb and _is_separator(toks, j - 1, dropped):
        j -= 1
    if j < separators_end:
        return j
    # A run-on ("walks forward turns around"): only auxiliaries go to the next clause, and a
    # subject of its own with its determiner ("walks forward a man turns around").
    j = verb
    while j - 1 > prev_verb and (toks[j - 1].pos in ("AUX", "PART") or j - 1 in dropped):
        j -= 1
    if j - 1 > prev_verb and toks[j - 1].text in _SUBJECTS:
        j -= 1
        while j - 1 > prev_verb and toks[j - 1].pos in ("DET", "ADJ"):
            j -= 1
    return j


def _render_words(toks: Sequence[_Tok]) -> str:
    """Tokens joined with the caption's spacing."""
    out = ""
    for t in toks:
        glue = t.space and out and not _NO_SPACE_BEFORE.match(t.text)
        out += (" " if glue else "") + t.text
    return out


def _is_punct(tok: _Tok) -> bool:
    """Punctuation by its text, since a tagger may mislabel a final period."""
    return not any(ch.isalnum() for ch in tok.text)


def _trim(toks: list[_Tok]) -> list[_Tok]:
    """Drop punctuation, conjunctions and sequence adverbs left at the end of a clause."""
    while toks and (_is_punct(toks[-1]) or toks[-1].pos in ("CCONJ", "SCONJ") or toks[-1].text in _SEQUENCE_ADVERBS):
        toks.pop()
    return toks


def _action_sentence(lead_in: Sequence[_Tok], verb: _Tok, rest: list[_Tok]) -> str:
    """ "a person <adverbs> <verb, 3rd person> <rest of the clause>"."""
    start = len(lead_in)  # the adverbs and auxiliaries right before the verb
    while start > 0 and lead_in[start - 1].pos in ("ADV", "AUX", "PART"):
        if lead_in[start - 1].text in _SEQUENCE_ADVERBS and not _aux_then(lead_in, start - 1):
            break
        start -= 1
    preverbal = lead_in[start:]
    adverbs = [t.text for t in preverbal if t.pos == "ADV" and t.text not in _NEGATIONS | _SEQUENCE_ADVERBS]
    negated = any(t.text in _NEGATIONS for t in preverbal)
    passive = _past_or_participle(verb) and any(t.pos == "AUX" and t.text in _PASSIVE_AUX for t in preverbal)
    if passive:
        verb_words = ["is not" if negated else "is", verb.text]
    elif negated:
        verb_words = ["does not", verb.lemma]
    else:
        verb_words = [inflect_third_person(verb.lemma)]
    tail = _render_words(_trim(rest))
    words = [NEUTRAL_SUBJECT, *adverbs, *verb_words]
    return " ".join(words) + ((" " if rest and rest[0].space else "") + tail if tail else "")


def _order_marker(toks: Sequence[_Tok], start: int, end: int) -> str | None:
    """ "after" / "before" when it introduces the clause in toks[start:end] (not "after that")."""
    for i in range(start, end):
        if toks[i].text in ("after", "before") and not (i + 1 < len(toks) and toks[i + 1].text in _ANAPHORS):
            return toks[i].text
    return None


def _neutral_subject(toks: Sequence[_Tok]) -> str:
    """The words themselves, a leading subject ("the man", "someone") made neutral."""
    toks = _trim(list(toks))
    for i, t in enumerate(toks):
        if t.text in _SUBJECTS and t.pos in ("NOUN", "PRON", "PROPN"):
            rest = toks[i + 1 :]
            tail = _render_words(rest)
            return NEUTRAL_SUBJECT + ((" " if rest[0].space else "") + tail if rest else "")
        if t.pos not in ("DET", "ADJ", "NUM"):
            break
    return _render_words(toks)


def _possessive_subject(lead_in: Sequence[_Tok]) -> bool:
    """Whether the subject is a body part ("a person's arms", "his legs"): then the caption's own
    words are kept, since "a person" cannot take its verb."""
    return any(t.text in ("'s", "'") for t in lead_in) or (bool(lead_in) and lead_in[0].text in _POSSESSIVES)


def _decompose_tokens(toks: Sequence[_Tok]) -> Decomposition:
    actions, dropped = _find_actions(toks)
    if not actions:
        return Decomposition(actions=(_neutral_subject(toks) or _render_words(toks),), verbs=())
    starts = [0, *(_split(toks, a, b, dropped) for a, b in pairwise(actions))]
    ends = [*starts[1:], len(toks)]
    sentences: list[tuple[str, str]] = []
    previous_at = 0
    for k, (verb, start, end) in enumerate(zip(actions, starts, ends, strict=True)):
        rest = [t for i, t in enumerate(toks[verb + 1 : end], verb + 1) if i not in dropped]
        head = toks[verb]._replace(lemma="be") if toks[verb].pos == "AUX" else toks[verb]  # a state clause's "is"
        if k == 0 and _possessive_subject(toks[:verb]):
            text = _neutral_subject(toks[:end])
        else:
            text = _action_sentence(toks[start:verb], head, rest)
        sentence = (text, head.lemma)
        marker = _order_marker(toks, start, verb)
        at = previous_at if k > 0 and marker == "after" else len(sentences)
        sentences.insert(at, sentence)
        previous_at = at
    if len(sentences) > 1 and _order_marker(toks, 0, actions[0]) == "before":
        sentences.insert(1, sentences.pop(0))
    return Decomposition(actions=tuple(s for s, _ in sentences), verbs=tuple(v for _, v in sentences))


def decompose(
    caption: str,
    tagged: Sequence[tuple[str, str]] | None = None,
    tagger: Tagger | None = None,
) -> Decomposition:
    """Split a caption at its action verbs into action sentences with a neutral subject.

    ``tagged`` are the corpus's (word, UPOS) pairs (:func:`parse_tagged_tokens`); without them
    ``tagger`` tags the caption (free-text prompts).
    """
    if not caption.strip():
        raise ValueError("cannot decompose an empty caption")
    if tagged is not None:
        toks = _tokens_from_tags(caption, tagged)
    elif tagger is not None:
        toks = _tokens_from_tagger(caption, tagger)
        if not _looks_english(toks):
            return _whole(caption)
    else:
        raise ValueError("decompose needs the caption's tagged tokens or a Tagger")
    if not toks:  # an empty tag field that cannot align: the caption as it is
        return _whole(caption)
    return _decompose_tokens(toks)


def _whole(caption: str) -> Decomposition:
    """The caption as it is, one action without a verb: what cannot be split."""
    return Decomposition(actions=(" ".join(caption.lower().split()).rstrip(".,;:!? "),), verbs=())


def _looks_english(toks: Sequence[_Tok]) -> bool:
    """Whether at least half the words are English ones (function words, subjects, lemminflect's
    lexicon). A prompt in another language is kept whole: split by English rules it would come
    out as franglais ("a person personnes marche")."""
    words = [t.text for t in toks if t.text.isalpha()]
    known = sum(w in _FUNCTION_WORDS or w in _SUBJECTS or bool(_readings(w)) for w in words)
    return 2 * known >= len(words)


# --------------------------------------------------------------------------------------- scoring

# Words a split may drop or change without changing what is done: articles, possessives and the
# sequence words that action sentences leave out.
_SCORE_IGNORED = (
    frozenset({"a", "an", "the", "and", "then", "first", "finally", "afterwards", "afterward"}) | _POSSESSIVES
)
_SCORE_WORD = re.compile(r"[a-z0-9]+(?:['-][a-z0-9]+)*")


def content_words(sentence: str) -> Counter[str]:
    """The words of an action sentence that a split must get right, with their counts: the verb
    as inflected (with the "is" of a passive) and everything else but case, punctuation and the
    ignored function words."""
    return Counter(w for w in _SCORE_WORD.findall(sentence.lower()) if w not in _SCORE_IGNORED)


def same_split(got: Decomposition, expected: Sequence[str]) -> bool:
    """Whether ``got`` is the labelled split ``expected``: as many actions, in the same order,
    each with the same content words (so the same verb, inflection and voice: "a person pushes"
    is not "a person is pushed")."""
    return len(got.actions) == len(expected) and all(
        content_words(action) == content_words(label) for action, label in zip(got.actions, expected, strict=True)
    )


# ---------------------------------------------------------------------------------------- tagger


class Tagger:
    """UPOS tags and lemmas for untagged text (prompts), from a spaCy pipeline.

    A pipeline trained by :func:`train_tagger` carries the corpus's own NOUN/VERB lemmas as a
    lookup table; they take precedence over the learnt lemmatizer, which serves unseen words.
    """

    def __init__(self, nlp: Language) -> None:
        self.nlp = nlp
        lookups = nlp.vocab.lookups
        self._lemmas = lookups.get_table(LEMMA_TABLE) if lookups.has_table(LEMMA_TABLE) else {}

    def _triples(self, doc: Doc) -> list[tuple[str, str, str]]:
        return [
            (
                t.text,
                self._lemmas.get(f"{t.pos_} {t.lower_}") or t.lemma_ or t.lower_,
                t.pos_ or "X",
            )
            for t in doc
            if not t.is_space
        ]

    def tag(self, text: str) -> list[tuple[str, str, str]]:
        """(surface, lemma, UPOS) for each token of ``text``."""
        return self._triples(self.nlp(text))

    def tag_many(self, texts: Iterable[str], batch_size: int = 256) -> list[list[tuple[str, str, str]]]:
        """:meth:`tag` for many texts, batched through ``nlp.pipe``."""
        return [self._triples(doc) for doc in self.nlp.pipe(texts, batch_size=batch_size)]

    def corpus_tokens(self, text: str) -> list[str]:
        """``text`` tagged as HumanML3D tags its captions, for a corpus whose captions come
        untagged: the tags checked against the lexicon as a prompt's are, words only (no numbers
        or punctuation, hyphens removed), NOUN and VERB words as their lemmas except "left"
        (EricGuo5513/HumanML3D, ``text_process.py``)."""
        tokens = []
        for tok in _tokens_from_tagger(text, self):
            word = tok.text.replace("-", "")
            if word.isalpha():
                tokens.append(f"{tok.lemma if tok.pos in _LEMMATISED_POS and word != 'left' else word}/{tok.pos}")
        return tokens


def _training_pipeline(width: int = 64) -> Language:
    """Blank English + shared hash-embedding CNN + morphologizer (UPOS) + edit-tree lemmatizer.

    Small (width 64, depth 2) so that training takes seconds; built-in spaCy components only, so
    the saved pipeline loads with nothing but spaCy.
    """
    nlp = spacy.blank("en")
    nlp.add_pipe(
        "tok2vec",
        config={
            "model": {
                "@architectures": "spacy.HashEmbedCNN.v2",
                "pretrained_vectors": None,
                "width": width,
                "depth": 2,
                "embed_size": 2000,
                "window_size": 1,
                "maxout_pieces": 3,
                "subword_features": True,
            }
        },
    )
    listener = {"@architectures": "spacy.Tok2VecListener.v1", "width": width, "upstream": "*"}
    tagger_model = {"@architectures": "spacy.Tagger.v2", "nO": None, "tok2vec": listener}
    nlp.add_pipe("morphologizer", config={"model": tagger_model})
    nlp.add_pipe(
        "trainable_lemmatizer",
        name="lemmatizer",
        config={"model": tagger_model, "min_tree_freq": 1, "backoff": "orth"},
    )
    return nlp


def train_tagger(
    tagged_captions: Iterable[tuple[str, Sequence[tuple[str, str]]]],
    out_dir: str | Path,
    seed: int = 0,
    epochs: int = 6,
) -> Tagger:
    """Train a UPOS tagger + lemmatizer on (caption, corpus tags) pairs and save it to ``out_dir``.

    Distils the corpus's ``en_core_web_sm`` tags into a pipeline that needs no download. Captions
    whose tags do not align with their text are skipped. Lemmas come from the tags too, since
    HumanML3D's NOUN and VERB words are the lemmas of the caption's words: an edit-tree
    lemmatizer learns them for unseen words, and a (UPOS, surface) -> lemma table saved in the
    pipeline's vocabulary makes the corpus's own words exact. Deterministic for a given ``seed``
    (same data, same thread count).
    """
    fix_random_seed(seed)
    nlp = _training_pipeline()
    examples = []
    lemma_counts: Counter[tuple[str, str]] = Counter()
    seen = 0
    for caption, tagged in tagged_captions:
        seen += 1
        aligned = _align(_normalise(caption)[0], tagged)
        if aligned is None:
            continue
        words = [t.text for t in aligned]
        spaces = [t.space for t in aligned[1:]] + [False]
        reference = Doc(
            nlp.vocab,
            words=words,
            spaces=spaces,
            pos=[t.pos for t in aligned],
            lemmas=[t.lemma for t in aligned],
        )
        examples.append(Example(Doc(nlp.vocab, words=words, spaces=spaces), reference))
        lemma_counts.update((f"{t.pos} {t.text}", t.lemma) for t in aligned if t.pos in _LEMMATISED_POS)
    if not examples:
        raise ValueError(f"none of the {seen} tagged captions aligns with its text: nothing to train")
    optimizer = nlp.initialize(lambda: examples)
    order = random.Random(seed)
    for _ in range(epochs):
        order.shuffle(examples)
        for batch in minibatch(examples, size=32):
            nlp.update(batch, sgd=optimizer, drop=0.1)
    lemmas: dict[str, str] = {}
    for (key, lemma), _ in sorted(lemma_counts.items(), key=lambda kv: (-kv[1], kv[0])):
        lemmas.setdefault(key, lemma)  # the most frequent lemma of each (UPOS, surface)
    nlp.vocab.lookups.add_table(LEMMA_TABLE, lemmas)
    nlp.meta["name"] = "m2d2m_tagger"
    nlp.meta["description"] = "UPOS tagger + lemmatizer distilled from corpus caption tags"
    nlp.meta["m2d2m"] = {
        "captions": seen,
        "trained_on": len(examples),
        "seed": seed,
        "epochs": epochs,
    }
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    nlp.to_disk(out)
    return Tagger(nlp)


def load_tagger(path: str | Path | None = None) -> Tagger:
    """The installed ``en_core_web_sm`` if there is one, else the pipeline trained at ``path``."""
    if spacy.util.is_package(SMALL_MODEL):
        return Tagger(spacy.load(SMALL_MODEL, exclude=["parser", "ner", "senter"]))
    if path is not None and (Path(path) / "config.cfg").is_file():
        return Tagger(spacy.load(path))
    where = f"at {path}" if path is not None else "(no path given)"
    raise FileNotFoundError(
        f"no spaCy tagger: {SMALL_MODEL} is not installed and there is no trained tagger {where}; "
        "run `m2d2m data` first, which trains one into data/<name>/nlp/"
    )
