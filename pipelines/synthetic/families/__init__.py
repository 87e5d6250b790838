"""Every action family of the corpus, in its canonical order (the order draws are made in)."""

from __future__ import annotations

from pipelines.synthetic.families import gestures, leaps, locomotion, whole_body
from pipelines.synthetic.family import ActionFamily

ACTIONS: dict[str, ActionFamily] = {
    family.name: family for module in (locomotion, leaps, gestures, whole_body) for family in module.ACTION_FAMILIES
}
FAMILIES: tuple[str, ...] = tuple(ACTIONS)
