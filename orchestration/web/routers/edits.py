"""Editing: a generation edited on its timeline, and a motion made elsewhere uploaded to be edited
like one."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from orchestration.web.dependencies import TheService
from orchestration.web.schema import EditRequest, UploadRequest
from orchestration.web.streaming import NDJSON, answer_when_sampled

router = APIRouter()


@router.post(
    "/generations/{generation_id}/edit",
    summary="Edit a generation on its timeline: regenerate an action, fill a gap, pin a pose, continue",
    responses={200: {"content": {NDJSON: {}}, "description": "the new generation, or its progress and then it"}},
)
async def edit(generation_id: str, body: EditRequest, request: Request, service: TheService) -> Any:
    parent = service.generations.get(generation_id)
    job, plan, run, finishing = await run_in_threadpool(service.prepare_edit, parent, body)
    return await answer_when_sampled(
        request, service.sampler, job, service.finish(job, parent.model, plan, run, finishing)
    )


@router.post(
    "/generations",
    summary="Upload a motion made elsewhere (features or joints, at its fps) to edit like a generation",
)
async def upload(body: UploadRequest, service: TheService) -> JSONResponse:
    return JSONResponse(await run_in_threadpool(service.upload, body))
