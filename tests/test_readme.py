"""The README's first screen says what to run, from where, what comes out and what the demo model
knows (issue 38: a newcomer had to read a page of metrics to find the page)."""

from __future__ import annotations

from pathlib import Path

from pipelines.bandai_namco_captions import CONTENTS, STYLES
from pipelines.synthetic.families import FAMILIES

README = Path(__file__).resolve().parents[1] / "README.md"


def first_screen() -> str:
    """The README up to its second section: what a newcomer reads before scrolling."""
    text = README.read_text(encoding="utf-8")
    return text[: text.index("\n## ", text.index("## First two commands") + 1)]


def test_the_first_screen_says_what_to_run_from_where_and_what_comes_out():
    screen = first_screen()
    for said in ("make demo", "make test", "repository's root", "make serve", "http://127.0.0.1:8000"):
        assert said in screen, said


def test_the_first_screen_lists_every_action_the_demo_model_knows():
    screen = first_screen()
    assert f"the embedded corpus's {len(FAMILIES)} actions" in screen
    assert all(f"`{family}`" in screen for family in FAMILIES), [f for f in FAMILIES if f"`{f}`" not in screen]


def test_the_real_motion_section_says_how_to_get_and_serve_a_real_model():
    text = README.read_text(encoding="utf-8")
    section = text[text.index("## Real motion") : text.index("\n## ", text.index("## Real motion") + 1)]
    for said in (
        "git clone",
        "Bandai-Namco-Research-Motiondataset",
        "make demo-real",
        "make serve DATASET=bandai-namco",
    ):
        assert said in section, said
    verbs = set().union(*(verbs for _, verbs in CONTENTS.values()))
    assert f"shown {len(verbs)} verbs" in section and f"{len(STYLES)} style labels" in section
