"""Issue 53 §3, §4, §6: every route of `m2d2m serve` that samples (generate, edit, upload to edit)
has the same limits in the same sentences; a motion that is no body is refused in one line before
any arithmetic; a rate travels with a motion (an upload says which it read, a pose's frame is
counted at the rate its clip was delivered at); and a seeded fuzz over every route gets a 4xx
sentence or an answer for every malformed request, never a 500."""

from __future__ import annotations

import base64
import io
import json
import re
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import TimeoutError as NotAnswered
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from fastapi.testclient import TestClient

from m2d2m.motion.clip import Motion
from m2d2m.motion.representation.features import joints_to_features
from m2d2m.motion.representation.skeleton import T2M
from m2d2m.motion.transforms.retime import resample
from orchestration.cli import main
from orchestration.errors import UserError
from orchestration.viewing import load_features
from orchestration.web.app import ServeSettings, create_app
from orchestration.web.edits import model_frame
from orchestration.web.generations import Generation
from tests.conftest import HUMANML3D_SAMPLE
from tests.test_bvh_reader import CMU

ACTIONS = [{"text": "a person walks forward", "seconds": 1.6}, {"text": "a person jumps", "seconds": 1.2}]
QUICK = {"ts": 4}
CAP = 6.0  # the server's --max-seconds here: the tiny model's actions last up to 4.8 s
WALK = np.load(HUMANML3D_SAMPLE / "new_joints" / "012314.npy")  # 170 frames at 20 fps, metres


def npy(array: np.ndarray) -> str:
    """A .npy file's bytes in base64, as an upload sends them."""
    buffer = io.BytesIO()
    np.save(buffer, array)
    return base64.b64encode(buffer.getvalue()).decode()


@pytest.fixture(scope="module")
def client(trained_project):
    settings = ServeSettings(dataset="tiny", track=False, max_seconds=CAP)
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        yield client


@pytest.fixture(scope="module")
def parent(client) -> dict:
    answer = client.post("/api/generate", json={"actions": ACTIONS, "options": QUICK})
    assert answer.status_code == 200, answer.text
    return answer.json()


def refusal(answer) -> str:
    """The one sentence of a 4xx answer."""
    assert 400 <= answer.status_code < 500, answer.text
    assert set(answer.json()) == {"error"} and "\n" not in answer.json()["error"], answer.text
    return answer.json()["error"]


# ------------------------------------------------------------------------- §3: the same limits
OUTSIDE = "is outside what this model supports (0.2–4.8 s per action)"
OVER_THE_CAP = "over the 6-s cap; give fewer actions or shorter seconds (the cap is the server's"


def test_an_edit_has_the_limits_of_a_generation_in_the_same_sentences(client, parent):
    """A `continue` of 600 s was accepted (a 602.8-s clip), `seconds: 0.01` sampled as 0.2 s: now
    each is the sentence POST /api/generate answers for the same length, and so is the cap on the
    whole clip."""
    generated = refusal(client.post("/api/generate", json={"actions": [{"text": "a person walks", "seconds": 600}]}))
    assert generated == f"600 s for 'a person walks' {OUTSIDE}"
    edit = f"/api/generations/{parent['id']}/edit"
    for body, message in (
        ({"operation": "continue", "actions": [{"text": "a person walks", "seconds": 600}]}, generated),
        ({"operation": "regenerate", "action": 1, "seconds": 0.01}, f"0.01 s for action 1 {OUTSIDE}"),
        ({"operation": "fill", "then": parent["id"], "seconds": 0.01}, f"0.01 s for the gap {OUTSIDE}"),
        ({"operation": "pin", "pose": {"generation": parent["id"], "frame": 4}, "at": 1e308}, "lies outside"),
        ({"operation": "continue", "actions": [{"text": "a person walks", "seconds": 3.6}]}, OVER_THE_CAP),
        ({"operation": "regenerate", "action": 1, "options": {"guidance": 1e300}}, "guidance must be [0, 20]"),
    ):
        assert message in refusal(client.post(edit, json={**body, "options": body.get("options", QUICK)})), body
    too_long = [{"text": "a person walks", "seconds": 3.6}, {"text": "a person jumps", "seconds": 2.8}]
    assert OVER_THE_CAP in refusal(client.post("/api/generate", json={"actions": too_long}))
    answer = client.post(edit, json={"operation": "regenerate", "action": 2, "seconds": 2.0, "options": QUICK})
    assert answer.status_code == 200 and answer.json()["seconds"] == pytest.approx(3.6), answer.text


def test_an_upload_has_the_limits_of_a_generation(client):
    """An uploaded motion is edited as a generation: its actions' seconds and its length are held
    to the same limits, in the same sentences."""
    walk = npy(WALK[:100])  # 4.95 s of features
    for actions, message in (
        ([{"text": "a person walks", "seconds": 600}], f"600 s for 'a person walks' {OUTSIDE}"),
        ([{"text": "a person walks", "seconds": 0.01}, {"text": "a person jumps"}], "0.01 s for 'a person walks'"),
    ):
        assert message in refusal(client.post("/api/generations", json={"motion": walk, "actions": actions}))
    answer = client.post("/api/generations", json={"motion": npy(WALK), "actions": [{"text": "a person walks"}]})
    assert OVER_THE_CAP in refusal(answer)  # its 8.45 s


def test_the_command_line_edit_has_the_same_limits(client, parent, capsys):
    """`m2d2m generate --edit … --continue … --seconds 600` samples no 600-s action either."""
    source = Path("runs/tiny/generate") / parent["id"] / "motion.npy"
    argv = ["generate", "--edit", str(source), "--dataset", "tiny", "--no-track", "--ts", "4", "--formats", "npy"]
    assert main([*argv, "--continue", "a person walks", "--seconds", "600"]) == 2
    assert f"600 s for 'a person walks' {OUTSIDE}" in capsys.readouterr().err
    assert main([*argv, "--continue", "a person walks", "--seconds", "4", "--max-seconds", "6"]) == 2
    assert "over the 6-s cap" in capsys.readouterr().err


# ------------------------------------------------------------------ §4: motion that is no body
DEGENERATE = {
    "all-zero joints": (np.zeros((60, 22, 3), np.float32), "have no length (joints on one point)"),
    "joints in micrometres": (WALK[:60] * 1e6, "the body is 1e+06× the size of the t2m skeleton's"),
    "joints with a NaN": (np.where(np.arange(60)[:, None, None] == 9, np.nan, WALK[:60]), "NaN or infinite"),
    "one frame of joints": (WALK[:1], "a motion needs at least two"),
    "all-zero features": (np.zeros((60, 263), np.float32), "have no length (joints on one point)"),
    "features of 1e6": (np.full((60, 263), 1e6, np.float32), "which no body's features do"),
    "no frames": (np.zeros((0, 263), np.float32), "has no frames"),
    "text": (np.array(["a", "b"]), "values, not numbers"),
}


@pytest.mark.parametrize("name", DEGENERATE)
def test_a_motion_that_is_no_body_is_one_line_before_any_arithmetic(name, monkeypatch):
    """The all-zero joints reached HumanML3D's processing and divided by zero (a 500): every such
    motion is refused where it is read, with the features' or joints' arithmetic never called."""
    array, message = DEGENERATE[name]

    def never(*args, **kwargs):
        raise AssertionError("a motion that is no body reached HumanML3D's processing")

    monkeypatch.setattr("orchestration.viewing.joints_to_features", never)
    with pytest.raises(UserError, match=r"^the upload: .*" + re.escape(message)):
        load_features(base64.b64decode(npy(array)), T2M, "the upload")


def test_a_real_body_reads_as_before():
    features = load_features(base64.b64decode(npy(WALK)), T2M, "the upload")
    np.testing.assert_array_equal(features, joints_to_features(WALK, T2M))


def test_degenerate_uploads_are_400s(client):
    for name, (array, message) in DEGENERATE.items():
        answer = client.post("/api/generations", json={"motion": npy(array), "actions": [{"text": "a person walks"}]})
        assert message in refusal(answer), name


# -------------------------------------------------------------------- §6: a rate with every motion
def test_an_upload_takes_its_rate_and_says_which_it_read(client):
    """4 s of HumanML3D's walk at 30 fps was read as 20 fps (6 s, played 1.5× slower, no word of
    it): given its fps it is resampled to the model's 20 and lasts its 4 s; without, the answer
    says it was read at the model's rate."""
    at_30 = resample(WALK[:80], T2M, 20, 30)  # 120 frames
    actions = [{"text": "a person walks"}]
    answer = client.post("/api/generations", json={"motion": npy(at_30), "fps": 30.0, "actions": actions})
    assert answer.status_code == 200, answer.text
    read = answer.json()
    assert read["source_fps"] == 30.0 and read["notices"] == [] and read["fps"] == 20.0
    assert read["seconds"] == pytest.approx(76 / 20)  # 79 features (one fewer than joints), whole 4-frame steps
    assumed = client.post("/api/generations", json={"motion": npy(at_30), "actions": actions}).json()
    assert assumed["source_fps"] == 20.0 and assumed["seconds"] == pytest.approx(116 / 20)  # 1.5× as long
    assert assumed["notices"] == ["the motion was read at 20 fps, the model's rate: give fps if it was made at another"]
    refused = client.post("/api/generations", json={"motion": npy(at_30), "fps": 0.5, "actions": actions})
    assert "fps must be a frame rate from 1 to 1000 frames per second" in refusal(refused)


def test_a_pose_is_counted_at_the_rate_its_clip_was_delivered_at(client):
    """A clip delivered at 30 fps has 84 frames (2.8 s); its frame 70 (2.33 s) was refused as
    past the model's 56, and any frame was read as a 20-fps one."""
    at_30 = client.post("/api/generate", json={"actions": ACTIONS, "options": QUICK, "fps": 30.0}).json()
    assert len(at_30["joints"]) == 84
    edit = f"/api/generations/{at_30['id']}/edit"
    pin = {"operation": "pin", "at": 1.0, "options": QUICK, "fps": 30.0}
    answer = client.post(edit, json={**pin, "pose": {"generation": at_30["id"], "frame": 70}})
    assert answer.status_code == 200, answer.text
    past = client.post(edit, json={**pin, "pose": {"generation": at_30["id"], "frame": 84}})
    assert refusal(past) == f"generation {at_30['id']} has frames 0 to 83 at its 30 fps, not 84"


def test_the_command_line_edits_a_delivered_npy_at_its_own_rate(client, trained_project, capsys):
    """`generate --edit motion.npy` of a clip delivered at 30 fps, without its features beside it:
    its joints were read as 20-fps ones (2.8 s became 4 s, its actions from the sidecar at 30 fps
    in the wrong places); read at the sidecar's rate it stays 2.8 s (2.6 s in whole 4-frame steps)."""
    at_30 = client.post("/api/generate", json={"actions": ACTIONS, "options": QUICK, "fps": 30.0}).json()
    source = trained_project / "delivered-at-30"
    source.mkdir()
    for name in ("motion.npy", "motion.json"):
        (source / name).write_bytes((Path("runs/tiny/generate") / at_30["id"] / name).read_bytes())
    out = trained_project / "edited-at-30"
    argv = ["generate", "--edit", str(source / "motion.npy"), "--regenerate", "1", "--out", str(out)]
    assert main([*argv, "--dataset", "tiny", "--no-track", "--ts", "4", "--formats", "npy"]) == 0, capsys.readouterr()
    edited = json.loads((out / "motion.json").read_text(encoding="utf-8"))
    assert edited["fps"] == 20.0 and edited["num_frames"] == 52
    assert [s["start_frame"] for s in edited["segments"]] == [0, 32]


def test_a_delivered_frame_is_the_model_frame_of_the_same_instant():
    class TwentyFps:
        fps = 20.0

    joints = np.zeros((84, 22, 3), np.float32)
    motion = Motion(np.zeros((56, 263), np.float32), joints, 30.0, "t2m", ["a"], [(0, 84)])
    generation = Generation("g", Path("."), motion, "m2d2m", "r", 0, "", None, None)
    assert [model_frame(generation, frame, TwentyFps()) for frame in (0, 3, 70, 83)] == [0, 2, 47, 55]
    at_20 = replace(generation, motion=replace(motion, joints=joints[:56], fps=20.0, ranges=[(0, 56)]))
    assert [model_frame(at_20, frame, TwentyFps()) for frame in (0, 3, 55)] == [0, 3, 55]
    with pytest.raises(UserError, match="generation g has frames 0 to 83 at its 30 fps, not 84"):
        model_frame(generation, 84, TwentyFps())


# ------------------------------------------------------------------------- the fuzz over every route
NASTY_NUMBERS = [0, -1, 0.01, 1e-300, 600, 1e300, -1e300, 1e308, 2**31, 2**63, 2.5, 4.8, 4.81]
NASTY = [*NASTY_NUMBERS, "", "3", "x" * 600, "🕺", "a person\u0000 walks", "../../etc/passwd", True, None, [], {}]
NASTY += [[1e300], [0.4, 1e308], [-1, 2], {"generation": "nope", "frame": 0}, {"a": {"b": [None]}}]
KNOBS = ["ts", "eta", "guidance", "truncation", "steps", "handshake", "slerp", "method", "nope"]
METHODS = ["tps", "independent", "handshake", "slerp", "blend", 7]


def nasty_motion(rng: np.random.Generator) -> str:
    """A .npy (or not) that no model should sample from, or a real body in a strange form."""
    frames = int(rng.choice([0, 1, 2, 3, 5, 40]))
    choices = [
        lambda: npy(np.zeros((frames, 22, 3), np.float32)),
        lambda: npy(WALK[: max(frames, 2)] * rng.choice([1e-9, 1e-3, 1.0, 1e3, 1e6, 1e30])),
        lambda: npy(np.full((frames, 263), rng.choice([0.0, 1e6, np.nan, np.inf, -1e38]), np.float32)),
        lambda: npy(rng.normal(size=(frames, 263)).astype(np.float32)),
        lambda: npy(rng.normal(size=(40, 22, 3))),
        lambda: npy(rng.integers(-5, 5, size=(40, 22, 3))),
        lambda: npy(np.ones((40, 22, 3), bool)),
        lambda: npy((rng.normal(size=(40, 263)) + 1j).astype(np.complex64)),
        lambda: npy(np.zeros((40, 21, 3), np.float32)),
        lambda: npy(np.float32(1.0)),
        lambda: npy(WALK[:40][::-1].copy()),
        lambda: base64.b64encode(base64.b64decode(npy(WALK[:40]))[:100]).decode(),  # cut short
        lambda: base64.b64encode(b"\x93NUMPY\x01\x00" + bytes(rng.integers(0, 256, 200, dtype=np.uint8))).decode(),
        lambda: "not base64!",
        lambda: "",
    ]
    return choices[int(rng.integers(len(choices)))]()


def mutated(rng: np.random.Generator, body: dict[str, Any], fields: list[str]) -> dict[str, Any]:
    """``body`` with one to three of ``fields`` set to a nasty value, dropped, or a stray field added."""
    body = json.loads(json.dumps(body))
    for _ in range(int(rng.integers(1, 4))):
        roll = rng.random()
        name = fields[int(rng.integers(len(fields)))]
        if roll < 0.1:
            body.pop(name, None)
        elif roll < 0.15:
            body["stray"] = 1
        elif name == "options":
            knob = KNOBS[int(rng.integers(len(KNOBS)))]
            pool = METHODS if knob == "method" else NASTY_NUMBERS
            body["options"] = {**body.get("options", {}), knob: pool[int(rng.integers(len(pool)))]}
        elif name == "actions" and rng.random() < 0.7:
            count = int(rng.choice([1, 2, 3, 40]))
            body["actions"] = [
                {"text": rng.choice(["a person walks", "a person jumps", "", "!!!", "x" * 501]), "seconds": seconds}
                for seconds in rng.choice(np.array(NASTY_NUMBERS + [None], dtype=object), count)
            ]
        else:
            body[name] = NASTY[int(rng.integers(len(NASTY)))]
    return body


def requests(rng: np.random.Generator, parent: str, count: int) -> list[tuple[str, str, dict[str, Any]]]:
    """``count`` malformed requests over every route, drawn with ``rng``: (method, path, httpx keywords)."""
    generation_ids = [parent, "nope", "../..", "%2e%2e", "0" * 64]
    edits = {
        "regenerate": {"action": 1, "text": "a person kicks", "seconds": 1.2},
        "fill": {"then": parent, "seconds": 0.8},
        "pin": {"pose": {"generation": parent, "frame": 4}, "at": 1.0},
        "continue": {"actions": [{"text": "a person waves", "seconds": 1.2}]},
        "layer": {"part": "upper", "text": "a person waves", "span": [0.4, 1.6]},
    }
    drawn = []
    for _ in range(count):
        route = rng.choice(["generate", "edit", "upload", "split", "file", "read", "rigs", "maps"], p=PROBABILITIES)
        one = lambda pool: pool[int(rng.integers(len(pool)))]  # noqa: E731
        if route == "generate":
            body = {"actions": ACTIONS, "options": QUICK, "method": "tps", "fps": 30.0, "root": "keep", "loop": False}
            fields = ["actions", "options", "method", "seed", "fps", "root", "loop", "plant_feet", "prompt", "seconds"]
            drawn.append(("POST", "/api/generate", {"json": mutated(rng, body, fields + ["model", "run"])}))
        elif route == "edit":
            operation = one(list(edits))
            body = {"operation": operation, **edits[operation], "options": QUICK}
            fields = [*edits[operation], "operation", "options", "fps", "loop", "seed", *one(list(edits.values()))]
            path = f"/api/generations/{one(generation_ids)}/edit"
            drawn.append(("POST", path, {"json": mutated(rng, body, fields)}))
        elif route == "upload":
            body = {"motion": nasty_motion(rng), "actions": [{"text": "a person walks"}]}
            if rng.random() < 0.5:
                body = mutated(rng, body, ["actions", "fps", "model", "run"])
            elif rng.random() < 0.5:
                body["fps"] = float(rng.choice([20.0, 30.0, 120.0]))
            drawn.append(("POST", "/api/generations", {"json": body}))
        elif route == "split":
            drawn.append(
                ("POST", "/api/split", {"json": mutated(rng, {"prompt": "a person walks"}, ["prompt", "model"])})
            )
        elif route == "file":
            name = one(["motion.npy", "motion.bvh", "motion.json", "motion.features.npy", "motion.exe", "..", ""])
            params = {"rest": one(["skeleton", "tpose", "apose", "../x"]), "rig": one([None, "nope", "../../x"])}
            path = f"/api/generations/{one(generation_ids)}/{name}"
            drawn.append(("GET", path, {"params": {k: v for k, v in params.items() if v is not None}}))
        elif route == "read":
            drawn.append(("GET", one(["/api/models/m2d2m/runs/nope", f"/api/generations/{one(generation_ids)}"]), {}))
        elif route == "rigs":
            content = one([b"", b"HIERARCHY", (CMU / "131_01.bvh").read_bytes()[:3000], bytes(range(256))])
            params = {"joint_map": one(["cmu", "mixamo", "auto", "/etc/passwd", "nope"])}
            drawn.append(("POST", "/api/rigs", {"content": content, "params": params}))
        else:
            text = one(["pelvis: [Hips", "- a\n- b", yaml.safe_dump({"head": [["x"]]}), "\xff", "{}", "tail: Hips"])
            drawn.append(("POST", "/api/joint-maps", {"content": text.encode("utf-8", "surrogateescape")}))
    return drawn


PROBABILITIES = [0.25, 0.3, 0.25, 0.04, 0.06, 0.03, 0.04, 0.03]
ANSWERED_WITHIN_S = 300  # no request needs a tenth of it: one past it is a hang, not a slow machine


def test_a_fuzz_over_every_route_gets_no_500_and_every_request_answered(client, parent):
    """400 malformed requests, the same on every run (seed 53), over every route that takes a
    body or a name: each is answered, a 4xx with one sentence or a 200 (a mutation that is still
    a valid request), and no request is left in the queue. Before issue 53 four of these were
    500s (uploads that divided by zero); another draw found an edit of 2³¹ s (a MemoryError)."""
    statuses = []
    waiter = ThreadPoolExecutor(1)  # not a `with`: its exit would wait for a request that hangs
    try:
        for method, path, keywords in requests(np.random.default_rng(53), parent["id"], 400):
            pending = waiter.submit(client.request, method, path, **keywords)
            try:
                answer = pending.result(timeout=ANSWERED_WITHIN_S)
            except NotAnswered:
                pytest.fail(f"{method} {path} {str(keywords)[:300]} was not answered")
            assert answer.status_code < 500, (method, path, str(keywords)[:300], answer.text)
            if answer.status_code != 200:
                refusal(answer)
            statuses.append(answer.status_code)
    finally:
        waiter.shutdown(wait=False, cancel_futures=True)
    health = client.get("/api/health").json()
    assert health["queued"] == 0 and health["running"] == 0
    assert {200, 400, 404, 422} <= set(statuses)  # it reaches the schema's checks, the model's, and sampling
