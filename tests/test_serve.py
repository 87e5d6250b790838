"""`m2d2m serve`'s HTTP API on the tiny trained project: every endpoint, a 4xx sentence for every
kind of bad input, the token rule, the same motion as `m2d2m generate`, concurrent requests
sampled in one batch, a client that leaves cancelling its work, SIGTERM finishing what is in flight."""

from __future__ import annotations

import base64
import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import asdict
from pathlib import Path

import httpx
import numpy as np
import psutil
import pygltflib
import pytest
from fastapi.testclient import TestClient

from m2d2m.generators.m2d2m.options import SAMPLING
from m2d2m.motion.representation.skeleton import T2M
from orchestration.cli import main
from orchestration.errors import UserError
from orchestration.web.app import ServeSettings, create_app
from orchestration.web.routers import API_ROUTERS
from orchestration.web.routers.page import STATIC
from orchestration.web.server import server_token
from tests.helpers import free_port
from tests.live_server import live_server
from tests.test_export import bvh_forward_kinematics, in_skeleton_order, parse_bvh

ACTIONS = [{"text": "a person walks forward", "seconds": 1.6}, {"text": "a person jumps", "seconds": 1.2}]
NDJSON = {"Accept": "application/x-ndjson"}


@pytest.fixture(scope="module")
def client(trained_project):
    with TestClient(create_app(ServeSettings(dataset="tiny"))) as client:
        yield client


def generate(client, **body) -> dict:
    answer = client.post("/api/generate", json={"actions": ACTIONS, "options": {"ts": 4}, **body})
    assert answer.status_code == 200, answer.text
    return answer.json()


def ndjson(text: str) -> list[dict]:
    return [json.loads(line) for line in text.splitlines()]


def test_models_lists_the_finished_runs_and_the_declared_knobs(client, trained_project):
    listed = client.get("/api/models").json()
    assert listed["dataset"] == "tiny" and listed["max_seconds"] == 60.0
    (m2d2m,) = listed["models"]  # the only model the tiny project trained
    latest = (trained_project / "runs/tiny/m2d2m/latest").read_text().strip()
    assert m2d2m["name"] == "m2d2m" and m2d2m["runs"] == [{"id": latest, "label": f"{latest} (latest)", "latest": True}]
    assert m2d2m["methods"] == list(SAMPLING.methods) and m2d2m["default_method"] == "tps"
    assert m2d2m["method_labels"] == dict(SAMPLING.method_labels) and set(m2d2m["method_labels"]) == set(
        SAMPLING.methods
    )
    declared = {
        knob.name: {
            **asdict(knob),
            "choices": knob.choices and list(knob.choices),
            "methods": None if knob.methods is None else list(knob.methods),
        }
        for knob in SAMPLING.knobs()
    }
    assert {knob.pop("name"): knob for knob in m2d2m["knobs"]} == {
        name: {**{k: v for k, v in knob.items() if k != "name"}, "default": getattr(SAMPLING.presets["multi"], name)}
        for name, knob in declared.items()
    }
    details = client.get(f"/api/models/m2d2m/runs/{latest}").json()
    assert details["id"] == latest and details["fps"] == 20.0 and details["seconds"] == [0.2, 4.8]
    assert {knob["name"] for knob in details["knobs"]} == set(declared)


def test_a_generation_is_the_motion_m2d2m_generate_makes(client, trained_project, capsys):
    result = generate(client, seed=3, method="independent")
    out = trained_project / "cli-equal"
    code = main(
        ["generate", *(a["text"] for a in ACTIONS), "--seconds", "1.6", "1.2", "--no-split", "--method", "independent"]
        + ["--ts", "4", "--seed", "3", "--dataset", "tiny", "--out", str(out), "--formats", "npy", "bvh", "--no-track"]
    )
    assert code == 0, capsys.readouterr().err
    assert result["actions"] == [
        {"text": "a person walks forward", "first": 0, "end": 32},
        {"text": "a person jumps", "first": 32, "end": 56},
    ]
    assert result["boundaries"] == [32] and result["fps"] == 20.0 and result["parents"] == T2M.parents.tolist()
    served = {}
    for name in ("motion.npy", "motion.features.npy", "motion.bvh", "motion.json"):
        answer = client.get(result["files"][name.removeprefix("motion.").removesuffix(".npy") or "npy"])
        assert answer.status_code == 200, name
        served[name] = answer.content
    for name, mine in (("motion.npy", "motion.npy"), ("motion.features.npy", "motion.features.npy")):
        (trained_project / "served.npy").write_bytes(served[name])
        assert np.array_equal(np.load(trained_project / "served.npy"), np.load(out / mine))
    assert served["motion.bvh"] == (out / "motion.bvh").read_bytes()
    joints = np.load(out / "motion.npy")
    assert np.abs(np.array(result["joints"]) - joints).max() <= 5e-6  # the JSON's 10-µm steps
    assert json.loads(served["motion.json"]) == json.loads((out / "motion.json").read_text())


def test_a_prompt_is_split_by_its_verbs_as_the_command_line_splits_it(client, trained_project, capsys):
    prompt = "a person walks forward and then jumps"
    result = generate(client, actions=None, prompt=prompt, seconds=3.0)
    assert (
        main(
            [
                "generate",
                prompt,
                "--seconds",
                "3",
                "--ts",
                "4",
                "--dataset",
                "tiny",
                "--out",
                str(trained_project / "p"),
                "--formats",
                "npy",
                "--no-track",
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert [a["text"] for a in result["actions"]] == ["a person walks forward", "a person jumps"]
    assert all(a["text"] in printed for a in result["actions"])
    assert np.abs(np.array(result["joints"]) - np.load(trained_project / "p/motion.npy")).max() <= 5e-6


def test_a_prompt_can_be_split_first_to_check_it_before_generating(client):
    """Issue 39, §4: the split a prompt gets is shown before sampling; it is the one generating
    the prompt would sample."""
    prompt = "a person walks forward and then jumps"
    answer = client.post("/api/split", json={"prompt": prompt})
    assert answer.status_code == 200, answer.text
    split = answer.json()
    assert split["actions"] == ["a person walks forward", "a person jumps"] and split["verbs"] == ["walk", "jump"]
    result = generate(client, actions=None, prompt=prompt, seconds=3.0)
    assert [a["text"] for a in result["actions"]] == split["actions"]
    assert split["notices"] == result["notices"]
    for body, status, message in (
        ({"prompt": "!!! ..."}, 400, "the prompt '!!! ...' has no words"),
        ({"prompt": "走路"}, 422, "prompt: '走路' has no English word"),
        ({"prompt": prompt, "model": "nope"}, 404, "unknown model 'nope'"),
    ):
        refused = client.post("/api/split", json=body)
        assert refused.status_code == status and message in refused.json()["error"], refused.text


def test_streaming_sends_the_queue_and_progress_then_the_result(client):
    answer = client.post("/api/generate", json={"actions": ACTIONS, "options": {"ts": 4}}, headers=NDJSON)
    assert answer.status_code == 200 and answer.headers["content-type"].startswith("application/x-ndjson")
    lines = ndjson(answer.text)
    assert lines[0] == {"queued": 1}
    progress = [line["progress"] for line in lines if "progress" in line]
    assert progress == sorted(progress) and 0 < progress[0] and progress[-1] == 1.0
    assert set(lines[-1]) == {"result"} and len(lines[-1]["result"]["joints"]) == 56


def test_downloads_are_by_id_and_name_the_bvh_parses_and_the_gif_is_drawn_on_demand(client, trained_project):
    result = generate(client, seed=5)
    directory = trained_project / "runs/tiny/generate" / result["id"]
    assert json.loads((directory / "run.json").read_text())["status"] == "finished"
    assert not (directory / "motion.gif").exists()
    gif = client.get(result["files"]["gif"])
    assert gif.status_code == 200 and gif.content[:6] == b"GIF89a" and (directory / "motion.gif").exists()
    bvh_answer = client.get(result["files"]["bvh"])
    (trained_project / "served.bvh").write_bytes(bvh_answer.content)
    bvh = parse_bvh(trained_project / "served.bvh")
    positions, _ = bvh_forward_kinematics(bvh)
    joints = np.array(result["joints"])
    assert np.abs(positions[:, in_skeleton_order(bvh, T2M)] - joints).max() < 1e-3  # millimetres
    import mlflow

    mlflow.set_tracking_uri(f"sqlite:///{trained_project / 'mlflow.db'}")
    names = {Path(a.path).name for a in mlflow.MlflowClient().list_artifacts(result["mlflow"]["run_id"], "motion")}
    assert {"motion.npy", "motion.bvh", "motion.json", "motion.gif"} <= names
    # the UI's model-training view, where a run's params and files are (MLflow 3 opens on GenAI's)
    assert result["mlflow"]["url"].endswith(f"/runs/{result['mlflow']['run_id']}?workflowType=machine_learning")
    for path in (
        f"/api/generations/{result['id']}/run.json",
        f"/api/generations/{result['id']}/..%2F..%2Fm2d2m%2Flatest",
        "/api/generations/..%2F..%2F..%2Fmlflow.db/motion.npy",
        "/api/generations/20990101-000000-abcd/motion.npy",
    ):
        answer = client.get(path)
        assert answer.status_code == 404 and set(answer.json()) == {"error"}, path


def test_a_results_delivery_comes_back_as_json(client):
    """Issue 53, finding 8: ``settings.delivery`` came back as a Python repr string, not JSON."""
    result = generate(client, seed=3, fps=30.0, root="in-place", loop=False, plant_feet=True)
    assert result["settings"]["delivery"] == {
        "fps": 30.0,
        "root": "in-place",
        "loop": False,
        "plant_feet": True,
        "rest_pose": "skeleton",
        "rig": None,
        "joint_map": None,
        "rest_frame": None,
    }


def test_a_clip_is_delivered_as_asked_and_comes_as_a_glb(client, trained_project):
    """Issue 40: the frame rate, the root, the loop and the feet, as `m2d2m generate` takes them."""
    result = generate(client, seed=3, fps=30.0, root="in-place", loop=False, plant_feet=True)
    joints = np.array(result["joints"])
    assert result["fps"] == 30.0 and len(joints) == 84  # 2.8 s of actions: 56 frames at 20 fps, 84 at 30
    assert np.abs(joints[:, 0, [0, 2]]).max() < 1e-5  # in place
    glb = client.get(result["files"]["glb"])
    assert glb.status_code == 200 and glb.content[:4] == b"glTF"
    raw = generate(client, seed=3, plant_feet=False)
    planted = generate(client, seed=3)
    # the feet fix is on by default for a generated clip (it moves only feet that slide, so its
    # figures, not a change of joints, say that it ran)
    assert "skating" not in raw["quality"] and planted["quality"]["skating"] <= planted["quality"]["skating_before_fix"]
    refused = client.post("/api/generate", json={"actions": ACTIONS, "root": "floating"})
    assert refused.status_code == 400 and "root must be one of keep, in-place, ground" in refused.json()["error"]


def test_a_generation_downloads_on_an_uploaded_rig(client, trained_project):
    """Issue 40 §2, §5: a person uploads their character's BVH, or its GLB, and gets the clip on it."""
    from m2d2m.motion.files.bvh_reader import read_bvh
    from m2d2m.motion.rigs.retarget import Rig
    from tests.test_bvh_reader import CMU
    from tests.test_retarget import cmu_rig_as_glb

    rig = (CMU / "131_01.bvh").read_bytes()
    uploaded = client.post("/api/rigs", content=rig, headers={"Content-Type": "application/octet-stream"})
    assert uploaded.status_code == 200, uploaded.text
    assert uploaded.json()["joints"] == 31 and uploaded.json()["joint_map"] == "cmu"
    assert client.post("/api/rigs", content=rig).json()["id"] == uploaded.json()["id"]  # kept by its bytes
    result = generate(client, seed=4)
    answer = client.get(result["files"]["bvh"], params={"rig": uploaded.json()["id"]})
    assert answer.status_code == 200
    (trained_project / "on-rig.bvh").write_bytes(answer.content)
    on_rig = read_bvh(trained_project / "on-rig.bvh")
    assert on_rig.names == read_bvh(CMU / "131_01.bvh").names and len(on_rig.values) == len(result["joints"])
    for content, params, status, message in (
        (b"HIERARCHY nothing", {}, 400, "the rig cannot take our motions: "),
        (b"", {}, 400, "the rig is empty"),
        (rig, {"joint_map": "robot"}, 400, "joint_map must be one of cmu, cmu-motionbuilder, mixamo, smpl"),
        (rig, {"joint_map": "mixamo"}, 400, "the rig cannot take our motions: joint map mixamo reads"),
    ):
        refused = client.post("/api/rigs", content=content, params=params)
        assert refused.status_code == status and message in refused.json()["error"], refused.text
    unknown = client.get(result["files"]["bvh"], params={"rig": "0" * 16})
    assert unknown.status_code == 404 and "upload it with POST /api/rigs" in unknown.json()["error"]
    gif = client.get(result["files"]["gif"], params={"rig": uploaded.json()["id"]})
    assert gif.status_code == 400 and "a rig goes with the BVH" in gif.json()["error"]
    cmu_rig_as_glb(trained_project / "cmu.glb", Rig.from_bvh(read_bvh(CMU / "131_01.bvh")))
    character = client.post("/api/rigs", content=(trained_project / "cmu.glb").read_bytes())
    assert character.status_code == 200 and character.json()["joint_map"] == "cmu", character.text
    answer = client.get(result["files"]["bvh"], params={"rig": character.json()["id"]})
    (trained_project / "on-glb.bvh").write_bytes(answer.content)
    assert read_bvh(trained_project / "on-glb.bvh").names == on_rig.names
    glb = client.get(result["files"]["glb"], params={"rig": character.json()["id"]})
    assert glb.status_code == 200, glb.text
    (trained_project / "on-glb.glb").write_bytes(glb.content)
    names = [node.name for node in pygltflib.GLTF2.load(str(trained_project / "on-glb.glb")).nodes]
    assert names[0] == "Armature" and set(on_rig.names) <= set(names)  # the character's file itself


LONG = "a person " + "walks " * 1700


@pytest.mark.parametrize(
    "body, status, message",
    [
        ({"model": "nope"}, 404, "unknown model 'nope'; this server has m2d2m"),
        ({"run": "../../mlflow.db"}, 404, "m2d2m has no finished run '../../mlflow.db'"),
        ({"options": {"temperature": 1}}, 400, "m2d2m has no sampling option 'temperature'"),
        ({"options": {"eta": "high"}}, 400, "option eta must be a finite number, got 'high'"),
        ({"options": {"eta": [1]}}, 422, "options.eta: a knob's value is a number, a text or null, got [1]"),
        ({"options": {"eta": True}}, 422, "options.eta: a knob's value is a number, a text or null"),
        ({"options": {"eta": -1}}, 400, "option eta must be [0, 100], got -1"),
        ({"options": {"ts": 9}}, 400, "T_s must lie in 0..T = 8"),
        ({"method": "blend"}, 400, "unknown method 'blend' for m2d2m"),
        ({"actions": None}, 422, "give either actions"),
        ({"actions": []}, 422, "actions: List should have at least 1 item"),
        ({"actions": [{"text": "a person jumps", "seconds": 0}]}, 400, "0 s for 'a person jumps' is outside"),
        ({"actions": [{"text": "a person jumps", "seconds": 600}]}, 400, "600 s for 'a person jumps' is outside"),
        ({"actions": [{"text": LONG}]}, 422, "actions.0.text: String should have at most 500 characters"),
        ({"actions": [{"text": "   "}]}, 400, "an action's text is empty"),
        ({"actions": [{"text": "!!! ..."}]}, 400, "the prompt '!!! ...' has no words"),
        ({"actions": [{"text": "a person jumps", "seconds": 4}] * 16}, 400, "over the 60-s cap"),
        ({"prompt": "a person jumps"}, 422, "give either actions"),
        ({"seconds": 3}, 422, "seconds goes with prompt"),
        ({"seed": -1}, 422, "seed: Input should be greater than or equal to 0"),
        ({"speed": 2}, 422, "speed: Extra inputs are not permitted"),
        # loose types were read as numbers ("3" as 3 s, true as 1 s, 1.0 as seed 1): refused now
        ({"actions": [{"text": "a person jumps", "seconds": "3"}]}, 422, "actions.0.seconds: Input should be"),
        ({"actions": [{"text": "a person jumps", "seconds": True}]}, 422, "actions.0.seconds: Input should be"),
        ({"seed": 1.0}, 422, "seed: Input should be a valid integer"),
        # text no model reads made a motion of nothing it said
        ({"actions": [{"text": "🕺💃"}]}, 422, "actions.0.text: '🕺💃' has no English word"),
        ({"actions": [{"text": "跳舞"}]}, 422, "has no English word; the models read English sentences"),
        ({"actions": [{"text": "a person\u0000 jumps"}]}, 422, "holds the control character U+0000"),
        ({"actions": None, "prompt": "走路"}, 422, "prompt: '走路' has no English word"),
        # the cap's advice names the API's fields, not the command line's flags
        ({"actions": [{"text": "a person jumps", "seconds": 4}] * 16}, 400, "give fewer actions or shorter seconds"),
    ],
)
def test_bad_input_is_a_4xx_with_one_sentence(client, body, status, message):
    answer = client.post("/api/generate", json={"actions": ACTIONS, **body})
    assert answer.status_code == status, answer.text
    assert set(answer.json()) == {"error"} and message in answer.json()["error"]
    assert "\n" not in answer.json()["error"] and "Traceback" not in answer.text


def test_the_bvh_comes_on_a_tpose_when_asked_and_the_page_gets_the_sides_and_the_head(client, trained_project):
    """Issue 38, item 13: a T-pose bind pose on the page and in the API, the motion unchanged."""
    result = generate(client, seed=6)
    assert result["head_joint"] == T2M.head_joint == 15
    assert (result["left_joints"], result["right_joints"]) == (list(T2M.left_joints), list(T2M.right_joints))
    answer = client.get(result["files"]["bvh"] + "?rest=tpose")
    assert answer.status_code == 200
    assert answer.headers["content-disposition"].endswith(f'filename="{result["id"]}-motion.tpose.bvh"')
    (trained_project / "tpose.bvh").write_bytes(answer.content)
    bvh = parse_bvh(trained_project / "tpose.bvh")
    wrist = bvh.offsets[bvh.names.index("right_wrist")]
    assert wrist[0] < 0 and abs(wrist[1]) < 1e-9  # the right arm out along -X
    positions, _ = bvh_forward_kinematics(bvh)
    assert np.abs(positions[:, in_skeleton_order(bvh, T2M)] - np.array(result["joints"])).max() < 1e-3
    refused = client.get(result["files"]["bvh"] + "?rest=apose")
    assert refused.status_code == 400 and refused.json() == {
        "error": "rest must be one of skeleton, tpose, got 'apose'"
    }


def test_a_body_that_is_not_json_or_too_large_is_a_4xx(client):
    answer = client.post("/api/generate", content=b"{not json", headers={"content-type": "application/json"})
    assert answer.status_code == 422 and answer.json()["error"].startswith("the body is not JSON")
    answer = client.post("/api/generate", content=b" " * (2 << 20), headers={"content-type": "application/json"})
    assert answer.status_code == 413 and "at most" in answer.json()["error"]
    assert client.get("/api/nothing-here").status_code == 404


def test_health_and_the_page_and_the_documentation(client):
    health = client.get("/api/health").json()
    assert health["status"] == "ok" and {"queued", "running", "served", "batches", "cancelled"} <= set(health)
    page = client.get("/")
    assert page.status_code == 200
    files = sorted(STATIC.iterdir())
    assert {f.name for f in files} >= {"index.html", "app.js", "player.js", "editor.js", "style.css"}
    for path in files:  # nothing from another origin
        text = path.read_text(encoding="utf-8")
        assert not re.search(r"(src|href)\s*=\s*[\"']?(https?:)?//|@import|url\(\s*['\"]?https?:", text), path.name
    for script in ("player.js", "editor.js", "app.js"):
        assert f'<script src="/static/{script}"></script>' in page.text
    assert client.get("/openapi.json").json()["paths"].keys() >= {"/api/generate", "/api/models", "/api/health"}
    assert client.get("/docs").status_code == 200


def test_every_api_operation_is_a_module_level_route_of_one_router_per_job(tmp_path, monkeypatch):
    """issue 55 §3: the API's routes live in one APIRouter per job (orchestration/web/routers/),
    each a module-level function that reaches the application's state through a dependency, not a
    closure inside create_app, and together they are exactly the operations /openapi.json lists."""
    monkeypatch.chdir(tmp_path)
    listed = {
        (path, method.upper())
        for path, operations in create_app(ServeSettings()).openapi()["paths"].items()
        for method in operations
    }
    routed = {
        ("/api" + route.path, method) for router in API_ROUTERS for route in router.routes for method in route.methods
    }
    assert routed == listed and len(listed) == 11
    closures = [route.endpoint.__qualname__ for router in API_ROUTERS for route in router.routes]
    assert [name for name in closures if "<locals>" in name] == []


def test_a_token_guards_every_api_call_and_only_loopback_goes_without(trained_project, monkeypatch):
    with TestClient(create_app(ServeSettings(dataset="tiny", token="s3cret-token"))) as client:
        assert client.get("/api/health").status_code == 401
        assert client.get("/api/models", headers={"Authorization": "Bearer wrong-token"}).status_code == 401
        answer = client.post("/api/generate", json={"actions": ACTIONS})
        assert answer.status_code == 401 and "token" in answer.json()["error"]
        good = {"Authorization": "Bearer s3cret-token"}
        assert client.get("/api/health", headers=good).status_code == 200
        result = client.post("/api/generate", json={"actions": ACTIONS, "options": {"ts": 4}}, headers=good).json()
        assert client.get(result["files"]["bvh"]).status_code == 401
        assert client.get(result["files"]["bvh"] + "?token=s3cret-token").status_code == 200
        assert client.get("/").status_code == 200  # the page itself holds nothing; it asks for the token
    monkeypatch.delenv("M2D2M_SERVE_TOKEN", raising=False)
    assert server_token("127.0.0.1", None) is None
    with pytest.raises(UserError, match="--host 0.0.0.0 opens the API beyond this machine"):
        server_token("0.0.0.0", None)
    monkeypatch.setenv("M2D2M_SERVE_TOKEN", "from-the-environment")
    assert server_token("0.0.0.0", None) == "from-the-environment"
    assert server_token("0.0.0.0", "given-on-the-line") == "given-on-the-line"


def test_serving_beyond_loopback_without_a_token_is_one_line_and_exit_2(trained_project, capsys, monkeypatch):
    monkeypatch.delenv("M2D2M_SERVE_TOKEN", raising=False)
    assert main(["serve", "--host", "0.0.0.0", "--port", str(free_port()), "--dataset", "tiny"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "give --token or set M2D2M_SERVE_TOKEN" in err


def test_concurrent_requests_are_sampled_in_one_batch_each_as_it_would_be_alone(trained_project):
    seeds = [11, 12, 13, 14]
    alone = {}
    with live_server(ServeSettings(dataset="tiny", gather_s=0.0, track=False)) as (base, app):
        for seed in seeds:
            alone[seed] = httpx.post(
                f"{base}/api/generate", json={"actions": ACTIONS, "options": {"ts": 4}, "seed": seed}, timeout=60
            ).json()
        assert app.state.service.sampler.stats().largest_batch == 1
    with live_server(ServeSettings(dataset="tiny", gather_s=1.0, track=False)) as (base, app):
        answers: dict[int, dict] = {}

        def ask(seed: int) -> None:
            body = {"actions": ACTIONS, "options": {"ts": 4}, "seed": seed}
            answers[seed] = httpx.post(f"{base}/api/generate", json=body, timeout=60).json()

        threads = [threading.Thread(target=ask, args=(seed,)) for seed in seeds]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        stats = app.state.service.sampler.stats()
    assert stats.batches == 1 and stats.largest_batch == 4 and stats.served == 4
    for seed in seeds:
        assert np.allclose(answers[seed]["joints"], alone[seed]["joints"], atol=1e-4), seed
    assert not np.allclose(answers[11]["joints"], answers[12]["joints"], atol=1e-3)


def test_a_full_queue_answers_429_and_a_client_that_leaves_cancels_its_work(trained_project):
    settings = ServeSettings(dataset="tiny", queue=1, gather_s=2.0, track=False)
    with live_server(settings) as (base, app):
        body = {"actions": ACTIONS, "options": {"ts": 4}}
        with httpx.stream("POST", f"{base}/api/generate", json=body, headers=NDJSON, timeout=60) as waiting:
            assert json.loads(next(waiting.iter_lines())) == {"queued": 1}
            refused = httpx.post(f"{base}/api/generate", json=body, timeout=60)
            assert refused.status_code == 429 and "waiting already" in refused.json()["error"]
        # the first client left while its request waited: it is dropped, never sampled
        deadline = time.monotonic() + 30
        while app.state.service.sampler.stats().cancelled < 1:
            assert time.monotonic() < deadline, app.state.service.sampler.stats()
            time.sleep(0.1)
        stats = app.state.service.sampler.stats()
        assert stats.served == 0 and stats.queued == 0
        # the same for a plain (not streamed) request whose client hangs up
        payload = json.dumps(body).encode()
        with socket.create_connection(("127.0.0.1", int(base.rsplit(":", 1)[1]))) as raw:
            raw.sendall(
                b"POST /api/generate HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                + f"Content-Length: {len(payload)}\r\n\r\n".encode()
                + payload
            )
            time.sleep(0.5)
        while app.state.service.sampler.stats().cancelled < 2:
            assert time.monotonic() < deadline + 30, app.state.service.sampler.stats()
            time.sleep(0.1)
        assert app.state.service.sampler.stats().served == 0


# ``python -c HELD sampling go argv...``: ``m2d2m argv`` whose sampler, at its first batch, touches
# the file ``sampling`` and samples only once the file ``go`` exists: a request is then in flight
# when the test sends its signal, however fast the machine samples
HELD = """
import pathlib, sys, time
from orchestration.web.sampler import Sampler
generate = Sampler._generate
def held(self, batch):
    pathlib.Path(sys.argv[1]).touch()
    while not pathlib.Path(sys.argv[2]).exists():
        time.sleep(0.01)
    return generate(self, batch)
Sampler._generate = held
from orchestration.cli import main
sys.exit(main(sys.argv[3:]))
"""


def test_sigterm_answers_the_request_in_flight_then_exits_leaving_nothing(trained_project, tmp_path):
    port = free_port()
    sampling, go = tmp_path / "sampling", tmp_path / "go"
    server = subprocess.Popen(
        [sys.executable, "-c", HELD, str(sampling), str(go), "serve", "--dataset", "tiny", "--port", str(port)],
        cwd=trained_project,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])},
    )
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            try:
                if httpx.get(f"{base}/api/health", timeout=5).status_code == 200:
                    break
            except httpx.TransportError:
                assert server.poll() is None and time.monotonic() < deadline, server.stdout.read().decode()
                time.sleep(0.2)
        body = {"actions": ACTIONS, "options": {"ts": 8, "steps": 8}}
        with httpx.stream("POST", f"{base}/api/generate", json=body, headers=NDJSON, timeout=120) as answer:
            lines = answer.iter_lines()
            assert "queued" in json.loads(next(lines))
            while not sampling.exists():  # the sampler holds the request: it cannot be answered yet
                assert server.poll() is None and time.monotonic() < deadline + 120, "the request was never sampled"
                time.sleep(0.01)
            server.send_signal(signal.SIGTERM)
            go.touch()
            rest = [json.loads(line) for line in lines]
        assert "result" in rest[-1], rest[-1]
        assert server.wait(timeout=60) == 0
        printed = server.stdout.read().decode()
        assert "stopped: the requests in flight were answered" in printed and "Traceback" not in printed
        with pytest.raises(OSError):
            socket.create_connection(("127.0.0.1", port), timeout=2).close()
        assert not [
            p for p in psutil.process_iter(["cmdline"]) if f"--port {port}" in " ".join(p.info["cmdline"] or [])
        ]
    finally:
        if server.poll() is None:
            server.kill()


def test_a_generation_is_edited_on_its_timeline(client, trained_project):
    """Issue 41 §2: four actions, the third regenerated with new text (the other actions' features
    bit for bit outside the margins, the parent in the MLflow run), a gap filled, a pose pinned,
    an action added; a bad edit is a 4xx sentence."""
    from orchestration.tracking import client as mlflow_client

    four = [
        {"text": text, "seconds": 1.2}
        for text in ("a person walks", "a person jumps", "a person waves", "a person sits")
    ]
    parent = generate(client, actions=four, seed=2)
    edit_url = f"/api/generations/{parent['id']}/edit"
    answer = client.post(
        edit_url, json={"operation": "regenerate", "action": 3, "text": "a person kicks", "options": {"ts": 4}}
    )
    assert answer.status_code == 200, answer.text
    redone = answer.json()
    assert [a["text"] for a in redone["actions"]] == [
        "a person walks",
        "a person jumps",
        "a person kicks",
        "a person sits",
    ]
    assert redone["settings"]["edit_parent"] == parent["id"]
    originals = {}
    for name, generation in (("parent", parent), ("redone", redone)):
        (trained_project / f"{name}.features.npy").write_bytes(client.get(generation["files"]["features"]).content)
        originals[name] = np.load(trained_project / f"{name}.features.npy")
    first, end = redone["actions"][2]["first"], redone["actions"][2]["end"]
    np.testing.assert_array_equal(originals["redone"][: first - 8], originals["parent"][: first - 8])
    np.testing.assert_array_equal(originals["redone"][end + 8 :], originals["parent"][end + 8 :])
    run = mlflow_client().get_run(redone["mlflow"]["run_id"])
    assert run.data.tags["mlflow.parentRunId"] == parent["mlflow"]["run_id"]
    for body in (
        {"operation": "fill", "then": redone["id"], "seconds": 0.8},
        {"operation": "pin", "pose": {"generation": redone["id"], "frame": 4}, "at": 2.0},
        {"operation": "continue", "actions": [{"text": "a person stands up", "seconds": 1.2}]},
    ):
        answer = client.post(edit_url, json={**body, "options": {"ts": 4}})
        assert answer.status_code == 200, (body, answer.text)
    for body, status, message in (
        ({"operation": "regenerate", "action": 9}, 400, "action 9 of a result with 4 action(s)"),
        ({"operation": "regenerate"}, 422, "regenerate names the action"),
        ({"operation": "regenerate", "action": 1, "at": 1.0}, 422, "at does not go with the operation regenerate"),
        ({"operation": "fill", "then": "nowhere"}, 404, "no generation 'nowhere' on this server"),
        ({"operation": "pin", "pose": {"generation": parent["id"], "frame": 999}, "at": 1.0}, 400, "has frames 0 to"),
        (
            {"operation": "pin", "pose": {"generation": parent["id"], "frame": 1}, "at": 99.0},
            400,
            "lies outside the motion",
        ),
        ({"operation": "layer", "part": "upper"}, 422, "layer names the body part, its text and its span"),
        (
            {"operation": "layer", "part": "upper", "text": "a person waves", "span": [0.4, 1.6]},
            400,
            "m2d2m keeps whole frames, not a body part alone",
        ),
        ({"operation": "dance"}, 422, "operation"),
    ):
        refused = client.post(edit_url, json=body)
        assert refused.status_code == status and message in refused.json()["error"], (body, refused.text)
    unknown = client.post("/api/generations/nowhere/edit", json={"operation": "regenerate", "action": 1})
    assert unknown.status_code == 404

    # a motion made elsewhere (here: the parent's features file) uploaded, then edited like a generation
    features = (trained_project / "parent.features.npy").read_bytes()
    actions = [{"text": a["text"], "seconds": 1.2} for a in four[:3]] + [{"text": four[3]["text"]}]
    answer = client.post("/api/generations", json={"motion": base64.b64encode(features).decode(), "actions": actions})
    assert answer.status_code == 200, answer.text
    uploaded = answer.json()
    assert "skating" not in uploaded["quality"]  # a motion made elsewhere: its feet kept as sent, not fixed
    assert [a["text"] for a in uploaded["actions"]] == [a["text"] for a in four]
    assert [(a["first"], a["end"]) for a in uploaded["actions"]] == [(a["first"], a["end"]) for a in parent["actions"]]
    answer = client.post(f"/api/generations/{uploaded['id']}/edit", json={"operation": "regenerate", "action": 2})
    assert answer.status_code == 200 and answer.json()["settings"]["edit_parent"] == uploaded["id"], answer.text
    for body, message in (
        ({"motion": "not base64!", "actions": actions}, "motion: not base64"),
        (
            {"motion": base64.b64encode(b"junk").decode(), "actions": actions},
            "the uploaded motion: not a readable .npy",
        ),
        (
            {
                "motion": base64.b64encode(features).decode(),
                "actions": [{"text": "a person walks", "seconds": 4.0}] * 2,
            },
            "its actions' seconds add up to more than its",
        ),
    ):
        refused = client.post("/api/generations", json=body)
        assert refused.status_code == 400 and message in refused.json()["error"], refused.text


def test_a_looped_generation_is_edited_on_the_timeline_it_shows(client, trained_project):
    """Issue 53 §1 through the API: a loop's features file holds its cycle's frames, as its joints
    do; action 2 regenerated gives a loop as long, each action as long, the other frames' features
    the loop's outside the action's margins; a pose copied from frame F of the loop is that frame's
    (pinned at F, the result meets it there); a pin past the loop's end is a 400 sentence."""
    three = [{"text": text, "seconds": 3.0} for text in ("a person walks", "a person jumps", "a person waves")]
    loop = generate(client, actions=three, seed=2, loop=True)

    def is_loop(generation: dict) -> bool:
        return client.get(generation["files"]["json"]).json().get("loop", False)

    def features(generation: dict) -> np.ndarray:
        path = trained_project / f"{generation['id']}.features.npy"
        path.write_bytes(client.get(generation["files"]["features"]).content)
        return np.load(path)

    looped = features(loop)
    count = len(loop["joints"])
    assert len(looped) == count and loop["actions"][-1]["end"] == count and is_loop(loop)
    edit_url = f"/api/generations/{loop['id']}/edit"
    answer = client.post(edit_url, json={"operation": "regenerate", "action": 2, "options": {"ts": 4}})
    assert answer.status_code == 200, answer.text
    redone = answer.json()
    assert len(redone["joints"]) == count and is_loop(redone)
    assert [(a["first"], a["end"]) for a in redone["actions"]] == [(a["first"], a["end"]) for a in loop["actions"]]
    first, end = loop["actions"][1]["first"], loop["actions"][1]["end"]
    kept = np.ones(count, dtype=bool)
    kept[np.arange(first - 11, end + 11) % count] = False  # 0.4 s each side, widened to whole tokens
    np.testing.assert_array_equal(features(redone)[kept], looped[kept])
    frame = count - 10
    pin = {
        "operation": "pin",
        "pose": {"generation": loop["id"], "frame": frame},
        "at": frame / 20,
        "options": {"ts": 4},
    }
    answer = client.post(edit_url, json=pin)
    assert answer.status_code == 200, answer.text
    shape = slice(3, 4 + 21 * 9)  # root height, joints around the root, rotations
    np.testing.assert_allclose(features(answer.json())[frame, shape], looped[frame, shape], atol=1e-5)
    refused = client.post(edit_url, json={**pin, "at": count / 20 + 1})
    assert refused.status_code == 400 and f"outside the motion's {count / 20:g} s" in refused.json()["error"]
