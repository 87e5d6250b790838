"""Sampling knobs declared once (m2d2m/generators/options.py): checked by hand-set cases, the same
declaration behind every registered generator and its registry entry, readable without torch, and
the source of the command line's shortcuts and help."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass

import pytest

from m2d2m.generators.options import MULTI, SINGLE, Sampling, check_knobs, knob
from orchestration.registry import models


@dataclass(frozen=True)
class Toy:
    method: str = knob("a", "how", choices=("a", "b"))
    count: int = knob(2, "how many", minimum=1)
    share: float | None = knob(None, "how much", above=0, maximum=1)


TOY = Sampling("toy", Toy, {MULTI: Toy(), SINGLE: Toy(method="b")})


@pytest.mark.parametrize(
    "changes, expected",
    [
        ({"count": 3.0}, Toy(count=3)),
        ({"share": 1}, Toy(share=1.0)),
        ({"share": None}, Toy()),
        ({"method": "b", "count": 1}, Toy(method="b", count=1)),
    ],
)
def test_changes_are_taken_as_their_knob_declares(changes, expected):
    changed = TOY.changed(TOY.presets[MULTI], **changes)
    assert changed == expected and type(changed.count) is int


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"count": 0}, "option count must be >= 1, got 0"),
        ({"count": 2.5}, "must be a whole number"),
        ({"count": "3"}, "must be a finite number"),
        ({"count": True}, "must be a finite number"),
        ({"count": float("nan")}, "must be a finite number"),
        ({"count": None}, "option count cannot be empty"),
        ({"share": 0.0}, r"option share must be \(0, 1\], got 0"),
        ({"share": 1.5}, r"\(0, 1\]"),
        ({"method": "c"}, "unknown method 'c' for toy: choose one of a, b"),
        ({"width": 1}, "toy has no sampling option 'width'; its options: count, share"),
    ],
)
def test_a_bad_change_is_one_sentence(changes, message):
    with pytest.raises(ValueError, match=message):
        TOY.changed(TOY.presets[MULTI], **changes)


def test_the_declaration_lists_knobs_methods_and_defaults():
    assert TOY.methods == ("a", "b") and TOY.names() == ("count", "share")
    assert [(k.name, k.kind, k.optional, k.bounds) for k in TOY.knobs()] == [
        ("count", "int", False, ">= 1"),
        ("share", "float", True, "(0, 1]"),
    ]
    assert TOY.defaults(SINGLE) == {"method": "b", "count": 2, "share": None}
    with pytest.raises(ValueError, match="option count must be >= 1"):
        check_knobs(Toy(count=0))
    with pytest.raises(TypeError, match="no single preset"):
        Sampling("toy", Toy, {MULTI: Toy()})


def test_every_model_has_one_declaration_behind_its_entry_and_its_generator():
    for name, entry in models().items():
        sampling = entry.load("sampling")
        assert entry.load("generator").sampling is sampling and sampling.model == name
        assert set(entry.shortcuts) <= set(sampling.names())
        for preset in (SINGLE, MULTI):
            check_knobs(sampling.presets[preset])
            assert sampling.presets[preset].method in sampling.methods


@pytest.mark.parametrize("model", ["m2d2m", "mmm", "mmm-body", "motiondiffuse"])
def test_every_knob_and_method_of_the_models_has_a_name_for_people(model):
    """The page shows these, not ts or eta (issue 38, item 8); a knob for some methods only names them."""
    sampling = models()[model].load("sampling")
    assert set(sampling.method_labels) == set(sampling.methods)
    for declared in sampling.knobs():
        assert declared.label and declared.label != declared.name, declared.name
        assert declared.methods is None or set(declared.methods) <= set(sampling.methods)


def test_a_knob_or_a_label_naming_an_unknown_method_is_refused():
    @dataclass(frozen=True)
    class Misnamed:
        method: str = knob("a", "how", choices=("a", "b"))
        count: int = knob(2, "how many", label="Count", methods=("c",))

    with pytest.raises(TypeError, match="count names unknown methods c"):
        Sampling("toy", Misnamed, {MULTI: Misnamed(), SINGLE: Misnamed()})
    with pytest.raises(TypeError, match="method_labels names unknown methods d"):
        Sampling("toy", Toy, {MULTI: Toy(), SINGLE: Toy()}, {"d": "D"})
    assert TOY.knob("count").label == "count"  # undeclared: its own name


def test_declared_choices_are_the_processes_own():
    from m2d2m.generators.mmm.options import SCHEDULES
    from m2d2m.generators.motiondiffuse.options import VARIANCES
    from m2d2m.processes import gaussian_diffusion, masking

    assert SCHEDULES == masking.SCHEDULES and VARIANCES == gaussian_diffusion.VARIANCES


def test_the_declarations_and_the_command_line_load_without_torch():
    code = (
        "import sys; from orchestration.cli import build_parser; from orchestration.cli.sampling import sampling_help; "
        "build_parser(); sampling_help(); "
        "assert 'torch' not in sys.modules, 'torch imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_a_plugins_shortcut_and_knobs_reach_the_command_line(monkeypatch, capsys):
    from orchestration.cli import build_parser
    from orchestration.cli.sampling import sampling_options
    from orchestration.registry import load_plugins

    monkeypatch.setenv("M2D2M_PLUGINS", "tests.fake_model")
    load_plugins()
    parser = build_parser()
    args = parser.parse_args(["generate", "a person walks", "--model", "playback", "--offset", "3", "--option", "x=1"])
    assert sampling_options(args) == {"x": 1, "offset": 3}
    assert sampling_options(parser.parse_args(["generate", "x", "--eta", "0.5"])) == {"eta": 0.5}
    with pytest.raises(SystemExit):
        parser.parse_args(["generate", "--help"])
    shown = capsys.readouterr().out
    assert "--offset INT" in shown and "playback: methods concat" in shown
    assert "top_p (float, (0, 1]; preset none)" in shown
    with pytest.raises(SystemExit):
        parser.parse_args(["generate", "x", "--offset", "three"])
