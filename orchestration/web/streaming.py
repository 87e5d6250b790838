"""How a route that samples answers (``POST /api/generate`` and an edit): the generation when it
is sampled and recorded, or, asked for ``application/x-ndjson``, ``{"queued": n}`` and
``{"progress": f}`` lines before it. A client that goes away cancels its job either way."""

from __future__ import annotations

import asyncio
import json
import logging
from collections.abc import AsyncIterator, Coroutine
from typing import Any

from fastapi import Request
from fastapi.responses import JSONResponse, StreamingResponse

from orchestration.errors import UserError
from orchestration.web.errors import ApiError
from orchestration.web.sampler import Cancelled, Job, QueueFull, Sampler

NDJSON = "application/x-ndjson"
log = logging.getLogger("m2d2m.serve")

Finishing = Coroutine[Any, Any, dict[str, Any]]  # the answer, once the job's motion is sampled


async def answer_when_sampled(
    request: Request, sampler: Sampler, job: Job, finishing: Finishing
) -> JSONResponse | StreamingResponse:
    """Queue ``job``; the answer when it is sampled and ``finishing`` is done, or its progress
    as NDJSON lines before it when the client asks for them."""
    events: asyncio.Queue[dict[str, Any] | None] = asyncio.Queue()
    loop = asyncio.get_running_loop()
    job.listener = lambda event: loop.call_soon_threadsafe(events.put_nowait, event)
    try:
        sampler.submit(job)
    except QueueFull as error:
        finishing.close()
        raise ApiError(429, str(error)) from error
    if NDJSON in request.headers.get("accept", ""):
        return StreamingResponse(_stream(job, events, finishing), media_type=NDJSON)
    # a JSONResponse as it is: FastAPI's encoder would walk every joint coordinate in Python first
    return JSONResponse(await _unless_disconnected(request, job, finishing))


async def _stream(job: Job, events: asyncio.Queue, finishing: Finishing) -> AsyncIterator[bytes]:
    """NDJSON lines: the job's events, then ``{"result": ...}`` or ``{"error": ...}``. A client
    that goes away cancels this generator (Starlette does), which cancels the job."""
    try:
        while (event := await events.get()) is not None:
            yield _line(event)
        try:
            yield _line({"result": await finishing})
        except (UserError, ValueError, Cancelled) as error:
            yield _line({"error": str(error)})
        except Exception as error:
            log.exception("generation failed")
            yield _line({"error": f"the generation failed on the server ({type(error).__name__}); see its log"})
    finally:
        job.cancel()
        finishing.close()


def _line(payload: dict[str, Any]) -> bytes:
    return (json.dumps(payload, separators=(",", ":")) + "\n").encode()


async def _unless_disconnected(request: Request, job: Job, finishing: Finishing) -> dict[str, Any]:
    """``finishing``'s answer; a client that disconnects before it cancels the job."""
    task = asyncio.ensure_future(finishing)
    try:
        while not task.done():
            await asyncio.wait({task}, timeout=0.25)
            if not task.done() and await request.is_disconnected():
                job.cancel()
        return task.result()
    finally:
        job.cancel()
