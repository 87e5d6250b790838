"""Every error a client can cause, answered as ``{"error": "one sentence"}`` with its 4xx status
(and an unexpected one as a 500 that names only its type: the server's log says more)."""

from __future__ import annotations

import logging
from collections.abc import Awaitable, Callable
from typing import Any

from fastapi import Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from orchestration.errors import UserError
from orchestration.web.catalog import NotFound
from orchestration.web.sampler import Cancelled

log = logging.getLogger("m2d2m.serve")


class ApiError(Exception):
    """An answer other than 200, with its one sentence."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


def sentence(error: RequestValidationError) -> str:
    """The first thing wrong with a request body, in one sentence: where, and what."""
    first = error.errors()[0]
    place = [str(part) for part in first.get("loc", ()) if part != "body"]
    body = error.body if isinstance(error.body, dict) else {}
    if place[:1] == [body.get("operation")]:  # the member of the edits' union the body's operation chose
        place = place[1:]
    if first.get("type") == "json_invalid":
        return "the body is not JSON: " + first.get("ctx", {}).get("error", "it does not parse")
    if place[:1] == ["options"] and len(place) > 2:  # which of the union's members failed says nothing
        return f"options.{place[1]}: a knob's value is a number, a text or null, got {first.get('input')!r}"
    message = first.get("msg", "invalid").removeprefix("Value error, ")
    return f"{'.'.join(place)}: {message}" if place else message


def _answer(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


async def _invalid(request: Request, error: RequestValidationError) -> JSONResponse:
    return _answer(422, sentence(error))


async def _refused(request: Request, error: ApiError) -> JSONResponse:
    return _answer(error.status, str(error))


async def _not_found(request: Request, error: NotFound) -> JSONResponse:
    return _answer(404, str(error))


async def _bad_request(request: Request, error: UserError) -> JSONResponse:
    return _answer(400, str(error))


async def _cancelled(request: Request, error: Cancelled) -> JSONResponse:
    return _answer(499, str(error))


async def _http_error(request: Request, error: StarletteHTTPException) -> JSONResponse:
    return _answer(error.status_code, str(error.detail))


async def _unexpected(request: Request, error: Exception) -> JSONResponse:
    log.exception("unexpected error on %s", request.url.path)
    return _answer(500, f"the server failed ({type(error).__name__}); its log says more")


# the application's exception handlers (FastAPI's ``exception_handlers``): the most specific class
# of an error answers it, so NotFound is a 404 though it is a UserError too
ERROR_HANDLERS: dict[type[Exception], Callable[[Request, Any], Awaitable[JSONResponse]]] = {
    RequestValidationError: _invalid,
    ApiError: _refused,
    NotFound: _not_found,
    UserError: _bad_request,
    Cancelled: _cancelled,
    StarletteHTTPException: _http_error,
    Exception: _unexpected,
}
