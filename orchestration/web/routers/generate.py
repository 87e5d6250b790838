"""Generating: a prompt split into the actions it becomes, and actions sampled into a generation."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request
from starlette.concurrency import run_in_threadpool

from orchestration.web.dependencies import TheService
from orchestration.web.schema import GenerateRequest, SplitRequest
from orchestration.web.streaming import NDJSON, answer_when_sampled

router = APIRouter()


@router.post(
    "/generate",
    summary="Several actions in a row with one model, method and seed",
    responses={200: {"content": {NDJSON: {}}, "description": "the generation, or its progress and then it"}},
)
async def generate(body: GenerateRequest, request: Request, service: TheService) -> Any:
    job, plan, run = await run_in_threadpool(service.prepare, body)
    return await answer_when_sampled(request, service.sampler, job, service.finish(job, body.model, plan, run))


@router.post("/split", summary="The actions a prompt is split into, to check and fix before generating")
async def split(body: SplitRequest, service: TheService) -> dict[str, Any]:
    return await run_in_threadpool(service.split, body)
