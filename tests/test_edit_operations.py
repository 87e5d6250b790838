"""Issue 55 §1: each edit operation is its own type with only its fields, checked once when it is
made and planned by its own planner; the command line's flags and the API's bodies each become
one, and the API's schema shows the union. Before, five operations shared one record of ten
optional fields, checked in six places, and ``plan_edit`` took 11 parameters."""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import pytest
from fastapi.testclient import TestClient

from m2d2m.generators.edits import Edit, Timeline, margin_frames, regenerate_action
from m2d2m.motion.representation.skeleton import T2M
from orchestration.cli import main
from orchestration.edit_operations import Continue, EditOperation, Fill, Layer, Pin, Regenerate, plan_edit
from orchestration.errors import UserError
from orchestration.registry import model, models
from orchestration.web.app import ServeSettings, create_app

D = T2M.feature_dim


class Model:
    """What a planner asks of a generator: its rate, its step, its lengths and its skeleton (a
    token model's 4-frame step at 20 fps)."""

    fps = 20.0
    frame_step = 4
    longest_frames = 196
    skeleton = T2M

    def round_frames(self, frames: int) -> int:
        return max(1, int(frames) // 4) * 4

    def typical_frames(self, verb: str | None) -> int:
        return 60


def three_actions() -> Timeline:
    """Actions a, b, c of 16, 12 and 16 frames, each frame's features its own."""
    features = np.arange(44 * D, dtype=np.float32).reshape(44, D) / (44 * D)
    return Timeline(features, ["a", "b", "c"], [0, 16, 28])


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: Regenerate(0), "actions are counted from 1, not 0"),
        (lambda: Continue((), ()), "continuing takes the new actions' texts (prompts)"),
        (lambda: Continue(("a person sits",), (1.0, 2.0)), "give one length per new action: 1 action(s), 2 length(s)"),
        (lambda: Layer("torso", "a person waves", (0.0, 1.0)), "unknown body part 'torso': choose from"),
    ],
)
def test_an_operation_that_cannot_be_is_refused_when_made(make, message):
    with pytest.raises(UserError, match=re.escape(message)):
        make()


def test_each_operation_is_planned_by_its_own_planner_in_the_models_frames():
    """Seconds become whole 4-frame steps, 0.4 s margins 8 frames; each planner says what it does."""
    source, model_ = three_actions(), Model()
    planned = {
        "regenerate": plan_edit(model_, source, Regenerate(2, "a person jumps", 0.8)),
        "fill": plan_edit(model_, source, Fill(source)),
        "pin": plan_edit(model_, source, Pin(source.features[3], 0.7)),
        "continue": plan_edit(model_, source, Continue(("a person sits", "a person stands"), (None, 0.4))),
        "layer": plan_edit(model_, source, Layer("upper", "a person waves", (0.2, 0.8))),
    }
    assert {name: said for name, (_, said) in planned.items()} == {
        "regenerate": "action 2 of 3 sampled again",
        "fill": "1 s filled between two results",
        "pin": "a pose pinned at frame 14",
        "continue": "2 action(s) added",
        "layer": "upper body doing 'a person waves' from 0.2 to 0.8 s",
    }
    assert {name: edit.frames for name, (edit, _) in planned.items()} == {
        "regenerate": [16, 16, 16],
        "fill": [16, 12, 16, 20, 16, 12, 16],
        "pin": [16, 12, 16],
        "continue": [16, 12, 16, 60, 8],
        "layer": [4, 12, 12, 16],  # the span, frames 4 to 16, cuts a
    }
    redo, _ = planned["regenerate"]
    expected = regenerate_action(source, 1, margin=8, text="a person jumps", frames=16, step=4)
    assert redo.actions == expected.actions
    np.testing.assert_array_equal(redo.keep.frames, expected.keep.frames)


def test_a_new_operation_is_one_type_and_its_planner():
    """An operation defined here, outside the project, is planned like the five it has; what a
    result cannot take is one line."""

    @dataclass(frozen=True)
    class RedoLast(EditOperation):
        def plan(self, generator: Model, timeline: Timeline) -> tuple[Edit, str]:
            last = len(timeline.actions) - 1
            return regenerate_action(timeline, last, margin_frames(generator)), "the last action sampled again"

    edit, said = plan_edit(Model(), three_actions(), RedoLast())
    assert said == "the last action sampled again" and edit.frames == [16, 12, 16]
    assert not edit.keep.frames[20:].any() and edit.keep.frames[:20].all()
    with pytest.raises(UserError, match="the edit keeps nothing of the source"):
        plan_edit(Model(), Timeline(three_actions().features, ["a"], [0]), RedoLast())


def test_what_a_model_edits_several_actions_with_is_declared_by_the_model():
    """MMM's transition tokens cannot keep frames across actions: it says it edits with its
    independent method (the table of model names that said so in orchestration/ is gone)."""
    declared = {name: entry.load("generator").edit_method for name, entry in models().items()}
    assert declared["mmm"] == "independent" and declared["m2d2m"] is None and declared["mmm-body"] is None
    for name, method in declared.items():
        assert method is None or method in model(name).load("sampling").methods, name


def test_the_api_schema_is_a_union_of_the_operations_and_refuses_in_their_words(tmp_path, monkeypatch):
    """`/openapi.json` gives the edit's body as a oneOf by operation, each with its own fields; a
    field of another operation, or one of its own missing, is a 422 sentence (before the
    generation is looked up)."""
    monkeypatch.chdir(tmp_path)
    with TestClient(create_app(ServeSettings(dataset="tiny", track=False))) as client:
        spec = client.get("/openapi.json").json()
        body = spec["paths"]["/api/generations/{generation_id}/edit"]["post"]["requestBody"]
        schema = body["content"]["application/json"]["schema"]
        mapping = schema["discriminator"]["mapping"]
        assert schema["discriminator"]["propertyName"] == "operation"
        assert set(mapping) == {"regenerate", "fill", "pin", "continue", "layer"}
        assert sorted(member["$ref"] for member in schema["oneOf"]) == sorted(mapping.values())
        members = {name: spec["components"]["schemas"][ref.rsplit("/", 1)[1]] for name, ref in mapping.items()}
        own = {
            name: set(member["properties"]) - {"operation", "options", "seed", "fps", "root", "loop", "plant_feet"}
            for name, member in members.items()
        }
        assert own == {
            "regenerate": {"action", "text", "seconds"},
            "fill": {"then", "text", "seconds"},
            "pin": {"pose", "at"},
            "continue": {"actions"},
            "layer": {"part", "text", "span"},
        }
        assert members["pin"]["required"] == ["operation", "pose", "at"]
        for sent, sentence in (
            ({"operation": "regenerate", "action": 1, "at": 1.0}, "at does not go with the operation regenerate"),
            ({"operation": "fill", "then": "x", "action": 2}, "action does not go with the operation fill"),
            (
                {"operation": "pin", "pose": {"generation": "x", "frame": 1}},
                "pin names the pose and the time to pin it at (pose: a generation and its frame; at: seconds)",
            ),
            ({"operation": "continue"}, "continue names the new actions (actions)"),
            ({"operation": "regenerate", "action": 0}, "action: Input should be greater than or equal to 1"),
        ):
            answer = client.post("/api/generations/nowhere/edit", json=sent)
            assert answer.status_code == 422 and answer.json() == {"error": sentence}, (sent, answer.text)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["a person walks", "--regenerate", "2"], "--regenerate edits a result on its timeline: it goes with --edit"),
        (["--edit", "a.npy", "--keep-body", "lower", "x", "--continue"], "--continue edits a result on its timeline"),
        (["--edit", "a.npy", "--regenerate", "2", "--at", "1"], "--at goes with --pin, not with --regenerate"),
        (["--edit", "a.npy", "x", "--continue", "--span", "0:1"], "--span goes with --layer, not with --continue"),
        (["--edit", "a.npy", "--regenerate", "1", "--fill-to", "b.npy"], "an edit is one of: regenerate an action"),
    ],
)
def test_the_command_line_refuses_an_operations_flags_before_a_model_loads(
    tmp_path, monkeypatch, capsys, argv, message
):
    """Before, a flag no operation asked for was dropped without a word (`--at` with
    `--regenerate`; `--regenerate` without `--edit` generated a new motion)."""
    monkeypatch.chdir(tmp_path)
    assert main(["generate", *argv]) == 2
    assert message in capsys.readouterr().err
