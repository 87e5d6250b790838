"""The HTTP application: the page at ``/``, the API under ``/api`` (OpenAPI at ``/docs``).

Every answer to a bad request is a 4xx JSON ``{"error": "one sentence"}``; an API call needs the
server's token when it has one (``Authorization: Bearer <token>``, or ``?token=`` on a download
link). ``POST /api/generate`` answers with the generation, or, asked for
``application/x-ndjson``, streams ``{"queued": n}`` and ``{"progress": f}`` lines before it.
"""

from __future__ import annotations

import asyncio
import base64
import binascii
import importlib.util
import json
import logging
import secrets
import threading
from collections.abc import AsyncIterator, Callable
from concurrent.futures import ThreadPoolExecutor
from contextlib import asynccontextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Depends, FastAPI, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, StreamingResponse
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException as StarletteHTTPException

from m2d2m.motion.clip import Motion
from m2d2m.motion.files.formats import on_rig, spoken
from m2d2m.motion.representation.pose import REST_POSES
from m2d2m.motion.transforms.delivery import Delivery
from orchestration.editing import finish_edit, motion_of
from orchestration.errors import UserError
from orchestration.generate import DEFAULT_MAX_SECONDS, PromptPlanner
from orchestration.runs import stage_dir
from orchestration.viewing import load_features
from orchestration.web.catalog import Catalog, NotFound
from orchestration.web.edits import plan_edit_request
from orchestration.web.generations import FILES, Generation, Generations
from orchestration.web.limits import BoundedBody
from orchestration.web.rigs import RIGS_STAGE, Rigs
from orchestration.web.sampler import Cancelled, Job, QueueFull, Sampler
from orchestration.web.schema import (
    EditRequest,
    GenerateRequest,
    Plan,
    SplitRequest,
    UploadRequest,
    plan_request,
    within_cap,
)

STATIC = Path(__file__).parent / "static"
DOCS_FILES = Path(importlib.util.find_spec("fastapi_offline").origin).parent / "static"  # Swagger UI, ReDoc
NDJSON = "application/x-ndjson"
RIGS = "/rigs"  # under /api: the one path that takes files of tens of MB
# bodies that are no JSON, as the OpenAPI page offers them (a file to choose, a text to type)
FILE_BODY = {
    "requestBody": {"content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}}}
}
YAML_BODY = {"requestBody": {"content": {"application/yaml": {"schema": {"type": "string"}}}}}
log = logging.getLogger("m2d2m.serve")


@dataclass(frozen=True)
class ServeSettings:
    """How a server runs (`m2d2m serve`'s options)."""

    dataset: str = "synthetic"
    token: str | None = None
    max_seconds: float | None = DEFAULT_MAX_SECONDS
    queue: int = 64
    max_batch: int = 16
    gather_s: float = 0.02
    device: str = "cpu"
    track: bool = True
    mlflow_ui: str | None = None
    max_rig_bytes: int = 64 << 20  # a character with its meshes and textures is tens of MB


class ApiError(Exception):
    """An answer other than 200, with its one sentence."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status


def _sentence(error: RequestValidationError) -> str:
    """The first thing wrong with a request body, in one sentence: where, and what."""
    first = error.errors()[0]
    place = [str(part) for part in first.get("loc", ()) if part != "body"]
    body = error.body if isinstance(error.body, dict) else {}
    if place[:1] == [body.get("operation")]:  # the member of the edits' union the body's operation chose
        place = place[1:]
    if first.get("type") == "json_invalid":
        return "the body is not JSON: " + first.get("ctx", {}).get("error", "it does not parse")
    if place[:1] == ["options"] and len(place) > 2:  # which of the union's members failed says nothing
        return f"options.{place[1]}: a knob's value is a number, a text or null, got {first.get('input')!r}"
    message = first.get("msg", "invalid").removeprefix("Value error, ")
    return f"{'.'.join(place)}: {message}" if place else message


class Service:
    """The state one application holds: the models, the sampling thread, the generations."""

    def __init__(self, settings: ServeSettings) -> None:
        self.settings = settings
        self.catalog = Catalog(settings.dataset, settings.device)
        self.sampler = Sampler(settings.queue, settings.max_batch, settings.gather_s)
        self.generations = Generations(settings.dataset, settings.track, mlflow_ui=settings.mlflow_ui)
        self.rigs = Rigs(stage_dir(settings.dataset, RIGS_STAGE))
        # one writer to the run folders and MLflow's store, one painter of GIFs and MP4s
        self.recorder = ThreadPoolExecutor(1, thread_name_prefix="m2d2m-recorder")
        self.painter = ThreadPoolExecutor(1, thread_name_prefix="m2d2m-painter")
        self._planners: dict[int, PromptPlanner] = {}
        self._planning = threading.Lock()

    def prepare(self, request: GenerateRequest) -> tuple[Job, Plan, str]:
        """Load the model (once), plan the request, and make its job (a blocking call)."""
        run, generator = self.catalog.generator(request.model, request.run)
        with self._planning:  # spaCy's tagger and the planners' caches are not shared across threads
            planner = self._planners.setdefault(id(generator), PromptPlanner(generator))
            plan = plan_request(request, planner, self.settings.max_seconds)
        job = Job(generator, (request.model, run, plan.options), plan.options, plan.actions, plan.frames, request.seed)
        return job, plan, run

    def prepare_edit(
        self, parent: Generation, request: EditRequest
    ) -> tuple[Job, Plan, str, Callable[[Motion], Motion]]:
        """An edit of a generation by the model and run that made it: its job, its plan, the run,
        and how its sample is finished (the kept frames pasted back, the parent recorded)."""
        run, generator = self.catalog.generator(parent.model, parent.run)
        edit, said, plan = plan_edit_request(request, parent, self.generations, generator, self.settings.max_seconds)
        key = (parent.model, run, plan.options)
        job = Job(generator, key, plan.options, plan.actions, plan.frames, request.seed, edit.keep)
        parent_run = {"edit_parent_run": parent.mlflow_run_id} if parent.mlflow_run_id else {}

        def finishing(sampled: Motion) -> Motion:
            return finish_edit(edit, sampled, generator, said, edit_parent=parent.id, **parent_run)

        return job, plan, run, finishing

    def upload(self, request: UploadRequest) -> dict[str, Any]:
        """A motion made elsewhere, recorded as a generation of the named model and run so that it
        can be edited, within the limits of a generation (a blocking call): the API's answer, with
        the rate the motion was read at (``source_fps``)."""
        run, generator = self.catalog.generator(request.model, request.run)
        try:
            raw = base64.b64decode(request.motion, validate=True)
        except binascii.Error as error:
            raise UserError(f"motion: not base64 ({error})") from error
        origin = "the uploaded motion"
        features = load_features(raw, generator.skeleton, origin, request.fps)
        within_cap([len(features)], generator, self.settings.max_seconds)
        texts, seconds = [a.text for a in request.actions], [a.seconds for a in request.actions]
        motion = motion_of(features, texts, seconds, generator, origin)
        # recorded motion: delivered exactly as it came (Delivery.plants_feet), so it edits what was sent
        delivered = motion.delivered(Delivery(), recorded=True)
        generation = self.generations.record(delivered, texts, request.model, run, 0, "uploaded")
        source_fps = generator.fps if request.fps is None else request.fps
        assumed = (
            [f"the motion was read at {source_fps:g} fps, the model's rate: give fps if it was made at another"]
            if request.fps is None
            else []
        )
        return {**self.generations.describe(generation), "source_fps": source_fps, "notices": assumed}

    def split(self, request: SplitRequest) -> dict[str, Any]:
        """The action sentences a prompt becomes for a run, their verbs, and what the run does not
        know of them (a blocking call: it may load the model and its tagger)."""
        _, generator = self.catalog.generator(request.model, request.run)
        with self._planning:
            planner = self._planners.setdefault(id(generator), PromptPlanner(generator))
            actions, verbs = planner.split(request.prompt)
            return {"actions": actions, "verbs": verbs, "notices": planner.notices(actions)}

    async def finish(
        self,
        job: Job,
        model: str,
        plan: Plan,
        run: str,
        finishing: Callable[[Motion], Motion] = Motion.on_rigid_skeleton,
    ) -> dict[str, Any]:
        """The sampled motion, finished (on one rigid skeleton; an edit's kept frames pasted back)
        and recorded; the API's answer, with what the model did not know of it."""
        try:
            motion = await asyncio.wrap_future(job.done)
        except ValueError as error:  # the protocol's answer to a request a model cannot serve
            raise UserError(str(error)) from error
        try:
            answer = await asyncio.wrap_future(
                self.recorder.submit(self._record, job, motion, model, plan, run, finishing)
            )
        except ValueError as error:  # a delivery the clip cannot take: a loop of a clip shorter than its fade
            raise UserError(str(error)) from error
        return {**answer, "notices": plan.notices}

    def _record(
        self, job: Job, motion: Motion, model: str, plan: Plan, run: str, finishing: Callable[[Motion], Motion]
    ) -> dict[str, Any]:
        """On the recorder's thread, not the event loop: the finishing, the delivery, the files and
        MLflow run, and the answer with every joint coordinate (milliseconds each, for a batch of 16)."""
        describe = job.generator.describe(job.options)
        delivered = finishing(motion).delivered(plan.delivery)
        generation = self.generations.record(delivered, plan.prompts, model, run, job.seed, describe, plan.delivery)
        return self.generations.describe(generation)

    def close(self) -> None:
        self.sampler.stop()
        self.recorder.shutdown(wait=True)
        self.painter.shutdown(wait=True)


def create_app(settings: ServeSettings) -> FastAPI:
    service = Service(settings)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        service.sampler.start()
        try:
            yield
        finally:
            service.close()

    app = FastAPI(
        title="m2d2m",
        summary="Multi-action text to motion: M2D2M, MMM and MotionDiffuse behind one interface",
        lifespan=lifespan,
        docs_url=None,  # FastAPI's own pages load Swagger UI and ReDoc from a CDN: ours are served here
        redoc_url=None,
    )
    _serve_api_documentation(app)
    app.state.service = service

    def authorised(request: Request) -> None:
        if settings.token is None:
            return
        given = request.headers.get("authorization", "").removeprefix("Bearer ").strip()
        given = given or request.query_params.get("token", "")
        if not secrets.compare_digest(given.encode(), settings.token.encode()):
            raise ApiError(401, "this server needs its token: send Authorization: Bearer <token>")

    api = APIRouter(prefix="/api", dependencies=[Depends(authorised)])

    @api.get("/health", summary="Whether the server is up, and what it is doing")
    def health() -> dict[str, Any]:
        return {"status": "ok", "dataset": settings.dataset, **asdict(service.sampler.stats())}

    @api.get("/models", summary="The models with a finished run: their runs, methods and knobs")
    def list_models() -> dict[str, Any]:
        return {
            "dataset": settings.dataset,
            "max_seconds": settings.max_seconds,
            "max_rig_bytes": settings.max_rig_bytes,
            "models": service.catalog.describe(),
        }

    @api.get("/models/{model}/runs/{run}", summary="A run's own sampling defaults and action lengths (loads it)")
    async def run_details(model: str, run: str) -> dict[str, Any]:
        return await run_in_threadpool(service.catalog.run_details, model, run)

    @api.post(
        "/generate",
        summary="Several actions in a row with one model, method and seed",
        responses={200: {"content": {NDJSON: {}}, "description": "the generation, or its progress and then it"}},
    )
    async def generate(body: GenerateRequest, request: Request) -> Any:
        job, plan, run = await run_in_threadpool(service.prepare, body)
        return await _sampled(request, job, service.finish(job, body.model, plan, run))

    @api.post(
        "/generations/{generation_id}/edit",
        summary="Edit a generation on its timeline: regenerate an action, fill a gap, pin a pose, continue",
        responses={200: {"content": {NDJSON: {}}, "description": "the new generation, or its progress and then it"}},
    )
    async def edit(generation_id: str, body: EditRequest, request: Request) -> Any:
        parent = service.generations.get(generation_id)
        job, plan, run, finishing = await run_in_threadpool(service.prepare_edit, parent, body)
        return await _sampled(request, job, service.finish(job, parent.model, plan, run, finishing))

    async def _sampled(request: Request, job: Job, finishing: Any) -> Any:
        """Queue ``job``; the answer when it is sampled and ``finishing`` is done, or its progress
        as NDJSON lines before it when the client asks for them."""
        events: asyncio.Queue[dict[str, Any] | None] = asyncio.Queue()
        loop = asyncio.get_running_loop()
        job.listener = lambda event: loop.call_soon_threadsafe(events.put_nowait, event)
        try:
            service.sampler.submit(job)
        except QueueFull as error:
            finishing.close()
            raise ApiError(429, str(error)) from error
        if NDJSON in request.headers.get("accept", ""):
            return StreamingResponse(_stream(job, events, finishing), media_type=NDJSON)
        # a JSONResponse as it is: FastAPI's encoder would walk every joint coordinate in Python first
        return JSONResponse(await _unless_disconnected(request, job, finishing))

    @api.post("/split", summary="The actions a prompt is split into, to check and fix before generating")
    async def split(body: SplitRequest) -> dict[str, Any]:
        return await run_in_threadpool(service.split, body)

    @api.post(
        "/generations",
        summary="Upload a motion made elsewhere (features or joints, at its fps) to edit like a generation",
    )
    async def upload(body: UploadRequest) -> JSONResponse:
        return JSONResponse(await run_in_threadpool(service.upload, body))

    @api.get("/generations/{generation_id}", summary="A generation made by this server")
    def generation(generation_id: str) -> JSONResponse:
        return JSONResponse(service.generations.describe(service.generations.get(generation_id)))

    @api.get(
        "/generations/{generation_id}/{name}",
        summary=f"A generation's file: {', '.join(FILES)} (an animation is drawn on first request; "
        f"?rest={REST_POSES[1]} gives the {spoken(on_rig())} on a T-pose bind pose)",
        response_class=FileResponse,
    )
    async def generation_file(
        generation_id: str, name: str, rest: str = REST_POSES[0], rig: str | None = None
    ) -> FileResponse:
        uploaded = None if rig is None else service.rigs.get(rig)
        loop = asyncio.get_running_loop()
        path = await loop.run_in_executor(
            service.painter, service.generations.file, generation_id, name, rest, uploaded
        )
        return FileResponse(path, filename=f"{generation_id}-{path.name}")

    @api.post(
        RIGS,
        summary="Upload a character's rig (the bytes of a BVH, or of a skinned GLB, streamed; or file=<id> of one "
        "sent before, under another joint_map) to download generations on it: GET a generation's motion.bvh?rig=<id> (or motion.glb, motion.fbx)",
        openapi_extra=FILE_BODY,
    )
    async def add_rig(
        request: Request,
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

    @api.post(
        "/joint-maps",
        summary="Upload a joint map of your own (the text of a YAML file, our joint: yours, as m2d2m generate "
        "--joint-map reads) to name as a rig's joint_map",
        openapi_extra=YAML_BODY,
    )
    async def add_joint_map(request: Request) -> dict[str, Any]:
        mapping = await run_in_threadpool(service.rigs.add_map, await request.body())
        return {"id": mapping.name, "map": {ours: list(theirs) for ours, theirs in mapping.sources.items()}}

    app.include_router(api)
    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    @app.get("/", include_in_schema=False)
    def page() -> FileResponse:
        return FileResponse(STATIC / "index.html")

    _answer_errors_in_one_sentence(app)
    app.add_middleware(BoundedBody, limits={api.prefix + RIGS: settings.max_rig_bytes})
    return app


def _serve_api_documentation(app: FastAPI) -> None:
    """``/docs`` (Swagger UI) and ``/redoc`` (ReDoc) from files installed with the project
    (fastapi-offline's copies), so that they work on a machine without internet; a content
    policy keeps the rest home too (ReDoc's footer would fetch Redocly's logo from its CDN)."""
    app.mount("/docs-files", StaticFiles(directory=DOCS_FILES), name="docs-files")
    common = {"openapi_url": app.openapi_url, "title": f"{app.title}: the HTTP API"}

    def at_home(page: HTMLResponse) -> HTMLResponse:
        page.headers["Content-Security-Policy"] = "img-src 'self' data:; font-src 'self' data:; connect-src 'self'"
        return page

    @app.get("/docs", include_in_schema=False)
    def swagger() -> HTMLResponse:
        return at_home(
            get_swagger_ui_html(
                **common,
                swagger_js_url="/docs-files/swagger-ui-bundle.js",
                swagger_css_url="/docs-files/swagger-ui.css",
                swagger_favicon_url="/docs-files/favicon.png",
            )
        )

    @app.get("/redoc", include_in_schema=False)
    def redoc() -> HTMLResponse:
        return at_home(
            get_redoc_html(
                **common,
                redoc_js_url="/docs-files/redoc.standalone.js",
                redoc_favicon_url="/docs-files/favicon.png",
                with_google_fonts=False,
            )
        )


async def _stream(job: Job, events: asyncio.Queue, finishing: Any) -> AsyncIterator[bytes]:
    """NDJSON lines: the job's events, then ``{"result": ...}`` or ``{"error": ...}``. A client
    that goes away cancels this generator (Starlette does), which cancels the job."""
    try:
        while (event := await events.get()) is not None:
            yield _line(event)
        try:
            yield _line({"result": await finishing})
        except (UserError, ValueError, Cancelled) as error:
            yield _line({"error": str(error)})
        except Exception as error:
            log.exception("generation failed")
            yield _line({"error": f"the generation failed on the server ({type(error).__name__}); see its log"})
    finally:
        job.cancel()
        finishing.close()


def _line(payload: dict[str, Any]) -> bytes:
    return (json.dumps(payload, separators=(",", ":")) + "\n").encode()


async def _unless_disconnected(request: Request, job: Job, finishing: Any) -> Any:
    """``finishing``'s answer; a client that disconnects before it cancels the job."""
    task = asyncio.ensure_future(finishing)
    try:
        while not task.done():
            await asyncio.wait({task}, timeout=0.25)
            if not task.done() and await request.is_disconnected():
                job.cancel()
        return task.result()
    finally:
        job.cancel()


def _answer_errors_in_one_sentence(app: FastAPI) -> None:
    """Every error a client can cause as ``{"error": "one sentence"}`` with its 4xx status."""

    def answer(status: int, message: str) -> JSONResponse:
        return JSONResponse({"error": message}, status_code=status)

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, error: RequestValidationError) -> JSONResponse:
        return answer(422, _sentence(error))

    @app.exception_handler(ApiError)
    async def refused(request: Request, error: ApiError) -> JSONResponse:
        return answer(error.status, str(error))

    @app.exception_handler(NotFound)
    async def not_found(request: Request, error: NotFound) -> JSONResponse:
        return answer(404, str(error))

    @app.exception_handler(UserError)
    async def bad_request(request: Request, error: UserError) -> JSONResponse:
        return answer(400, str(error))

    @app.exception_handler(Cancelled)
    async def cancelled(request: Request, error: Cancelled) -> JSONResponse:
        return answer(499, str(error))

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, error: StarletteHTTPException) -> JSONResponse:
        return answer(error.status_code, str(error.detail))

    @app.exception_handler(Exception)
    async def unexpected(request: Request, error: Exception) -> JSONResponse:
        log.exception("unexpected error on %s", request.url.path)
        return answer(500, f"the server failed ({type(error).__name__}); its log says more")
