"""The page at ``/`` and the API's documentation (``/docs``: Swagger UI, ``/redoc``: ReDoc), served
from files installed with the project (fastapi-offline's copies of Swagger UI and ReDoc), so that
they work on a machine without internet; a content policy keeps the rest home too (ReDoc's footer
would fetch Redocly's logo from its CDN). FastAPI's own documentation pages load from a CDN, so
``create_app`` turns them off."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

from fastapi import APIRouter, FastAPI, Request
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles

STATIC = Path(__file__).parents[1] / "static"
DOCS_FILES = Path(importlib.util.find_spec("fastapi_offline").origin).parent / "static"  # Swagger UI, ReDoc
AT_HOME = "img-src 'self' data:; font-src 'self' data:; connect-src 'self'"  # a Content-Security-Policy

router = APIRouter()
router.mount("/docs-files", StaticFiles(directory=DOCS_FILES), name="docs-files")
router.mount("/static", StaticFiles(directory=STATIC), name="static")


@router.get("/", include_in_schema=False)
def page() -> FileResponse:
    return FileResponse(STATIC / "index.html")


@router.get("/docs", include_in_schema=False)
def swagger(request: Request) -> HTMLResponse:
    return _at_home(
        get_swagger_ui_html(
            **_documenting(request.app),
            swagger_js_url="/docs-files/swagger-ui-bundle.js",
            swagger_css_url="/docs-files/swagger-ui.css",
            swagger_favicon_url="/docs-files/favicon.png",
        )
    )


@router.get("/redoc", include_in_schema=False)
def redoc(request: Request) -> HTMLResponse:
    return _at_home(
        get_redoc_html(
            **_documenting(request.app),
            redoc_js_url="/docs-files/redoc.standalone.js",
            redoc_favicon_url="/docs-files/favicon.png",
            with_google_fonts=False,
        )
    )


def _documenting(app: FastAPI) -> dict[str, Any]:
    """What both documentation pages show: the application's OpenAPI document, under its title."""
    return {"openapi_url": app.openapi_url, "title": f"{app.title}: the HTTP API"}


def _at_home(html: HTMLResponse) -> HTMLResponse:
    html.headers["Content-Security-Policy"] = AT_HOME
    return html
