"""The calls the add-on makes to `m2d2m serve`'s HTTP API (docs/serving.md), with Python's standard
library alone (nothing is installed into Blender's Python), and its refusals as one sentence for
Blender's status bar: the API's own 4xx sentence, or how to start a server that is not running."""

from __future__ import annotations

import json
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Callable
from typing import Any

DEFAULT_SERVER = "http://127.0.0.1:8000"  # `m2d2m serve`'s own address (--host 127.0.0.1 --port 8000)
TIMEOUT_S = 600.0  # a long clip on a CPU samples for minutes; progress lines arrive meanwhile
NDJSON = "application/x-ndjson"


class ServerError(Exception):
    """A call that failed, said in one sentence a person can act on."""


class Client:
    """`m2d2m serve` at ``server`` (``http://host:port``), with its token when it has one."""

    def __init__(self, server: str, token: str = "", timeout: float = TIMEOUT_S) -> None:
        self.server = (server.strip() or DEFAULT_SERVER).rstrip("/")
        self.token = token.strip()
        self.timeout = timeout

    def models(self) -> list[dict[str, Any]]:
        """The served models, their runs and methods (``GET /api/models``)."""
        return json.loads(self._call("GET", "/api/models"))["models"]

    def upload_rig(self, bvh: str) -> dict[str, Any]:
        """A rig from the text of a BVH (``POST /api/rigs``): its ``id`` and the joint map it is read through."""
        return json.loads(self._call("POST", "/api/rigs", bvh.encode(), "application/octet-stream"))

    def generate(self, request: dict[str, Any], progress: Callable[[float], None] | None = None) -> dict[str, Any]:
        """A generation (``POST /api/generate``), its progress (0 to 1) told to ``progress`` as it samples."""
        return self._sampled("/api/generate", request, progress)

    def edit(
        self, generation: str, request: dict[str, Any], progress: Callable[[float], None] | None = None
    ) -> dict[str, Any]:
        """An edit of a generation (``POST /api/generations/{id}/edit``): the new generation."""
        return self._sampled(f"/api/generations/{urllib.parse.quote(generation)}/edit", request, progress)

    def bvh_on_rig(self, generation: str, rig: str) -> str:
        """A generation's clip as a BVH on an uploaded rig (``motion.bvh?rig=<id>``)."""
        path = f"/api/generations/{urllib.parse.quote(generation)}/motion.bvh?rig={urllib.parse.quote(rig)}"
        return self._call("GET", path).decode()

    def _sampled(self, path: str, request: dict[str, Any], progress: Callable[[float], None] | None) -> dict[str, Any]:
        """A call that samples, read as NDJSON lines: progress while it samples, then the result or
        the error the server met after it had answered 200."""
        body = json.dumps(request).encode()
        with self._open("POST", path, body, "application/json", accept=NDJSON) as answer:
            for line in answer:
                if not line.strip():
                    continue
                event = json.loads(line)
                if "result" in event:
                    return event["result"]
                if "error" in event:
                    raise ServerError(f"the server refused: {event['error']}")
                if "progress" in event and progress is not None:
                    progress(float(event["progress"]))
        raise ServerError(f"{self.server} closed the answer before sending the clip; its log says why")

    def _call(self, method: str, path: str, body: bytes | None = None, content_type: str | None = None) -> bytes:
        with self._open(method, path, body, content_type) as answer:
            return answer.read()

    def _open(
        self, method: str, path: str, body: bytes | None, content_type: str | None, accept: str = "application/json"
    ) -> Any:
        headers = {"Accept": accept}
        if content_type is not None:
            headers["Content-Type"] = content_type
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        request = urllib.request.Request(self.server + path, body, headers, method=method)
        try:
            return urllib.request.urlopen(request, timeout=self.timeout)
        except urllib.error.HTTPError as error:
            raise ServerError(refusal(error.code, error.read())) from error
        except (TimeoutError, urllib.error.URLError, ConnectionError) as error:
            raise ServerError(unreachable(self.server, error)) from error


def refusal(status: int, body: bytes) -> str:
    """The API's one sentence for a refused call (``{"error": "..."}``), else its status."""
    try:
        said = json.loads(body).get("error")
    except (ValueError, AttributeError):
        said = None
    return f"the server refused ({status}): {said}" if said else f"the server answered {status}"


def unreachable(server: str, error: Exception) -> str:
    """Why no answer came, and what to do: most often, no server is running."""
    reason = getattr(error, "reason", error)
    if isinstance(reason, ConnectionRefusedError):
        return f"no m2d2m server at {server}: start one with `m2d2m serve` (or `make serve`), or set the address"
    if isinstance(reason, TimeoutError):
        return f"{server} did not answer in time"
    return f"cannot reach {server}: {reason}"


def generation_request(
    model: str,
    method: str,
    actions: list[tuple[str, float]],
    prompt: str,
    seconds: float,
    seed: int,
    fps: float,
    root: str,
    plant_feet: bool,
) -> dict[str, Any]:
    """The body of ``POST /api/generate`` for the panel's choices: its ``actions`` (text and
    seconds; 0 s: the model's typical length for the sentence), or one ``prompt`` the server splits
    by its verbs when no action is listed (``seconds`` for the whole; 0: typical lengths); the clip
    at the scene's ``fps``, its root and feet as chosen."""
    request: dict[str, Any] = {"model": model, "seed": seed, "fps": fps, "root": root, "plant_feet": plant_feet}
    if method:
        request["method"] = method
    listed = [(text.strip(), length) for text, length in actions if text.strip()]
    if listed:
        request["actions"] = [{"text": text, "seconds": length or None} for text, length in listed]
    elif prompt.strip():
        request["prompt"] = prompt.strip()
        request["seconds"] = seconds or None
    else:
        raise ValueError("type an action (or a sentence) to generate")
    return request
