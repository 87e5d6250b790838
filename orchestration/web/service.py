"""The state one application holds, typed: its settings, the models, the sampling thread, the
generations and the rigs. The routers (:mod:`orchestration.web.routers`) reach it through
:func:`orchestration.web.dependencies.service_of` rather than through a closure's variables; its
methods are the blocking steps a route runs off the event loop."""

from __future__ import annotations

import asyncio
import base64
import binascii
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from m2d2m.motion.clip import Motion
from m2d2m.motion.transforms.delivery import Delivery
from orchestration.editing import finish_edit, motion_of
from orchestration.errors import UserError
from orchestration.generate import DEFAULT_MAX_SECONDS, PromptPlanner
from orchestration.runs import stage_dir
from orchestration.viewing import load_features
from orchestration.web.catalog import Catalog
from orchestration.web.edits import plan_edit_request
from orchestration.web.generations import Generation, Generations
from orchestration.web.rigs import RIGS_STAGE, Rigs
from orchestration.web.sampler import Job, Sampler
from orchestration.web.schema import (
    EditRequest,
    GenerateRequest,
    Plan,
    SplitRequest,
    UploadRequest,
    plan_request,
    within_cap,
)


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
        """The sampling thread finishes its queue, then the recorder and the painter theirs."""
        self.sampler.stop()
        self.recorder.shutdown(wait=True)
        self.painter.shutdown(wait=True)
