"""The HTTP application: the page at ``/``, the API under ``/api`` (OpenAPI at ``/docs``).

Every answer to a bad request is a 4xx JSON ``{"error": "one sentence"}``; an API call needs the
server's token when it has one (``Authorization: Bearer <token>``, or ``?token=`` on a download
link). ``POST /api/generate`` answers with the generation, or, asked for
``application/x-ndjson``, streams ``{"queued": n}`` and ``{"progress": f}`` lines before it.

``create_app`` only assembles: the state (:class:`~orchestration.web.service.Service`), the routers
of :mod:`orchestration.web.routers` (one per job), the error answers and the bound on bodies.
"""

from __future__ import annotations

from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import APIRouter, Depends, FastAPI

from orchestration.web.dependencies import authorised
from orchestration.web.errors import ERROR_HANDLERS
from orchestration.web.limits import BoundedBody
from orchestration.web.routers import API_ROUTERS, page, rigs
from orchestration.web.service import ServeSettings, Service

API = "/api"


def create_app(settings: ServeSettings) -> FastAPI:
    """The application of one server: its state built, its routers included."""
    service = Service(settings)
    app = FastAPI(
        title="m2d2m",
        summary="Multi-action text to motion: M2D2M, MMM and MotionDiffuse behind one interface",
        lifespan=_lifespan,
        docs_url=None,  # FastAPI's own pages load Swagger UI and ReDoc from a CDN: ours are served here
        redoc_url=None,
        exception_handlers=ERROR_HANDLERS,
    )
    app.state.service = service
    api = APIRouter(prefix=API, dependencies=[Depends(authorised)])
    for router in API_ROUTERS:
        api.include_router(router)
    app.include_router(api)
    app.include_router(page.router)
    app.add_middleware(BoundedBody, limits={API + rigs.RIGS: settings.max_rig_bytes})
    return app


@asynccontextmanager
async def _lifespan(app: FastAPI) -> AsyncIterator[None]:
    """The sampling thread runs while the application serves; at shutdown it finishes its queue."""
    service: Service = app.state.service
    service.sampler.start()
    try:
        yield
    finally:
        service.close()
