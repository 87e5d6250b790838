"""Downloads: a generation's description and its files (an animation drawn, or a motion
retargeted onto an uploaded rig, on first request, on the painter's thread)."""

from __future__ import annotations

import asyncio

from fastapi import APIRouter
from fastapi.responses import FileResponse, JSONResponse

from m2d2m.motion.files.formats import on_rig, spoken
from m2d2m.motion.representation.pose import REST_POSES
from orchestration.web.dependencies import TheService
from orchestration.web.generations import FILES

router = APIRouter()


@router.get("/generations/{generation_id}", summary="A generation made by this server")
def generation(generation_id: str, service: TheService) -> JSONResponse:
    return JSONResponse(service.generations.describe(service.generations.get(generation_id)))


@router.get(
    "/generations/{generation_id}/{name}",
    summary=f"A generation's file: {', '.join(FILES)} (an animation is drawn on first request; "
    f"?rest={REST_POSES[1]} gives the {spoken(on_rig())} on a T-pose bind pose)",
    response_class=FileResponse,
)
async def generation_file(
    generation_id: str, name: str, service: TheService, rest: str = REST_POSES[0], rig: str | None = None
) -> FileResponse:
    uploaded = None if rig is None else service.rigs.get(rig)
    loop = asyncio.get_running_loop()
    path = await loop.run_in_executor(service.painter, service.generations.file, generation_id, name, rest, uploaded)
    return FileResponse(path, filename=f"{generation_id}-{path.name}")
