"""Characters: a rig (a BVH, or a skinned GLB, streamed) and a joint map of one's own, uploaded to
download generations on them."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Query, Request
from starlette.concurrency import run_in_threadpool

from orchestration.errors import UserError
from orchestration.web.dependencies import TheService

RIGS = "/rigs"  # under /api: the one path that takes files of tens of MB
# bodies that are no JSON, as the OpenAPI page offers them (a file to choose, a text to type)
FILE_BODY = {
    "requestBody": {"content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}}
}
YAML_BODY = {"requestBody": {"content": {"application/yaml": {"schema": {"type": "string"}}}}}

router = APIRouter()


@router.post(
    RIGS,
    summary="Upload a character's rig (the bytes of a BVH, or of a skinned GLB, streamed; or file=<id> of one "
    "sent before, under another joint_map) to download generations on it: GET a generation's motion.bvh?rig=<id> (or motion.glb, motion.fbx)",
    openapi_extra=FILE_BODY,
)
async def add_rig(
    request: Request,
    service: TheService,
    joint_map: str | None = None,
    file: str | None = None,
    rest_frame: int | None = Query(None, ge=0, description="the frame of a BVH whose pose motions are aimed from"),
) -> dict[str, Any]:
    if file is None:
        file = await service.rigs.receive(request.stream())
    else:
        async for chunk in request.stream():
            if chunk:
                raise UserError("give the rig's bytes or file=<id> of a rig sent before, not both")
    rig = await run_in_threadpool(service.rigs.add, file, joint_map, rest_frame)
    bind = rig.target.bind
    aimed = "rest pose" if bind.frame is None else f"frame {bind.frame}"
    return {"id": rig.id, "file": rig.file, "joints": rig.joints, "joint_map": rig.joint_map, "aimed_from": aimed}


@router.post(
    "/joint-maps",
    summary="Upload a joint map of your own (the text of a YAML file, our joint: yours, as m2d2m generate "
    "--joint-map reads) to name as a rig's joint_map",
    openapi_extra=YAML_BODY,
)
async def add_joint_map(request: Request, service: TheService) -> dict[str, Any]:
    mapping = await run_in_threadpool(service.rigs.add_map, await request.body())
    return {"id": mapping.name, "map": {ours: list(theirs) for ours, theirs in mapping.sources.items()}}
