"""Captions of the Bandai Namco Research Motion Dataset's takes, in plain English, from their
content and style labels (``cfg/content_label.txt``, ``cfg/style_label.txt``; Kobayashi et al.
2023, arXiv:2306.08861).

Each content has three phrasings, as HumanML3D gives a motion several captions, so that a text
encoder does not learn one template; each names the content's verb, which the pipeline splits
captions at (pipelines/language.py). A take gets all three, each with a phrasing of its style,
which phrasing a hash of the take's name picks, so the captions are the same on every build.
What a label does not say was measured from the joints, over every take of the content
(docs/data.md, "The Bandai Namco corpus"): ``bye`` waves the right hand only, ``byebye`` both
hands together (in a few takes the hand barely moves, the rig ending at the wrist, so one wording
says only that it is raised); ``guide`` holds the right hand out in front at chest height; ``respond`` raises
the left hand above the shoulder; ``call`` is a deep bow (55°); ``walk-left`` and ``walk-right``
walk about 30° off the way the body faces, without turning; ``kick`` kicks the right leg up to
1 m; ``slash`` keeps the wrists together, as round a sword's grip; ``chimpira`` (Japanese for a
street punk) stands and walks with the feet 20–28 cm apart, against 3–14 cm in ``normal``.
"""

from __future__ import annotations

import hashlib

# content → (its phrasings, "{style}" where the style's words go; the verbs each must contain)
CONTENTS: dict[str, tuple[tuple[str, str, str], frozenset[str]]] = {
    "walk": (
        (
            "a person walks forward{style}",
            "someone walks straight ahead{style}",
            "a person walks in a straight line{style}",
        ),
        frozenset({"walk"}),
    ),
    "run": (
        ("a person runs forward{style}", "someone runs straight ahead{style}", "a person is running forward{style}"),
        frozenset({"run"}),
    ),
    "dash": (
        (
            "a person dashes forward{style}",
            "someone sprints straight ahead{style}",
            "a person dashes ahead at full speed{style}",
        ),
        frozenset({"dash", "sprint"}),
    ),
    "walk-back": (
        (
            "a person walks backward{style}",
            "someone walks backwards{style}",
            "a person walks back, facing forward{style}",
        ),
        frozenset({"walk"}),
    ),
    "walk-left": (
        (
            "a person walks diagonally forward to the left{style}",
            "someone walks forward and to the left{style}",
            "a person walks ahead at an angle to the left{style}",
        ),
        frozenset({"walk"}),
    ),
    "walk-right": (
        (
            "a person walks diagonally forward to the right{style}",
            "someone walks forward and to the right{style}",
            "a person walks ahead at an angle to the right{style}",
        ),
        frozenset({"walk"}),
    ),
    "bow": (
        ("a person bows{style}", "someone bows forward{style}", "a person bends forward in a bow{style}"),
        frozenset({"bow", "bend"}),
    ),
    "bye": (
        (
            "a person waves goodbye with the right hand{style}",
            "someone raises the right hand in a goodbye wave{style}",
            "a person waves bye with the right hand{style}",
        ),
        frozenset({"wave", "raise"}),
    ),
    "byebye": (
        (
            "a person waves goodbye with both hands{style}",
            "someone raises both hands in a goodbye wave{style}",
            "a person waves bye with both hands{style}",
        ),
        frozenset({"wave", "raise"}),
    ),
    "guide": (
        (
            "a person shows the way with the right hand{style}",
            "someone gestures forward with the right hand{style}",
            "a person points the way with the right hand{style}",
        ),
        frozenset({"show", "gesture", "point"}),
    ),
    "respond": (
        (
            "a person raises the left hand{style}",
            "someone raises the left hand high{style}",
            "a person puts the left hand up{style}",
        ),
        frozenset({"raise", "put"}),
    ),
    "call": (
        (
            "a person bows deeply{style}",
            "someone bends forward in a deep bow{style}",
            "a person greets someone with a deep bow{style}",
        ),
        frozenset({"bow", "bend", "greet"}),
    ),
    "punch": (
        (
            "a person throws punches{style}",
            "someone punches from a fighting stance{style}",
            "a person punches with the fists up{style}",
        ),
        frozenset({"throw", "punch"}),
    ),
    "kick": (
        (
            "a person kicks with the right leg{style}",
            "someone kicks high with the right leg{style}",
            "a person kicks the right leg up high{style}",
        ),
        frozenset({"kick"}),
    ),
    "slash": (
        (
            "a person slashes with a sword held in both hands{style}",
            "someone swings an imaginary sword with both hands{style}",
            "a person slashes with both hands together{style}",
        ),
        frozenset({"slash", "swing"}),
    ),
    "dance-long": (
        ("a person dances{style}", "someone is dancing{style}", "a person performs a dance{style}"),
        frozenset({"dance", "perform"}),
    ),
    "dance-short": (
        ("a person dances{style}", "someone is dancing{style}", "a person performs a dance{style}"),
        frozenset({"dance", "perform"}),
    ),
    "walk-turn-left": (
        (
            "a person walks forward{style} and turns left",
            "someone walks ahead{style}, then turns to the left",
            "a person walks{style} and turns ninety degrees to the left",
        ),
        frozenset({"walk"}),
    ),
    "walk-turn-right": (
        (
            "a person walks forward{style} and turns right",
            "someone walks ahead{style}, then turns to the right",
            "a person walks{style} and turns ninety degrees to the right",
        ),
        frozenset({"walk"}),
    ),
    "wave-both-hands": (
        (
            "a person waves both hands{style}",
            "someone waves with both hands{style}",
            "a person raises both hands and waves them{style}",
        ),
        frozenset({"wave"}),
    ),
    "wave-left-hand": (
        (
            "a person waves the left hand{style}",
            "someone waves with the left hand{style}",
            "a person raises the left hand and waves it{style}",
        ),
        frozenset({"wave"}),
    ),
    "wave-right-hand": (
        (
            "a person waves the right hand{style}",
            "someone waves with the right hand{style}",
            "a person raises the right hand and waves it{style}",
        ),
        frozenset({"wave"}),
    ),
    "raise-up-both-hands": (
        (
            "a person raises both hands{style}",
            "someone raises both hands up{style} and lowers them again",
            "a person raises both hands{style}, then puts them down",
        ),
        frozenset({"raise"}),
    ),
    "raise-up-left-hand": (
        (
            "a person raises the left hand{style}",
            "someone raises the left hand up{style} and lowers it again",
            "a person raises the left hand{style}, then puts it down",
        ),
        frozenset({"raise"}),
    ),
    "raise-up-right-hand": (
        (
            "a person raises the right hand{style}",
            "someone raises the right hand up{style} and lowers it again",
            "a person raises the right hand{style}, then puts it down",
        ),
        frozenset({"raise"}),
    ),
}

# style → three ways of saying it, after the content's verb phrase ("" for the plain style)
STYLES: dict[str, tuple[str, str, str]] = {
    "normal": ("", "", ""),
    "happy": (" happily", " cheerfully", " in a happy mood"),
    "sad": (" sadly", " in a sad mood", " with a sad air"),
    "angry": (" angrily", " in an angry mood", " with an angry air"),
    "proud": (" proudly", " with pride", " in a proud manner"),
    "not-confident": (" timidly", " without confidence", " in an unsure way"),
    "masculinity": (" in a masculine way", " in a manly way", " with a masculine manner"),
    "masculine": (" in a masculine way", " in a manly way", " with a masculine manner"),
    "feminine": (" in a feminine way", " with a feminine manner", " in a ladylike way"),
    "childish": (" like a child", " in a childish way", " childishly"),
    "old": (" like an old person", " like an elderly person", " in an elderly way"),
    "elderly": (" like an elderly person", " like an old person", " in an elderly way"),
    "tired": (" tiredly", " wearily", " in a tired way"),
    "exhausted": (" in an exhausted way", " with exhaustion", " with no energy left"),
    "active": (" energetically", " actively", " with lots of energy"),
    "youthful": (" youthfully", " in a youthful way", " with youthful energy"),
    "musical": (" like in a musical", " theatrically", " in a musical style"),
    "giant": (" like a giant", " in the manner of a giant", " like a huge giant"),
    "chimpira": (" like a street punk", " like a thug with the feet wide apart", " with a wide-legged swagger"),
}


def captions_for(content: str, style: str, take: str) -> list[str]:
    """The three captions of ``take`` (its name), of that content and style (labels without
    their ``dataset-N_`` prefix); KeyError names a label no caption is written for."""
    if content not in CONTENTS:
        raise KeyError(f"none are written for the content {content!r}")
    if style not in STYLES:
        raise KeyError(f"none are written for the style {style!r}")
    phrasings, _ = CONTENTS[content]
    turn = int(hashlib.sha256(take.encode("utf-8")).hexdigest()[:8], 16) % len(STYLES[style])
    return [
        phrasing.format(style=STYLES[style][(i + turn) % len(STYLES[style])]) for i, phrasing in enumerate(phrasings)
    ]
