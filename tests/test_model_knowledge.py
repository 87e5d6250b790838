"""What a trained model knows, said before anyone asks (issue 38, items 5 and 7): its defaults are
the same wherever they are shown (`m2d2m models`, `/api/models`, a run's details, the generation
itself); its actions, lengths and words are listed by `m2d2m models` and the page's run details;
a prompt with words it never read, or a verb it was never shown alone, is warned about before
sampling on the command line and in the API's answer."""

from __future__ import annotations

import json
import shutil

import pytest
from fastapi.testclient import TestClient

from m2d2m.generators.m2d2m.checkpoint import M2D2M_FORMAT
from m2d2m.generators.m2d2m.generator import M2D2MGenerator
from orchestration.cli import main
from orchestration.model_summary import also_trained
from orchestration.web.app import ServeSettings, create_app

CHOSEN = {"steps": 3, "guidance": 1.5}  # what the second run's config chose for every preset


@pytest.fixture(scope="module")
def chosen_run(trained_project):
    """A second, newer M2D2M run whose config's ``sampling`` section chose its own steps and
    guidance: in its run record and in its model file, as training writes both."""
    folder = trained_project / "runs" / "tiny" / "m2d2m"
    first = (folder / "latest").read_text().strip()
    second = folder / "20990101-000000-beef"
    shutil.copytree(folder / first, second)
    payload = M2D2M_FORMAT.read(second / "model.pt")
    M2D2M_FORMAT.write(second / "model.pt", {**payload, "sampling": CHOSEN})
    info = json.loads((second / "run.json").read_text())
    info["config"]["sampling"] = CHOSEN
    (second / "run.json").write_text(json.dumps(info))
    (folder / "latest").write_text(second.name + "\n")
    return second


@pytest.fixture(scope="module")
def client(chosen_run):
    with TestClient(create_app(ServeSettings(dataset="tiny", track=False))) as client:
        yield client


def knob_defaults(knobs: list[dict]) -> dict:
    return {knob["name"]: knob["default"] for knob in knobs}


def test_the_defaults_are_the_model_files_wherever_they_are_shown(client, chosen_run, capsys):
    """`/api/models` said the paper's guidance 2.0 while the model file and the result said s = 1."""
    generator = M2D2MGenerator.load(chosen_run / "model.pt")
    sampled = {k: v for k, v in vars(generator.options()).items() if k != "method"}
    assert {k: sampled[k] for k in CHOSEN} == CHOSEN
    (listed,) = client.get("/api/models").json()["models"]
    assert knob_defaults(listed["knobs"]) == sampled
    details = client.get(f"/api/models/m2d2m/runs/{chosen_run.name}").json()
    assert knob_defaults(details["knobs"]) == sampled
    assert main(["models", "--dataset", "tiny"]) == 0
    printed = capsys.readouterr().out
    assert f"run {chosen_run.name}, 1 older" in printed
    assert ", ".join(f"{k} {'none' if v is None else v}" for k, v in sampled.items()) in printed


def test_models_and_the_run_details_list_the_actions_and_lengths_it_knows(client, chosen_run, capsys):
    generator = M2D2MGenerator.load(chosen_run / "model.pt")
    verbs = sorted(generator.known_verbs)
    assert verbs == ["jump", "wave"]  # the tiny corpus's single-action captions (tests/helpers.py, CAPTIONS)
    details = client.get(f"/api/models/m2d2m/runs/{chosen_run.name}").json()
    assert details["actions"] == verbs and details["seconds"] == [0.2, 4.8]
    assert main(["models", "--dataset", "tiny"]) == 0
    printed = capsys.readouterr().out
    assert f"actions it was shown alone ({len(verbs)}): {', '.join(verbs)}" in printed
    assert "each action 0.2–4.8 s, at 20 frames per second; it reads only the words of its training captions" in printed


def test_the_actions_proposed_are_actions_not_do_get_or_back(client, chosen_run, capsys, monkeypatch):
    """Issue 53, finding 8: the page proposed "do", "get" and "back" as actions (chips adding "a
    person dos", "a person gets", "a person backs"): verbs of the corpus's single-action captions
    that name no action alone."""
    verbs = ("back", "do", "get", "jump", "perform", "put", "start", "walk", "wave")
    monkeypatch.setattr(M2D2MGenerator, "known_verbs", property(lambda self: verbs))
    details = client.get(f"/api/models/m2d2m/runs/{chosen_run.name}").json()
    assert details["actions"] == ["jump", "walk", "wave"]
    assert main(["models", "--dataset", "tiny"]) == 0
    assert "actions it was shown alone (3): jump, walk, wave" in capsys.readouterr().out


def test_models_without_a_dataset_lists_every_trained_dataset(chosen_run, capsys):
    """A real-motion model beside the demo's is found without knowing its dataset's name."""
    assert main(["models"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert "dataset tiny (serve it: m2d2m serve --dataset tiny)" in printed
    assert any(line.startswith("  m2d2m: ") for line in printed)
    assert f"    run {chosen_run.name}, 1 older ({chosen_run.relative_to(chosen_run.parents[3])}/model.pt)" in printed


def test_serving_one_dataset_names_the_others_with_trained_models(chosen_run):
    assert (
        also_trained("synthetic")
        == "serving the models of dataset synthetic; models of tiny (--dataset tiny) are trained too"
    )
    assert also_trained("tiny") is None


def test_models_outside_a_trained_dataset_is_one_line(chosen_run, capsys):
    assert main(["models", "--dataset", "nothing-here"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == (
        "m2d2m models: error: no model of dataset 'nothing-here' has finished training; "
        "run `make train-diffusion` first"
    )


def test_words_and_verbs_the_model_does_not_know_are_warned_about_before_sampling(chosen_run, capsys):
    """ "a man does a cartwheel" silently gave something."""
    out = chosen_run.parent.parent / "cartwheel"
    argv = [
        "generate",
        "a man does a cartwheel",
        "--dataset",
        "tiny",
        "--out",
        str(out),
        "--formats",
        "npy",
        "--overwrite",
    ]
    assert main([*argv, "--no-track", "--seconds", "1"]) == 0
    err = capsys.readouterr().err
    warnings = [line for line in err.splitlines() if line.startswith("warning: ")]
    assert warnings == [
        "warning: 'a person does a cartwheel': the model never read 'does', 'cartwheel' in training; "
        "it samples as if they were not there"
    ]
    # a word of its captions, but a verb it was only ever shown beside another one
    assert main([*argv[:1], "a person walks forward", *argv[2:], "--no-track", "--seconds", "1"]) == 0
    assert [line for line in capsys.readouterr().err.splitlines() if line.startswith("warning: ")] == [
        "warning: 'a person walks forward': the model was never shown 'walk' alone; it knows 2 actions "
        "(jump, wave; `m2d2m models` lists them)"
    ]
    assert main([*argv[:1], "someone jumps on the spot", *argv[2:], "--no-track", "--seconds", "1"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_the_api_answers_with_the_same_notices(client):
    answer = client.post(
        "/api/generate",
        json={"actions": [{"text": "a person walks forward"}, {"text": "a person juggles", "seconds": 1}]},
    )
    assert answer.status_code == 200, answer.text
    assert answer.json()["notices"] == [
        "'a person juggles': the model never read 'juggles' in training; it samples as if it were not there"
    ]
