"""Issue 52 §3: a character's file of tens of MB uploads to `m2d2m serve` (streamed to disk, its own
limit, refused with 413 as soon as it passes it, whether or not it says its length, while every other
request keeps the 1-MiB limit), is read once and named by its id after, and a joint map of one's own
goes beside the presets; a clip comes back on the character as `m2d2m generate --rig` puts it."""

from __future__ import annotations

import asyncio
import json
import re
import socket
from pathlib import Path

import numpy as np
import pytest
import yaml
from fastapi.testclient import TestClient

import m2d2m.motion.rigs.retarget as retarget_module
from m2d2m.motion.files.bvh_reader import read_bvh
from m2d2m.motion.rigs.joint_map import PRESETS
from m2d2m.motion.rigs.retarget import read_rig, retarget_to_bvh
from orchestration.cli import main
from orchestration.web import server
from orchestration.web.app import ServeSettings, create_app
from orchestration.web.limits import MAX_BODY_BYTES
from tests.helpers import XBOT, free_port, xbot_with_a_mesh
from tests.live_server import live_server
from tests.test_retarget import BANDAI_WALK

ACTIONS = [{"text": "a person walks forward", "seconds": 1.6}, {"text": "a person jumps", "seconds": 1.2}]
MIXAMO_MAP = {ours: list(theirs) for ours, theirs in PRESETS["mixamo"].sources.items()}


@pytest.fixture(scope="module")
def character(tmp_path_factory) -> Path:
    """X Bot with a 3-MB skinned mesh: a character's GLB three times the small body limit."""
    return xbot_with_a_mesh(tmp_path_factory.mktemp("character") / "xbot.glb", megabytes=3)


@pytest.fixture
def bare_client(tmp_path, monkeypatch):
    """The application in a folder of its own, no model trained: rigs and maps need none."""
    monkeypatch.chdir(tmp_path)
    with TestClient(create_app(ServeSettings(dataset="tiny", track=False))) as client:
        yield client


@pytest.fixture
def reads(monkeypatch) -> list[Path]:
    """Every rig file read (:func:`m2d2m.motion.rigs.retarget.read_rig`), in order."""
    read: list[Path] = []

    def counted(path):
        read.append(Path(path))
        return read_rig(path)

    monkeypatch.setattr(retarget_module, "read_rig", counted)
    return read


def post(app, path: str, chunks, length: int | None = None) -> tuple[int, dict, int]:
    """POST ``chunks`` (an iterator of bytes) to the ASGI ``app`` as a client sends them, with
    ``length`` as its Content-Length or none (chunked): the status, the JSON answer, and how many
    chunks the application asked for."""
    headers = [(b"content-type", b"application/octet-stream")]
    if length is not None:
        headers.append((b"content-length", str(length).encode()))
    scope = {
        "type": "http",
        "asgi": {"version": "3.0"},
        "http_version": "1.1",
        "method": "POST",
        "scheme": "http",
        "path": path,
        "raw_path": path.encode(),
        "query_string": b"",
        "root_path": "",
        "headers": headers,
        "client": ("127.0.0.1", 1),
        "server": ("127.0.0.1", 80),
    }
    asked, sent = 0, []

    async def receive() -> dict:
        nonlocal asked
        asked += 1
        return {"type": "http.request", "body": next(chunks), "more_body": True}

    async def send(message: dict) -> None:
        sent.append(message)

    asyncio.run(app(scope, receive, send))
    status = next(m["status"] for m in sent if m["type"] == "http.response.start")
    body = b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body")
    return status, json.loads(body), asked


def endless(size: int = 1 << 20):
    while True:
        yield b"x" * size


def test_a_character_over_a_mib_uploads_and_is_read_once(bare_client, character, reads):
    """The 3-MB character is taken (the body limit of every other request is 1 MiB), read once:
    sent again, or named by its file's id under the same map, it is not read again."""
    assert character.stat().st_size > 3 * MAX_BODY_BYTES
    uploaded = bare_client.post("/api/rigs", content=character.read_bytes())
    assert uploaded.status_code == 200, uploaded.text
    rig = uploaded.json()
    assert (rig["joints"], rig["joint_map"]) == (65, "mixamo") and len(reads) == 1
    assert bare_client.post("/api/rigs", content=character.read_bytes()).json() == rig
    assert bare_client.post("/api/rigs", params={"file": rig["file"]}).json() == rig
    assert len(reads) == 1
    stored = Path("runs/tiny/rigs") / f"{rig['file']}.glb"
    assert stored.read_bytes() == character.read_bytes() and [p.name for p in stored.parent.iterdir()] == [stored.name]
    # the same file under another map: a rig of its own, checked on the file already there
    other = bare_client.post("/api/rigs", params={"file": rig["file"], "joint_map": "cmu"})
    assert other.status_code == 400 and "joint map cmu reads Chest" in other.json()["error"] and len(reads) == 2
    both = bare_client.post("/api/rigs", params={"file": rig["file"]}, content=b"BVH")
    assert both.status_code == 400 and both.json()["error"] == (
        "give the rig's bytes or file=<id> of a rig sent before, not both"
    )
    unknown = bare_client.post("/api/rigs", params={"file": "0" * 16})
    assert unknown.status_code == 404 and "send its bytes to POST /api/rigs" in unknown.json()["error"]
    assert bare_client.get("/api/models").json()["max_rig_bytes"] == 64 << 20


def test_a_body_over_its_limit_is_refused_as_soon_as_it_passes_it(tmp_path, monkeypatch):
    """413 and one sentence: before a byte is read when Content-Length says the body is too large,
    at the first chunk past the limit when it does not say (chunked) — a character's file over the
    rig limit, any other request over 1 MiB — and nothing of the refused upload is left on disk."""
    monkeypatch.chdir(tmp_path)
    app = create_app(ServeSettings(dataset="tiny", track=False, max_rig_bytes=8 << 20))
    rig_error = {"error": "a request body to /api/rigs may hold at most 8 MiB"}
    assert post(app, "/api/rigs", endless(), length=(8 << 20) + 1) == (413, rig_error, 0)
    assert post(app, "/api/rigs", endless()) == (413, rig_error, 9)  # 1-MiB chunks: the 9th passes 8 MiB
    assert not list((tmp_path / "runs/tiny/rigs").iterdir())
    small = {"error": "a request body to /api/generate may hold at most 1 MiB"}
    assert post(app, "/api/generate", endless(), length=MAX_BODY_BYTES + 1) == (413, small, 0)
    assert post(app, "/api/generate", endless(1000)) == (413, small, MAX_BODY_BYTES // 1000 + 1)
    maps = {"error": "a request body to /api/joint-maps may hold at most 1 MiB"}
    assert post(app, "/api/joint-maps", endless()) == (413, maps, 2)


def test_the_rig_limit_is_the_servers_option(tmp_path, monkeypatch):
    """`m2d2m serve --max-rig-mb 8` serves with an 8-MiB limit on a rig's file."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs").mkdir()  # a project
    served = []
    monkeypatch.setattr(server, "serve", lambda settings, host, port: served.append(settings))
    assert main(["serve", "--dataset", "tiny", "--port", str(free_port()), "--max-rig-mb", "8"]) == 0
    assert [settings.max_rig_bytes for settings in served] == [8 << 20]


def test_a_real_server_answers_413_without_waiting_for_the_body(tmp_path, monkeypatch):
    """Over a socket: a client that says it will send 1 GiB is answered before it sends a byte."""
    monkeypatch.chdir(tmp_path)
    with live_server(ServeSettings(dataset="tiny", track=False)) as (base, _):
        with socket.create_connection(("127.0.0.1", int(base.rsplit(":", 1)[1])), timeout=10) as raw:
            raw.sendall(b"POST /api/rigs HTTP/1.1\r\nHost: x\r\nContent-Length: 1073741824\r\n\r\n")
            answer = b""
            while not re.search(rb"\r\n\r\n\{.*\}$", answer, re.DOTALL):  # the head, then the JSON whole
                answer += raw.recv(4096)
    head, _, body = answer.decode().partition("\r\n\r\n")
    assert head.startswith("HTTP/1.1 413") and json.loads(body) == {
        "error": "a request body to /api/rigs may hold at most 64 MiB"
    }


def test_a_joint_map_of_ones_own_reads_a_rig_and_a_bad_one_is_one_line(bare_client):
    """A YAML map as `--joint-map` takes it (here Mixamo's names, our spine2 the midpoint of the
    rig's Spine1 and Spine2), uploaded once and named by its id as a rig's joint_map; a map that is
    no map of our joints, or one naming joints the rig lacks, is a 400 in one line."""
    own = {**MIXAMO_MAP, "spine2": ["mixamorig:Spine1", "mixamorig:Spine2"]}
    sent = bare_client.post("/api/joint-maps", content=yaml.safe_dump(own))
    assert sent.status_code == 200, sent.text
    assert sent.json()["map"] == own and len(sent.json()["id"]) == 16
    rig = bare_client.post("/api/rigs", params={"joint_map": sent.json()["id"]}, content=XBOT.read_bytes())
    assert rig.status_code == 200, rig.text
    assert rig.json()["joint_map"] == sent.json()["id"] and rig.json()["joints"] == 65
    assert bare_client.post("/api/joint-maps", content=yaml.safe_dump(own)).json() == sent.json()
    strange = {**own, "tail": "mixamorig:Hips"}
    for content, message in (
        (yaml.safe_dump(strange), "the joint map: t2m has no joint tail"),
        (yaml.safe_dump({**own, "head": ["Head", ["Neck"]]}), "the joint map: head: a list of their joints holds"),
        ("pelvis: [Hips\nhead: Head", "the joint map: not a readable YAML joint map (while parsing a flow sequence"),
        ("- Hips\n- Head", "the joint map: a joint map is a mapping of our joint → their joint or a list of theirs"),
        ("", "the joint map: a joint map is a mapping"),
        (b"\xff\xfe", "the joint map is not UTF-8 text"),
    ):
        refused = bare_client.post("/api/joint-maps", content=content)
        assert refused.status_code == 400 and refused.json()["error"].startswith(message), refused.text
        assert "\n" not in refused.json()["error"] and "/tmp" not in refused.json()["error"]
    elsewhere = {**own, "pelvis": "Hips"}
    other = bare_client.post("/api/joint-maps", content=yaml.safe_dump(elsewhere)).json()["id"]
    refused = bare_client.post("/api/rigs", params={"joint_map": other}, content=XBOT.read_bytes())
    assert refused.status_code == 400
    assert (
        refused.json()["error"] == f"the rig cannot take our motions: joint map {other} reads Hips, which the BVH lacks"
    )
    path = bare_client.post("/api/rigs", params={"joint_map": "/etc/passwd"}, content=XBOT.read_bytes())
    assert path.status_code == 400 and path.json()["error"].startswith(
        "joint_map must be one of cmu, cmu-motionbuilder, mixamo, smpl, bandai-namco, auto or the id of a map"
    )


def test_a_map_naming_some_joints_corrects_the_automatic_one_and_auto_can_be_asked(bare_client):
    """As `--joint-map` on the command line: a YAML naming only some of our joints corrects the
    map found from the rig's names and hierarchy (docs/generation.md, "On your own rig"), and
    ``joint_map=auto`` asks for that map where a preset would fit."""
    found = bare_client.post("/api/rigs", params={"joint_map": "auto"}, content=XBOT.read_bytes())
    assert found.status_code == 200, found.text
    assert found.json()["joint_map"] == "auto" and found.json()["joints"] == 65
    correction = {"spine2": ["mixamorig:Spine1", "mixamorig:Spine2"]}
    sent = bare_client.post("/api/joint-maps", content=yaml.safe_dump(correction)).json()
    assert sent["map"] == correction
    rig = bare_client.post("/api/rigs", params={"file": found.json()["file"], "joint_map": sent["id"]})
    assert rig.status_code == 200, rig.text
    assert rig.json()["joint_map"] == f"{sent['id']} over auto"


def test_a_clip_comes_back_on_the_character_as_the_command_line_puts_it(trained_project, character, reads):
    """The 3-MB character uploaded once: every generation's BVH downloads on it without the file
    being read again, each the BVH `m2d2m generate --rig` writes of the same joints."""
    with TestClient(create_app(ServeSettings(dataset="tiny", track=False))) as client:
        rig = client.post("/api/rigs", content=character.read_bytes()).json()
        assert len(reads) == 1
        for seed in (1, 2):
            result = client.post("/api/generate", json={"actions": ACTIONS, "options": {"ts": 4}, "seed": seed}).json()
            answer = client.get(result["files"]["bvh"], params={"rig": rig["id"]})
            assert answer.status_code == 200, answer.text
            downloaded = trained_project / f"on-character-{seed}.bvh"
            downloaded.write_bytes(answer.content)
            (trained_project / "joints.npy").write_bytes(client.get(result["files"]["npy"]).content)
            joints = np.load(trained_project / "joints.npy")
            by_the_cli = retarget_to_bvh(trained_project / "by-the-cli.bvh", joints, character, fps=result["fps"])
            assert answer.content == by_the_cli.read_bytes()
            on_character = read_bvh(downloaded)
            assert len(on_character.names) == 65 and len(on_character.values) == len(result["joints"])
        assert reads == [reads[0]] + [character] * 2  # the server read it once; the command line, each time


def test_a_rig_is_aimed_from_the_frame_asked_and_a_frame_it_lacks_is_one_line(bare_client):
    """Bandai Namco's rest pose lies along its bones: by default its rig is aimed from its file's
    first frame, with ``rest_frame`` from another (a rig of its own); a frame the file lacks is a
    400 in one sentence, a negative one a 422 as every invalid field is."""
    walk = BANDAI_WALK.read_bytes()
    default = bare_client.post("/api/rigs", content=walk)
    assert default.status_code == 200, default.text
    assert default.json()["aimed_from"] == "frame 0"
    later = bare_client.post("/api/rigs", params={"file": default.json()["file"], "rest_frame": 40}).json()
    assert later["aimed_from"] == "frame 40" and later["id"] != default.json()["id"]
    frames = len(read_bvh(BANDAI_WALK).values)
    missing = bare_client.post("/api/rigs", params={"file": default.json()["file"], "rest_frame": frames})
    assert missing.status_code == 400
    assert f"rest frame {frames}: the rig's file has {frames} frame(s)" in missing.json()["error"]
    negative = bare_client.post("/api/rigs", params={"file": default.json()["file"], "rest_frame": -1})
    assert negative.status_code == 422 and "rest_frame" in negative.json()["error"]  # as every invalid field
