"""What a route is given by FastAPI's dependency injection rather than a closure: the
application's :class:`~orchestration.web.service.Service`, and the check of the server's token
that guards every call under ``/api``."""

from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import Depends, Request

from orchestration.web.errors import ApiError
from orchestration.web.service import Service


async def service_of(request: Request) -> Service:
    """The state of the application that received ``request`` (``create_app`` puts it on
    ``app.state``, which Starlette leaves untyped)."""
    return request.app.state.service


TheService = Annotated[Service, Depends(service_of)]


async def authorised(request: Request, service: TheService) -> None:
    """Nothing when the server has no token or the request carries it (``Authorization: Bearer
    <token>``, or ``?token=`` on a download link); else a 401."""
    token = service.settings.token
    if token is None:
        return
    given = request.headers.get("authorization", "").removeprefix("Bearer ").strip()
    given = given or request.query_params.get("token", "")
    if not secrets.compare_digest(given.encode(), token.encode()):
        raise ApiError(401, "this server needs its token: send Authorization: Bearer <token>")
