"""The application's routes, one :class:`fastapi.APIRouter` per job (FastAPI's "Bigger
Applications"): ``create_app`` includes :data:`API_ROUTERS` under ``/api`` behind the token, and
:mod:`.page` (the page and the API's documentation) at the root. Each route reaches the
application's state through :mod:`orchestration.web.dependencies`, none through a closure."""

from __future__ import annotations

from fastapi import APIRouter

from orchestration.web.routers import downloads, edits, generate, health, models, rigs

# in the order the OpenAPI document lists their operations
API_ROUTERS: tuple[APIRouter, ...] = (
    health.router,
    models.router,
    generate.router,
    edits.router,
    downloads.router,
    rigs.router,
)
