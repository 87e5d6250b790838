"""The catalog: the models a server offers, their runs and knobs, and one run's own defaults."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from starlette.concurrency import run_in_threadpool

from orchestration.web.dependencies import TheService

router = APIRouter()


@router.get("/models", summary="The models with a finished run: their runs, methods and knobs")
def list_models(service: TheService) -> dict[str, Any]:
    settings = service.settings
    return {
        "dataset": settings.dataset,
        "max_seconds": settings.max_seconds,
        "max_rig_bytes": settings.max_rig_bytes,
        "models": service.catalog.describe(),
    }


@router.get("/models/{model}/runs/{run}", summary="A run's own sampling defaults and action lengths (loads it)")
async def run_details(model: str, run: str, service: TheService) -> dict[str, Any]:
    return await run_in_threadpool(service.catalog.run_details, model, run)
