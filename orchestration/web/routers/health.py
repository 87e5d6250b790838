"""``GET /api/health``: whether the server is up, and what its sampling thread is doing."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

from fastapi import APIRouter

from orchestration.web.dependencies import TheService

router = APIRouter()


@router.get("/health", summary="Whether the server is up, and what it is doing")
def health(service: TheService) -> dict[str, Any]:
    return {"status": "ok", "dataset": service.settings.dataset, **asdict(service.sampler.stats())}
