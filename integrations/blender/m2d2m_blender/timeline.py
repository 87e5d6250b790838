"""Where a clip's actions lie on Blender's timeline, and what an edit at the playhead asks the
server: pure Python, tested outside Blender.

A clip is keyed from the scene's first frame, one key per frame at the scene's rate (the server
delivers it at that rate), so the answer's action ``first``/``end`` frames are scene frames
moved by the start. An edit samples the changed span and 0.4 s on each side of it anew
(docs/generation.md, "Editing a result": the margins that make the joins), so the keys replaced
are the span and those margins; the keys beyond them are kept as they are.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

EDIT_MARGIN_S = 0.4  # what an edit samples on each side of its span (m2d2m/generators/edits.py)
MARKER_CHARACTERS = 63  # a timeline marker's name holds at most 63 characters


@dataclass(frozen=True)
class Span:
    """An action on the timeline: its text and its scene frames, ``first`` to ``end`` (exclusive)."""

    text: str
    first: int
    end: int


def spans(actions: Sequence[dict[str, Any]], start: int) -> list[Span]:
    """The answer's actions (``text``, ``first``, ``end``: frames of the clip) as scene frames of a
    clip keyed from frame ``start``."""
    return [Span(action["text"], start + int(action["first"]), start + int(action["end"])) for action in actions]


def action_at(actions: Sequence[Span], frame: int) -> int:
    """The index of the action whose span holds ``frame``; a ValueError saying where the actions are."""
    for index, action in enumerate(actions):
        if action.first <= frame < action.end:
            return index
    where = ", ".join(f"{action.first}-{action.end - 1}" for action in actions)
    raise ValueError(f"the playhead (frame {frame}) is in no action of the clip; its actions span frames {where}")


def replaced_frames(first: int, end: int, fps: float, clip_first: int, clip_end: int) -> range:
    """The scene frames an edit of the span ``first`` to ``end`` gives anew: the span and the
    margins the model sampled round it, within the clip (``clip_first`` to ``clip_end``)."""
    margin = round(EDIT_MARGIN_S * fps)
    return range(max(clip_first, first - margin), min(clip_end, end + margin))


def fill_seconds(frame: int, clip_end: int, fps: float) -> float:
    """The seconds from the clip's end to the playhead at ``frame`` (its last frame included), which
    "Fill to here" asks the server to continue the clip by; a ValueError when the playhead is not past the end."""
    if frame < clip_end:
        raise ValueError(f"move the playhead past the clip's last frame ({clip_end - 1}) to fill up to it")
    return (frame + 1 - clip_end) / fps


def marker_name(text: str) -> str:
    """An action's text as a timeline marker's name (cut to what a marker holds, with an ellipsis)."""
    return text if len(text) <= MARKER_CHARACTERS else text[: MARKER_CHARACTERS - 1] + "…"
