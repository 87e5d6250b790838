"""The embedded synthetic motion-language corpus, written in HumanML3D's raw layout.

Real corpora cannot be redistributed (AMASS licence), so the demo and the tests run on a corpus
the project makes itself: clips of 1–3 chained actions with three captions each, tagged the way
HumanML3D's ``text_process.py`` tags them. Everything is a function of ``(seed, clip index)``, so
the corpus is byte-identical whatever the number of workers.

Layout under ``out_dir``::

    joints/<id>.npy     float32 (T, 22, 3), 20 fps, 40 ≤ T ≤ 199
    texts/<id>.txt      caption#word/POS word/POS ...#0.0#0.0   (three lines)
    train.txt val.txt test.txt
    annotations.jsonl   per clip: actions (family, parameters, frame range), body scale, captions
    corpus.json         seed, clip count, families, generator version, summary

**Motion.** A motion is first written as a :class:`~pipelines.synthetic.program.Program`: per-frame
curves for the pelvis (position, heading, tilt), the spine, the neck, wrist targets for the arms
(in the chest's frame), and ankle targets plus foot orientation for the legs.
:func:`~pipelines.synthetic.program.program_joints` turns a program into joint positions with
forward kinematics of the pelvis, spine, neck and collars on the standard hierarchy whose rest
offsets are ``T2M.raw_offsets × bone lengths`` (each joint's rotation moves all its child bones,
so the pelvis and the chest are rigid), and analytic two-bone IK for the limbs. That keeps every
bone at its length, bends knees and elbows only the anatomical way, and keeps a planted foot
exactly where it was put: its ankle target does not move, and the pelvis is lowered wherever a
leg would otherwise not reach. Locomotion is driven by footsteps: feet are planted, rolled over
the toes and swung to the next footprint; the pelvis follows the smoothed middle of the feet, so
stride length × cadence is the speed.

**Action families.** Each family is one :class:`~pipelines.synthetic.family.ActionFamily`
(``families/``): its motion — a function of the body, the
:class:`~pipelines.synthetic.body.State` the previous action left (where the feet are, which way
the body faces, standing or seated) and its parameters, returning its program and the state it
ends in, so actions chain without jumps —, how its parameters are drawn, and its phrases. A new
family is one object in one of those modules; since the families' order
(``families.ACTIONS``) is the order draws are made in, a new one changes every corpus: raise
``corpus.GENERATOR_VERSION`` with it.

**Captions** are built from a small grammar whose every word carries the universal POS tag spaCy's
``en_core_web_sm`` gives it in that position (``is``/AUX, ``his``/PRON, ``left``/ADJ before a noun
and ADV after "turn", particles such as "down" in "sits down"/ADP); NOUN and VERB tokens are
written as their lemma except the word ``left``, and punctuation is kept in the caption but not
in the tokens, exactly as HumanML3D's processed texts.
"""

from pipelines.synthetic.body import FPS
from pipelines.synthetic.captions import make_captions
from pipelines.synthetic.clips import MAX_FRAMES, MIN_FRAMES, TEXTURE, make_clip
from pipelines.synthetic.corpus import assign_splits, existing_corpus, generate_corpus
from pipelines.synthetic.families import ACTIONS, FAMILIES
from pipelines.synthetic.program import Texture, band_noise
from pipelines.synthetic.words import UPOS, caption_line

__all__ = [
    "ACTIONS",
    "FAMILIES",
    "FPS",
    "MAX_FRAMES",
    "MIN_FRAMES",
    "TEXTURE",
    "UPOS",
    "Texture",
    "assign_splits",
    "band_noise",
    "caption_line",
    "existing_corpus",
    "generate_corpus",
    "make_captions",
    "make_clip",
]
