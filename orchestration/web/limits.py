"""How many bytes a request's body may hold (issue 52 §3; docs/serving.md): a small limit for
every request, far above what a person or a tool sends, and larger ones for the few paths that
take files (a character's rig, tens of MB).

A body is refused with 413 and one sentence as soon as it is known to be too large: before a byte
of it is read when its Content-Length says so, else (a chunked body, or a Content-Length that
lies) at the first chunk past the limit, so a server never reads or keeps more than the limit."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException

MAX_BODY_BYTES = 1 << 20  # far above any request a person or a tool sends


class BodyTooLarge(HTTPException):
    """A body found over its limit while it was read: the application answers it as any 4xx."""

    def __init__(self, path: str, limit: int) -> None:
        super().__init__(413, too_large(path, limit))


def too_large(path: str, limit: int) -> str:
    return f"a request body to {path} may hold at most {_size(limit)}"


def _size(count: int) -> str:
    return f"{count >> 20} MiB" if count >= 1 << 20 and count % (1 << 20) == 0 else f"{count} bytes"


class BoundedBody:
    """ASGI middleware that bounds each request's body: ``limits`` by path, else
    :data:`MAX_BODY_BYTES`. Plain ASGI rather than ``@app.middleware``: Starlette's
    BaseHTTPMiddleware wraps ``receive`` so that a handler no longer hears its client disconnect."""

    def __init__(self, app: Any, limits: Mapping[str, int] | None = None) -> None:
        self.app = app
        self.limits = dict(limits or {})

    async def __call__(self, scope: dict, receive: Any, send: Any) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = self.limits.get(scope["path"], MAX_BODY_BYTES)
        length = dict(scope.get("headers", ())).get(b"content-length")
        if length is not None and (not length.isdigit() or int(length) > limit):
            await JSONResponse({"error": too_large(scope["path"], limit)}, 413)(scope, receive, send)
            return
        received = 0

        async def bounded() -> dict:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise BodyTooLarge(scope["path"], limit)
            return message

        await self.app(scope, bounded, send)
