"""What a client may send to the routes that sample (``POST /api/generate``, an edit, an upload to
edit), and how a request becomes one sequence to sample.

The bounds here are the ones no model changes (lengths of texts and lists, the seed's range);
everything that depends on the model — its methods and knobs, the seconds an action may last, the
length cap — is checked by the same code as `m2d2m generate` (:func:`~orchestration.generate.check_seconds`
wherever seconds become frames, :func:`within_cap` on every route, the model's declared knobs), so
the page, the API and the command line accept and refuse the same requests in the same sentences.
"""

from __future__ import annotations

import unicodedata
from abc import abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar, Literal, Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt, StrictStr, field_validator, model_validator

from m2d2m.generators.edits import Timeline
from m2d2m.generators.protocol import MotionGenerator
from m2d2m.motion.transforms.delivery import Delivery
from orchestration.edit_operations import Continue, EditOperation, Fill, Layer, Pin, Regenerate
from orchestration.errors import UserError
from orchestration.generate import PromptPlanner, check_length
from orchestration.registry import DEFAULT_MODEL
from orchestration.web.catalog import LATEST_RUN

MAX_TEXT = 500  # characters of one action's sentence
MAX_PROMPT = 2000  # characters of a free prompt, split into actions by its verbs
MAX_ACTIONS = 32
MAX_SEED = 2**31 - 1
# the end of the length cap's refusal, in the API's terms rather than the command line's flags
API_LENGTH_REMEDY = "give fewer actions or shorter seconds (the cap is the server's: m2d2m serve --max-seconds)"


def english_sentence(text: str | None) -> str | None:
    """``text`` if it can be an action sentence: no control characters (a NUL byte reached the
    tagger and the model before) and at least one Latin letter (the models read English words;
    a text of emoji or CJK alone made a motion of nothing it said)."""
    if text is None:
        return None
    control = next((c for c in text if unicodedata.category(c) == "Cc" and c not in "\t\n"), None)
    if control is not None:
        raise ValueError(f"holds the control character U+{ord(control):04X}; send plain text")
    symbols = [c for c in text if not c.isspace() and not unicodedata.category(c).startswith("P")]
    if symbols and not any("a" <= c.lower() <= "z" for c in symbols):  # blank or punctuation: the planner says so
        raise ValueError(f"{text[:40]!r} has no English word; the models read English sentences")
    return text


class Action(BaseModel):
    """One action: its sentence and, optionally, its length (none: the corpus's typical length).
    Types are strict: ``"seconds": "3"`` or ``true`` is refused, not read as 3 or 1."""

    model_config = ConfigDict(extra="forbid", strict=True)
    text: str = Field(min_length=1, max_length=MAX_TEXT, description="the action in one sentence")
    seconds: float | None = Field(None, allow_inf_nan=False, description="its length; none: the typical length")

    _english = field_validator("text")(english_sentence)


class Sampled(BaseModel):
    """What every request that samples takes: the model's knobs, the seed, and how the clip is
    delivered, as `m2d2m generate`'s options (m2d2m.motion.transforms.delivery.Delivery)."""

    model_config = ConfigDict(extra="forbid", strict=True)
    options: dict[str, StrictInt | StrictFloat | StrictStr | None] = Field(
        default_factory=dict, max_length=32, description="sampling knobs by name (GET /api/models lists them)"
    )
    seed: int = Field(0, ge=0, le=MAX_SEED)
    # how the clip is delivered, as `m2d2m generate`'s options (m2d2m.motion.transforms.delivery.Delivery)
    fps: float | None = Field(None, allow_inf_nan=False, description="the files' frame rate; none: the model's")
    root: str = Field("keep", max_length=16, description="keep, in-place (the root's path taken out) or ground")
    loop: bool = Field(False, description="one seamless cycle, the end blended into the start")
    plant_feet: bool | None = Field(
        None,
        description="feet kept from sliding where they touch down (none: yes, a generated clip's rule; false: as generated)",
    )


class GenerateRequest(Sampled):
    """Several actions in a row (``actions``), or one free sentence split by its verbs as `m2d2m
    generate` splits a prompt (``prompt``, with ``seconds`` for the whole)."""

    model_config = ConfigDict(extra="forbid", protected_namespaces=(), strict=True)
    model: str = Field(DEFAULT_MODEL, max_length=64, description="a model of GET /api/models")
    run: str = Field(LATEST_RUN, max_length=64, description="one of the model's runs, or latest")
    actions: list[Action] | None = Field(None, min_length=1, max_length=MAX_ACTIONS)
    prompt: str | None = Field(None, min_length=1, max_length=MAX_PROMPT)
    seconds: float | None = Field(None, allow_inf_nan=False, description="the prompt's length")
    method: str | None = Field(None, max_length=64, description="the multi-action method; none: the model's default")

    _english = field_validator("prompt")(english_sentence)

    @model_validator(mode="after")
    def _one_way_of_asking(self) -> GenerateRequest:
        if (self.actions is None) == (self.prompt is None):
            raise ValueError("give either actions (a list of sentences with seconds) or one prompt")
        if self.seconds is not None and self.prompt is None:
            raise ValueError("seconds goes with prompt; give each action its own seconds")
        return self


class PoseReference(BaseModel):
    """A frame of a generation this server made, counted as its answer's joints are: at the rate
    it was delivered at (its ``fps``)."""

    model_config = ConfigDict(extra="forbid", strict=True)
    generation: str = Field(max_length=64, description="a generation's id")
    frame: int = Field(ge=0, description="its frame, at the generation's own fps (its joints' index)")


class EditSources(Protocol):
    """How an edit reads the generations it names besides the one it edits
    (:class:`~orchestration.web.edits.GenerationSources`)."""

    def timeline(self, generation: str) -> Timeline:
        """The timeline of generation ``generation``."""

    def pose(self, reference: PoseReference) -> np.ndarray:
        """The features of the pose ``reference`` names."""


class EditFields(Sampled):
    """What every edit of a generation takes (docs/generation.md, "Editing a result"), by the model
    and run that made it: each operation's body adds its own fields to the knobs, the seed and
    the delivery, and becomes its operation of :mod:`orchestration.edit_operations`
    (:meth:`edit_operation`). Answers as ``POST /api/generate``."""

    model_config = ConfigDict(extra="forbid", strict=True)
    asks: ClassVar[str]  # what the operation must be given, said when a field of it is missing

    _english = field_validator("text", check_fields=False)(english_sentence)  # the operations that take a text

    @model_validator(mode="before")
    @classmethod
    def _its_own_fields(cls, data: Any) -> Any:
        """A field of another operation, or one of its own missing, said in the operation's words."""
        if isinstance(data, dict):
            stray = sorted(set(data) - set(cls.model_fields))
            if stray:
                raise ValueError(f"{', '.join(stray)} does not go with the operation {data.get('operation')}")
            if any(field.is_required() and name not in data for name, field in cls.model_fields.items()):
                raise ValueError(f"{data.get('operation')} names {cls.asks}")
        return data

    @abstractmethod
    def edit_operation(self, sources: EditSources) -> EditOperation:
        """The operation this body asks for, the generations it names read from ``sources``."""


class RegenerateRequest(EditFields):
    """Action ``action`` sampled again, under ``text`` and ``seconds`` when given."""

    asks: ClassVar[str] = "the action to sample again (action, counted from 1)"
    operation: Literal["regenerate"]
    action: int = Field(ge=1, le=MAX_ACTIONS, description="the action, counted from 1")
    text: str | None = Field(None, min_length=1, max_length=MAX_TEXT, description="its new text")
    seconds: float | None = Field(None, allow_inf_nan=False, description="its new length")

    def edit_operation(self, sources: EditSources) -> Regenerate:
        return Regenerate(self.action, self.text, self.seconds)


class FillRequest(EditFields):
    """``seconds`` of new motion doing ``text`` between the generation and generation ``then``."""

    asks: ClassVar[str] = "the generation that follows the gap (then)"
    operation: Literal["fill"]
    then: str = Field(max_length=64, description="the generation that follows the gap")
    text: str | None = Field(None, min_length=1, max_length=MAX_TEXT, description="what happens in the gap")
    seconds: float | None = Field(None, allow_inf_nan=False, description="the gap's length; none: 1 s")

    def edit_operation(self, sources: EditSources) -> Fill:
        return Fill(sources.timeline(self.then), 1.0 if self.seconds is None else self.seconds, self.text or "")


class PinRequest(EditFields):
    """The pose ``pose`` pinned at ``at`` seconds."""

    asks: ClassVar[str] = "the pose and the time to pin it at (pose: a generation and its frame; at: seconds)"
    operation: Literal["pin"]
    pose: PoseReference = Field(description="the pose, a frame of a generation")
    at: float = Field(allow_inf_nan=False, description="where, in seconds")

    def edit_operation(self, sources: EditSources) -> Pin:
        return Pin(sources.pose(self.pose), self.at)


class ContinueRequest(EditFields):
    """``actions`` appended, each its ``seconds`` long (none: the model's typical length)."""

    asks: ClassVar[str] = "the new actions (actions)"
    operation: Literal["continue"]
    actions: list[Action] = Field(min_length=1, max_length=MAX_ACTIONS, description="the new actions")

    def edit_operation(self, sources: EditSources) -> Continue:
        return Continue(tuple(a.text for a in self.actions), tuple(a.seconds for a in self.actions))


class LayerRequest(EditFields):
    """Body ``part`` doing ``text`` over ``span``, the rest of the body as it was."""

    asks: ClassVar[str] = "the body part, its text and its span (part, text, span)"
    operation: Literal["layer"]
    part: str = Field(max_length=16, description="the body part (upper, lower) doing text")
    text: str = Field(min_length=1, max_length=MAX_TEXT, description="what the part does")
    span: list[float] = Field(min_length=2, max_length=2, description="its start and end, in seconds")

    def edit_operation(self, sources: EditSources) -> Layer:
        return Layer(self.part, self.text, (self.span[0], self.span[1]))


# one edit, its fields those of the operation it names (OpenAPI: a oneOf by operation)
EditRequest = Annotated[
    RegenerateRequest | FillRequest | PinRequest | ContinueRequest | LayerRequest, Field(discriminator="operation")
]


def delivery_of(request: Sampled) -> Delivery:
    """How a request's clip is delivered, or a UserError in one sentence."""
    try:
        return Delivery(fps=request.fps, root=request.root, loop=request.loop, plant_feet=request.plant_feet)
    except ValueError as error:
        raise UserError(str(error)) from error


class UploadRequest(BaseModel):
    """A motion made elsewhere, to edit as a generation of the named model and run: ``motion``, a
    ``.npy`` file's bytes in base64 (features (T, D) or joints (T, J, 3)) made at ``fps`` frames a
    second (none: the model's; another rate is resampled to the model's, and the answer's
    ``source_fps`` says which rate was read), and its ``actions`` in order, each with its seconds
    (the last's may be none: to the end)."""

    model_config = ConfigDict(extra="forbid", protected_namespaces=(), strict=True)
    model: str = Field(DEFAULT_MODEL, max_length=64, description="a model of GET /api/models")
    run: str = Field(LATEST_RUN, max_length=64, description="one of the model's runs, or latest")
    motion: str = Field(min_length=1, description="base64 of a .npy of features or joints")
    fps: float | None = Field(
        None, allow_inf_nan=False, description="the motion's frame rate; none: the model's (the answer says which)"
    )
    actions: list[Action] = Field(min_length=1, max_length=MAX_ACTIONS)


class SplitRequest(BaseModel):
    """A sentence to split into action sentences as ``prompt`` of ``POST /api/generate`` would be,
    by the named run's tagger, to see (and fix) them before sampling."""

    model_config = ConfigDict(extra="forbid", protected_namespaces=(), strict=True)
    model: str = Field(DEFAULT_MODEL, max_length=64, description="a model of GET /api/models")
    run: str = Field(LATEST_RUN, max_length=64, description="one of the model's runs, or latest")
    prompt: str = Field(min_length=1, max_length=MAX_PROMPT)

    _english = field_validator("prompt")(english_sentence)


@dataclass(frozen=True)
class Plan:
    """A request made concrete for one generator: the action sentences, their frames, the options."""

    actions: list[str]
    frames: list[int]
    options: Any
    prompts: list[str]  # what the user typed, for the run's record
    notices: list[str]  # what the model does not know of the actions (PromptPlanner.notices)
    delivery: Delivery  # how the clip is delivered


def within_cap(frames: Sequence[int], generator: MotionGenerator, max_seconds: float | None) -> None:
    """The server's cap on a clip, the same for every route that samples one or keeps one to
    sample from (generate, edit, upload), in the same sentence; each action's own range is checked
    where its seconds become frames (:func:`~orchestration.generate.check_seconds`)."""
    check_length(frames, generator.fps, max_seconds, API_LENGTH_REMEDY)


def plan_request(request: GenerateRequest, planner: PromptPlanner, max_seconds: float | None) -> Plan:
    """The request as `m2d2m generate` would sample it: a list of actions as prompts given with
    ``--no-split`` (each its own seconds or the typical length), a prompt split by its verbs; a
    UserError in one sentence for anything this model cannot do."""
    generator = planner.generator
    if request.prompt is not None:
        prompts = [request.prompt]
        actions, frames = planner.plan(prompts, None if request.seconds is None else [request.seconds], split=True)
    else:
        prompts, actions, frames = [], [], []
        for action in request.actions or ():
            if not action.text.strip():
                raise UserError("an action's text is empty")
            texts, lengths = planner.plan([action.text], None if action.seconds is None else [action.seconds], False)
            prompts.append(action.text)
            actions += texts
            frames += lengths
    within_cap(frames, generator, max_seconds)
    changes = dict(request.options)
    if request.method is not None:
        changes["method"] = request.method
    try:
        options = generator.options(**changes)
    except ValueError as error:
        raise UserError(str(error)) from error
    return Plan(actions, frames, options, prompts, planner.notices(actions), delivery_of(request))
